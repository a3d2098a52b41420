"""Ground-truth oracles: answer D4RT queries (u, v, t_src, t_tgt, t_cam) exactly from ground truth.

All oracles return the same dict as the model's decoder (torch tensors, float in the queries' dtype
unless noted):
- ``points (N, 3)``: the surface point seen at (u, v) in frame t_src, at time t_tgt, in camera t_cam.
- ``uv (N, 2)``: its projection into frame t_tgt, normalised like (u, v) (NaN where behind camera t_tgt).
- ``visibility (N,)``: 1.0 where it is visible in frame t_tgt (in front, inside the image, not occluded).
- ``motion (N, 3)``: position at t_tgt minus position at t_src, both in camera t_cam.
- ``normals (N, 3)``: unit surface normal at t_tgt in camera t_cam.
- ``confidence (N,)``: 1.0 where the answer is valid (the oracle is certain), else 0.
- ``valid (N,)`` bool: ground truth exists for this query; ``uv_valid (N,)`` bool: the point is in
  front of camera t_tgt so ``uv`` is defined; ``object_id (N,)`` long: the body the point lies on.

``AnalyticOracle`` ray-casts the scene description, exact for any continuous (u, v).
``ArrayOracle`` needs only depth, normals, object ids and poses (any dataset in the npz layout): it is
exact at pixel centres and answers other (u, v) with the pixel that contains them.
``ViewOracle`` answers in the coordinates of a crop / resize / frame subset of another oracle's clip.
"""

from __future__ import annotations

import numpy as np
import torch

from d4rt.errors import UserError
from d4rt.geometry.camera import pixel_rays, project, uv_to_pixel
from d4rt.geometry.view import View
from d4rt.geometry.transforms import apply_rotation, apply_transform
from d4rt.synthetic.raytrace import Hits, SceneTracer
from d4rt.synthetic.scene import SceneDescription

QUERY_CHUNK = 1 << 16


def validate_queries(queries, num_frames: int, device=None) -> torch.Tensor:
    """Check (N, 5) queries [u, v, t_src, t_tgt, t_cam] and return them as a floating torch tensor.

    Raises UserError naming the problem: wrong shape, non-finite values, (u, v) outside [0, 1], or time
    indices that are not integers in [0, num_frames). Nothing is clamped.
    """
    q = torch.as_tensor(queries)
    if not q.is_floating_point():
        q = q.to(torch.float64)
    if device is not None:
        q = q.to(device)
    if q.ndim != 2 or q.shape[1] != 5:
        raise UserError(f"queries must have shape (N, 5) = [u, v, t_src, t_tgt, t_cam], got {tuple(q.shape)}")
    if not torch.isfinite(q).all():
        raise UserError("queries contain NaN or infinite values")
    uv = q[:, :2]
    bad = (uv < 0) | (uv > 1)
    if bad.any():
        i = int(torch.nonzero(bad.any(1))[0])
        raise UserError(f"query {i} has (u, v) = ({q[i, 0].item():.6g}, {q[i, 1].item():.6g}) outside [0, 1]")
    t = q[:, 2:]
    bad = (t != torch.round(t)) | (t < 0) | (t >= num_frames)
    if bad.any():
        i, j = (int(x) for x in torch.nonzero(bad)[0])
        name = ("t_src", "t_tgt", "t_cam")[j]
        raise UserError(f"query {i} has {name} = {t[i, j].item():.6g}: time indices must be integers in "
                        f"[0, {num_frames - 1}] for this {num_frames}-frame clip")
    return q


class Oracle:
    """Common base: validation, chunking, and the geometry shared by every ground-truth source."""

    num_frames: int
    height: int
    width: int

    def query(self, queries) -> dict:
        """Answer (N, 5) queries; see the module docstring for the returned dict."""
        q = validate_queries(queries, self.num_frames, self.device)
        parts = [self._answer(q[i:i + QUERY_CHUNK]) for i in range(0, max(q.shape[0], 1), QUERY_CHUNK)]
        out = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
        return {k: (v.to(q.dtype) if v.is_floating_point() else v) for k, v in out.items()}

    def _answer(self, q: torch.Tensor) -> dict:
        raise NotImplementedError


class _PoseOracle(Oracle):
    """An oracle over per-frame cameras and body poses (float64 internally)."""

    def __init__(self, intrinsics, cam_to_world, object_to_world, height: int, width: int, device="cpu"):
        self.device = torch.device(device)
        f64 = dict(dtype=torch.float64, device=self.device)
        self.intrinsics = torch.as_tensor(np.asarray(intrinsics), **f64)
        self.cam_to_world = torch.as_tensor(np.asarray(cam_to_world), **f64)
        self.object_to_world = torch.as_tensor(np.asarray(object_to_world), **f64)
        self.world_to_cam = torch.linalg.inv(self.cam_to_world)
        self.world_to_object = torch.linalg.inv(self.object_to_world)
        self.num_frames = self.intrinsics.shape[0]
        self.height, self.width = height, width

    def _surface_at_source(self, uv, t_src):
        """World point (N,3), world normal (N,3), body id (N,) long and validity (N,) of the source pixels."""
        raise NotImplementedError

    def _visible(self, xy, z, obj, t_tgt, world_point) -> torch.Tensor:
        """Visibility of world points that project to pixel xy (N,2) at depth z in frame t_tgt."""
        raise NotImplementedError

    def _answer(self, q: torch.Tensor) -> dict:
        q = q.to(torch.float64)
        uv = q[:, :2]
        t_src, t_tgt, t_cam = (q[:, i].long() for i in (2, 3, 4))
        x_src, n_src, obj, valid = self._surface_at_source(uv, t_src)
        # Rigid motion of the point's body from t_src to t_tgt: T_tgt @ T_src^-1.
        motion = self.object_to_world[t_tgt, obj] @ self.world_to_object[t_src, obj]
        x_tgt = apply_transform(motion, x_src)
        n_tgt = apply_rotation(motion[:, :3, :3], n_src)
        to_cam = self.world_to_cam[t_cam]
        points = apply_transform(to_cam, x_tgt)
        points_src = apply_transform(to_cam, x_src)
        normals = apply_rotation(to_cam[:, :3, :3], n_tgt)
        cam_tgt = apply_transform(self.world_to_cam[t_tgt], x_tgt)
        xy, z = project(cam_tgt, self.intrinsics[t_tgt])
        in_front = z > 1e-9
        uv_tgt = torch.stack([(xy[:, 0] + 0.5) / self.width, (xy[:, 1] + 0.5) / self.height], 1)
        uv_tgt = torch.where(in_front[:, None], uv_tgt, torch.full_like(uv_tgt, float("nan")))
        inside = in_front & (uv_tgt >= 0).all(1) & (uv_tgt <= 1).all(1)
        visible = torch.zeros_like(inside)
        idx = torch.nonzero(inside & valid).squeeze(1)
        if idx.numel():
            visible[idx] = self._visible(xy[idx], z[idx], obj[idx], t_tgt[idx], x_tgt[idx])
        nan3 = torch.full_like(points, float("nan"))
        return {
            "points": torch.where(valid[:, None], points, nan3),
            "uv": torch.where(valid[:, None], uv_tgt, torch.full_like(uv_tgt, float("nan"))),
            "visibility": visible.to(torch.float64),
            "motion": torch.where(valid[:, None], points - points_src, nan3),
            "normals": torch.where(valid[:, None], normals, nan3),
            "confidence": valid.to(torch.float64),
            "valid": valid,
            "uv_valid": valid & in_front,
            "object_id": obj,
        }


class AnalyticOracle(_PoseOracle):
    """Exact answers for any continuous (u, v), by ray casting the scene description in float64."""

    def __init__(self, scene: SceneDescription, intrinsics, cam_to_world, object_to_world, height, width,
                 device="cpu", depth_tolerance: float = 1e-6):
        super().__init__(intrinsics, cam_to_world, object_to_world, height, width, device)
        self.tracer = SceneTracer(scene, object_to_world, device=device, dtype=torch.float64)
        self.depth_tolerance = depth_tolerance

    def _cast(self, xy, frames):
        c2w = self.cam_to_world[frames]
        dirs = apply_rotation(c2w[:, :3, :3], pixel_rays(xy, self.intrinsics[frames]))  # camera z = 1: t is depth
        origins = c2w[:, :3, 3]
        return origins, dirs, self.tracer.trace_rays(frames, origins, dirs)

    def _surface_at_source(self, uv, t_src):
        xy = uv_to_pixel(uv, self.height, self.width)
        origins, dirs, hits = self._cast(xy, t_src)
        valid = torch.isfinite(hits.t)
        safe = Hits(torch.where(valid, hits.t, torch.ones_like(hits.t)), hits.obj, hits.face)
        surf = self.tracer.surface(t_src, origins, dirs, safe)
        return surf["world_point"], surf["world_normal"], hits.obj.long(), valid

    def _visible(self, xy, z, obj, t_tgt, world_point):
        _, _, hits = self._cast(xy, t_tgt)
        return (hits.obj.long() == obj) & ((hits.t - z).abs() <= self.depth_tolerance * z)


class ArrayOracle(_PoseOracle):
    """Answers from depth, normals and object-id maps plus poses: exact at pixel centres.

    A query (u, v) is answered with the surface point of the pixel that contains it (u = 1 belongs to
    the last pixel). A point counts as visible in frame t_tgt when the pixel nearest to its projection
    shows the same body at a depth within ``depth_tolerance`` (relative) of the point's.
    """

    def __init__(self, depth, normals, object_ids, intrinsics, cam_to_world, object_to_world, device="cpu",
                 depth_tolerance: float = 0.03):
        depth = np.asarray(depth)
        super().__init__(intrinsics, cam_to_world, object_to_world, depth.shape[1], depth.shape[2], device)
        self.depth = torch.as_tensor(depth, dtype=torch.float64, device=self.device)
        self.normals = torch.as_tensor(np.asarray(normals), dtype=torch.float64, device=self.device)
        self.object_ids = torch.as_tensor(np.asarray(object_ids).astype(np.int64), device=self.device)
        self.depth_tolerance = depth_tolerance

    def _surface_at_source(self, uv, t_src):
        col = torch.clamp(torch.floor(uv[:, 0] * self.width), max=self.width - 1).long()
        row = torch.clamp(torch.floor(uv[:, 1] * self.height), max=self.height - 1).long()
        d = self.depth[t_src, row, col]
        valid = torch.isfinite(d) & (d > 0)
        centre = torch.stack([col, row], 1).to(torch.float64)
        x_cam = pixel_rays(centre, self.intrinsics[t_src]) * torch.where(valid, d, torch.ones_like(d))[:, None]
        c2w = self.cam_to_world[t_src]
        world = apply_transform(c2w, x_cam)
        normal = apply_rotation(c2w[:, :3, :3], self.normals[t_src, row, col])
        return world, normal, self.object_ids[t_src, row, col], valid

    def _visible(self, xy, z, obj, t_tgt, world_point):
        col = torch.clamp(torch.floor(xy[:, 0] + 0.5), 0, self.width - 1).long()
        row = torch.clamp(torch.floor(xy[:, 1] + 0.5), 0, self.height - 1).long()
        d = self.depth[t_tgt, row, col]
        return (self.object_ids[t_tgt, row, col] == obj) & ((d - z).abs() <= self.depth_tolerance * z)


class ViewOracle(Oracle):
    """The oracle of a view (crop, resize, frame subset) of another oracle's clip."""

    def __init__(self, parent: Oracle, view: View):
        view.check_frames(parent.num_frames)
        self.parent, self.view = parent, view
        self.device = parent.device
        self.num_frames = view.num_frames
        self.height, self.width = view.size

    def _answer(self, q: torch.Tensor) -> dict:
        src = torch.cat([self.view.uv_to_source(q[:, :2]), self.view.time_to_source(q[:, 2:])], 1)
        out = self.parent.query(src)
        uv = self.view.uv_from_source(out["uv"])
        inside = (uv >= 0).all(1) & (uv <= 1).all(1)
        out["uv"] = uv
        out["visibility"] = out["visibility"] * inside.to(out["visibility"].dtype)
        return out
