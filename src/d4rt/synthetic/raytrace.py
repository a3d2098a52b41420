"""Exact ray casting through a synthetic scene at any frame: the one geometric core that both the
renderer and the ground-truth oracle use.

A ``SceneTracer`` holds, on one device and dtype, every body's world-to-canonical transform for every
frame. ``trace_grid`` casts whole frames (bodies culled to their projected bounding boxes),
``trace_rays`` casts arbitrary rays each tagged with its frame (bodies culled by a bounding-sphere
test), and ``surface`` turns hits into world points, normals and body-frame texture coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from d4rt.synthetic.scene import SceneDescription
from d4rt.synthetic.shapes import canonical_normal, intersect

CURVED = ("sphere", "cylinder", "cone", "outdoor")
GRAZING_COS = 0.5  # plane hits of rays within 60 degrees of grazing are refined in float64


@dataclass
class Hits:
    """Ray hits: ray parameter ``t`` (inf = miss), body id ``obj`` and primitive ``face``; any shape."""

    t: torch.Tensor
    obj: torch.Tensor
    face: torch.Tensor


class SceneTracer:
    """Ray casting through ``scene`` posed by ``object_to_world`` (T, K, 4, 4) at frames 0..T-1."""

    def __init__(self, scene: SceneDescription, object_to_world: np.ndarray, device="cpu", dtype=torch.float32):
        pose = np.asarray(object_to_world, dtype=np.float64)
        if pose.ndim != 4 or pose.shape[1] != scene.num_bodies or pose.shape[2:] != (4, 4):
            raise ValueError(
                f"object_to_world has shape {pose.shape}, expected (T, {scene.num_bodies}, 4, 4) for this scene"
            )
        self.scene = scene
        self.device = torch.device(device)
        self.dtype = dtype
        self.num_frames = pose.shape[0]
        scale = np.array([b.half_extents for b in scene.bodies], dtype=np.float64)  # (K, 3)
        rot = pose[..., :3, :3]
        trans = pose[..., :3, 3]
        # canonical = diag(1/s) R^T (x - t), stored as [diag(1/s) R^T | t]. Subtracting t first keeps
        # float32 precise: folding it into an offset would cancel large terms for distant bodies.
        lin = np.swapaxes(rot, -1, -2) / scale[None, :, :, None]
        to_canon = np.concatenate([lin, trans[..., None]], -1)  # (T, K, 3, 4)
        # One contiguous (T, ...) table per body: per-ray rows are gathered with index_select, far
        # cheaper than advanced indexing into (T, K, ...) arrays. Kept in the tracing dtype and in
        # float64 (exact ground truth where float32 is ill-conditioned, see ``surface``).
        self._tables = {dt: _BodyTables(to_canon, rot, trans, scale, dt, self.device) for dt in {dtype, torch.float64}}
        self.translation = torch.as_tensor(trans, dtype=dtype, device=self.device)  # (T, K, 3)
        self.radius = [b.bounding_radius for b in scene.bodies]

    # ---------------------------------------------------------------------------------------------
    def trace_grid(self, frames: torch.Tensor, origins: torch.Tensor, dirs: torch.Tensor, rects=None,
                   t_min: float = 1e-4) -> Hits:
        """Cast the rays of whole frames.

        frames: (F,) frame indices; origins: (F, 3) one origin per frame; dirs: (F, H, W, 3).
        rects: optional (F, K, 4) int pixel boxes [x0, y0, x1, y1) outside which body k cannot appear
        in frame f (from ``projected_rects``); the environment (k = 0) is never culled.
        Returns Hits of shape (F, H, W).
        """
        f, h, w, _ = dirs.shape
        planes = [c.contiguous() for c in dirs.unbind(-1)]  # component planes: faster elementwise ops
        best_t = torch.full((f, h, w), float("inf"), dtype=self.dtype, device=self.device)
        best_obj = torch.zeros((f, h, w), dtype=torch.uint8, device=self.device)
        best_face = torch.zeros((f, h, w), dtype=torch.uint8, device=self.device)
        for k, body in enumerate(self.scene.bodies):
            if rects is not None and k > 0:
                box = rects[:, k]
                x0, y0 = int(box[:, 0].min()), int(box[:, 1].min())
                x1, y1 = int(box[:, 2].max()), int(box[:, 3].max())
                if x1 <= x0 or y1 <= y0:
                    continue
            else:
                x0, y0, x1, y1 = 0, 0, w, h
            a = rows(self._tables[self.dtype].canon[k], frames)  # (F, 3, 4)
            o_c = _affine(a, origins)  # per frame
            o_c = tuple(c[:, None, None] for c in o_c)
            d_block = [c[:, y0:y1, x0:x1] for c in planes]
            d_c = _linear(a[:, None, None], d_block)
            t, face = intersect(body.shape, o_c, d_c, t_min, body.r_top)
            tb = best_t[:, y0:y1, x0:x1]
            nearer = t < tb
            tb.copy_(torch.where(nearer, t, tb))
            ob = best_obj[:, y0:y1, x0:x1]
            ob.masked_fill_(nearer, k)
            fb = best_face[:, y0:y1, x0:x1]
            fb.copy_(torch.where(nearer, face, fb))
        return Hits(best_t, best_obj, best_face)

    def trace_rays(self, frames: torch.Tensor, origins: torch.Tensor, dirs: torch.Tensor, t_min: float = 1e-4,
                   include_environment: bool = True, t_max: torch.Tensor | None = None,
                   dtype: torch.dtype | None = None) -> Hits:
        """Cast arbitrary rays. frames: (N,) long; origins, dirs: (N, 3). Returns Hits of shape (N,).

        ``t_max`` (N,) skips bodies whose bounding sphere starts beyond it (e.g. shadow rays).
        ``dtype``: float64 casts exactly like the ground-truth oracle (default: the tracer's dtype).
        """
        dtype = dtype or self.dtype
        tables = self._tables[dtype]
        origins, dirs = origins.to(dtype), dirs.to(dtype)
        n = dirs.shape[0]
        best_t = torch.full((n,), float("inf"), dtype=dtype, device=self.device)
        best_obj = torch.zeros((n,), dtype=torch.uint8, device=self.device)
        best_face = torch.zeros((n,), dtype=torch.uint8, device=self.device)
        for k, body in enumerate(self.scene.bodies):
            if k == 0 and not include_environment:
                continue
            if k == 0:
                idx = None
            else:
                idx = self._sphere_candidates(tables.translation[k], k, frames, origins, dirs, t_min, t_max)
                if idx.numel() == 0:
                    continue
            fr = frames if idx is None else frames[idx]
            o = origins if idx is None else origins[idx]
            d = dirs if idx is None else dirs[idx]
            a = rows(tables.canon[k], fr)
            t, face = intersect(body.shape, _affine(a, o), _linear(a, d), t_min, body.r_top)
            cur = best_t if idx is None else best_t[idx]
            nearer = t < cur
            if idx is None:
                best_t = torch.where(nearer, t, best_t)
                best_obj = best_obj.masked_fill(nearer, k)
                best_face = torch.where(nearer, face, best_face)
            else:
                sel = idx[nearer]
                best_t[sel] = t[nearer]
                best_obj[sel] = k
                best_face[sel] = face[nearer]
        return Hits(best_t, best_obj, best_face)

    def _sphere_candidates(self, translation, k, frames, origins, dirs, t_min, t_max):
        """Indices of rays that pass within body k's bounding sphere (ahead of t_min, before t_max);
        translation: (T, 3) body k's origin per frame."""
        centre = rows(translation, frames)
        cx, cy, cz = (centre[:, i] - origins[:, i] for i in range(3))
        dx, dy, dz = dirs[:, 0], dirs[:, 1], dirs[:, 2]
        dd = dx * dx + dy * dy + dz * dz
        cd = cx * dx + cy * dy + cz * dz
        tc = cd / dd  # closest approach along the ray
        dist2 = cx * cx + cy * cy + cz * cz - cd * tc
        r = self.radius[k] * 1.001 + 1e-6
        ok = dist2 <= r * r
        r_t = r / torch.sqrt(dd)
        ok &= tc + r_t > t_min
        if t_max is not None:
            ok &= tc - r_t < t_max
        return torch.nonzero(ok).squeeze(1)

    # ---------------------------------------------------------------------------------------------
    def surface(self, frames: torch.Tensor, origins: torch.Tensor, dirs: torch.Tensor, hits: Hits,
                exact_depth: bool = False, dtype: torch.dtype | None = None) -> dict:
        """Surface data of hit rays. frames: (M,) long; origins, dirs: (M, 3) (pass them in float64 when
        ``exact_depth``); hits: (M,). Computed in ``dtype`` (default: the tracer's).

        Returns ``t (M,)``, ``world_point (M,3)``, ``world_normal (M,3)`` (unit, facing the ray's side)
        and ``local_point (M,3)`` (body frame, metres: where textures live). With ``exact_depth``, also
        ``t_exact (M,)`` in float64 and ``lost (M,)``: tracing decided WHICH body a ray sees; the rays
        whose float32 hit is ill-conditioned are intersected again with that body alone in float64 (all
        rays on curved bodies, whose roots lose digits to cancellation when the camera is many radii
        away, and grazing rays on planes, whose hits amplify rounding). ``lost`` marks rays whose body
        the float64 ray misses altogether (silhouettes): the caller must cast them again in float64.
        """
        dt = dtype or self.dtype
        tables = self._tables[dt]
        refine = exact_depth and dt != torch.float64
        o, d = origins.to(dt), dirs.to(dt)
        t = hits.t.to(dt).clone()
        t_exact = hits.t.to(torch.float64).clone() if exact_depth else None
        lost = torch.zeros_like(hits.t, dtype=torch.bool)
        local = torch.empty_like(o)
        normal = torch.empty_like(o)
        obj = hits.obj.long()
        for k in present_ids(obj):
            body = self.scene.bodies[k]
            idx = torch.nonzero(obj == k).squeeze(1)
            fr = frames[idx]
            if refine and body.shape in CURVED:
                self._refine(k, idx, frames, origins, dirs, t, t_exact, lost)
            a = rows(tables.canon[k], fr)
            o_c, d_c = _affine(a, o[idx]), _linear(a, d[idx])
            t_k = t[idx]
            p_c = torch.stack([oc + t_k * dc for oc, dc in zip(o_c, d_c)], -1)
            n_local = canonical_normal(body.shape, p_c, hits.face[idx], body.r_top) / tables.scale[k]
            n_world = _rotate(rows(tables.rotation[k], fr), n_local)
            n_world = n_world / n_world.norm(dim=-1, keepdim=True)
            local[idx] = p_c * tables.scale[k]
            normal[idx] = n_world
            if refine and body.shape not in CURVED:
                d_k = d[idx]
                cos = (n_world * d_k).sum(-1).abs() / d_k.norm(dim=-1)
                grazing = idx[cos < GRAZING_COS]
                if grazing.numel():
                    self._refine(k, grazing, frames, origins, dirs, t, t_exact, lost)
        if exact_depth and not refine:
            t_exact = t.to(torch.float64)
        out = {"t": t, "world_point": o + t[:, None] * d, "world_normal": normal, "local_point": local}
        if exact_depth:
            out["t_exact"], out["lost"] = t_exact, lost
        return out

    def _refine(self, k, idx, frames, origins, dirs, t, t_exact, lost) -> None:
        """Intersect rays ``idx`` with body k alone in float64; update t_exact, t and lost in place."""
        a64 = rows(self._tables[torch.float64].canon[k], frames[idx])
        o64, d64 = origins[idx].to(torch.float64), dirs[idx].to(torch.float64)
        body = self.scene.bodies[k]
        t_ref, _ = intersect(body.shape, _affine(a64, o64), _linear(a64, d64), 0.0, body.r_top)
        found = torch.isfinite(t_ref)
        t_exact[idx] = torch.where(found, t_ref, t_exact[idx])
        t[idx] = t_exact[idx].to(t.dtype)
        lost[idx] = ~found

    def projected_rects(self, frames: torch.Tensor, cam_to_world: torch.Tensor, intrinsics: torch.Tensor,
                        height: int, width: int, near: float = 1e-3) -> torch.Tensor:
        """Conservative pixel boxes of every body's bounding sphere: (F, K, 4) int [x0, y0, x1, y1).

        The box of the projected corners of the sphere's bounding cube contains the sphere's image
        (perspective maps convex sets in front of the camera to convex sets). Bodies crossing the
        camera plane get the whole image.
        """
        centers = self.translation[frames]  # (F, K, 3)
        rot = cam_to_world[:, :3, :3]
        cc = _rotate(rot.transpose(-1, -2)[:, None], centers - cam_to_world[:, None, :3, 3])  # camera frame
        r = torch.tensor(self.radius, dtype=self.dtype, device=self.device)[None, :, None]
        signs = torch.tensor([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                             dtype=self.dtype, device=self.device)
        corners = cc[:, :, None, :] + signs[None, None] * r[..., None]  # (F, K, 8, 3)
        z = corners[..., 2]
        k = intrinsics[:, None, None]
        x = k[..., 0, 0] * corners[..., 0] / z + k[..., 0, 2]
        y = k[..., 1, 1] * corners[..., 1] / z + k[..., 1, 2]
        rect = torch.stack([x.amin(-1).floor() - 1, y.amin(-1).floor() - 1, x.amax(-1).ceil() + 2,
                            y.amax(-1).ceil() + 2], -1)
        full = torch.tensor([0, 0, width, height], dtype=self.dtype, device=self.device)
        crosses = (z.amin(-1) <= near)[..., None]
        behind = (z.amax(-1) <= near)[..., None]
        rect = torch.where(crosses, full, rect)
        rect = torch.where(behind, torch.zeros_like(rect), rect)
        lo = torch.zeros(4, dtype=self.dtype, device=self.device)
        rect = torch.minimum(torch.maximum(rect, lo), torch.stack([full[2], full[3], full[2], full[3]]))
        return rect.long()


class _BodyTables:
    """Per-body (T, ...) tables in one dtype: canonical maps (T, 3, 4), rotations (T, 3, 3),
    translations (T, 3); and the (K, 3) half-extents."""

    def __init__(self, to_canon, rot, trans, scale, dtype, device):
        def split(array):
            return [torch.as_tensor(np.ascontiguousarray(array[:, k]), dtype=dtype, device=device)
                    for k in range(array.shape[1])]

        self.canon, self.rotation, self.translation = split(to_canon), split(rot), split(trans)
        self.scale = torch.as_tensor(scale, dtype=dtype, device=device)


def rows(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """table[index] along the first axis, through index_select (fast for per-ray gathers)."""
    return table.index_select(0, index)


def present_ids(obj: torch.Tensor) -> list[int]:
    """Sorted body ids that occur in ``obj`` (bincount: much cheaper than a sort-based unique)."""
    return torch.nonzero(torch.bincount(obj.reshape(-1).long())).squeeze(1).tolist()


def _linear(a: torch.Tensor, v):
    """Linear part of (..., 3, 4) maps applied to (..., 3) vectors (or their x, y, z components),
    returned as x, y, z components."""
    x, y, z = (v[..., 0], v[..., 1], v[..., 2]) if isinstance(v, torch.Tensor) else v
    return tuple(a[..., i, 0] * x + a[..., i, 1] * y + a[..., i, 2] * z for i in range(3))


def _affine(a: torch.Tensor, p: torch.Tensor):
    """Maps [L | t] (..., 3, 4) applied to (..., 3) points as L (p - t), returned as x, y, z components."""
    x, y, z = (p[..., i] - a[..., i, 3] for i in range(3))
    return tuple(a[..., i, 0] * x + a[..., i, 1] * y + a[..., i, 2] * z for i in range(3))


def _rotate(r: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotations applied to (..., 3) vectors."""
    x, y, z = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return r[..., :, 0] * x + r[..., :, 1] * y + r[..., :, 2] * z
