"""Exact ray casting through a synthetic scene at any frame: the one geometric core that both the
renderer and the ground-truth oracle use.

A ``SceneTracer`` holds, on one device and dtype, every body's world-to-canonical transform for every
frame. ``trace_grid`` casts whole frames (bodies culled to their projected bounding boxes),
``trace_rays`` casts arbitrary rays each tagged with its frame (bodies culled by a bounding-sphere
test), and ``surface`` turns hits into world points, normals and body-frame texture coordinates.

Inside, vectors and per-ray matrices are kept as contiguous component planes (a (3, N) tensor for N
vectors, (12, N) for N 3x4 maps): elementwise work on (N, 3) rows is several times slower on the CPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from d4rt.geometry.transforms import apply_rotation
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
        # Per-body tables in the tracing dtype and in float64 (exact ground truth where float32 is
        # ill-conditioned, see ``surface``).
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
        tables = self._tables[self.dtype]
        planes = [c.contiguous() for c in dirs.unbind(-1)]
        o_planes = [c.contiguous() for c in origins.unbind(-1)]
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
            a = tables.canon[k].index_select(1, frames)  # (12, F): one map per frame
            o_c = tuple(c[:, None, None] for c in _affine(a, o_planes))
            d_c = _linear(a[:, :, None, None], [c[:, y0:y1, x0:x1] for c in planes])
            t, face = intersect(body.shape, o_c, d_c, t_min, body.r_top)
            tb = best_t[:, y0:y1, x0:x1]
            nearer = t < tb
            tb.copy_(torch.where(nearer, t, tb))
            best_obj[:, y0:y1, x0:x1].masked_fill_(nearer, k)
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
        o_all, d_all = origins.to(dtype).T.contiguous(), dirs.to(dtype).T.contiguous()  # (3, N)
        n = o_all.shape[1]
        best_t = torch.full((n,), float("inf"), dtype=dtype, device=self.device)
        best_obj = torch.zeros((n,), dtype=torch.uint8, device=self.device)
        best_face = torch.zeros((n,), dtype=torch.uint8, device=self.device)
        for k, body in enumerate(self.scene.bodies):
            if k == 0 and not include_environment:
                continue
            if k == 0:
                fr, o, d, cur = frames, o_all, d_all, best_t
            else:
                idx = self._sphere_candidates(tables.translation[k], k, frames, o_all, d_all, t_min, t_max)
                if idx.numel() == 0:
                    continue
                fr, o, d, cur = frames[idx], o_all[:, idx], d_all[:, idx], best_t[idx]
            a = tables.canon[k].index_select(1, fr)
            t, face = intersect(body.shape, _affine(a, o), _linear(a, d), t_min, body.r_top)
            nearer = t < cur
            if k == 0:
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
        """Indices of rays (origins, dirs: (3, N) planes) passing within body k's bounding sphere, ahead
        of t_min and before t_max; translation: (3, T) body k's origin per frame."""
        centre = translation.index_select(1, frames)
        cx, cy, cz = (centre[i] - origins[i] for i in range(3))
        dx, dy, dz = dirs
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
        o_all, d_all = origins.to(dt).T.contiguous(), dirs.to(dt).T.contiguous()  # (3, M)
        t = hits.t.to(dt).clone()
        t_exact = hits.t.to(torch.float64).clone() if exact_depth else None
        lost = torch.zeros_like(hits.t, dtype=torch.bool)
        local = torch.empty_like(o_all)
        normal = torch.empty_like(o_all)
        obj = hits.obj.long()
        for k in present_ids(obj):
            body = self.scene.bodies[k]
            idx = torch.nonzero(obj == k).squeeze(1)
            fr = frames[idx]
            if refine and body.shape in CURVED:
                self._refine(k, idx, frames, origins, dirs, t, t_exact, lost)
            a = tables.canon[k].index_select(1, fr)
            d_k = d_all[:, idx]
            o_c, d_c = _affine(a, o_all[:, idx]), _linear(a, d_k)
            t_k = t[idx]
            p_c = torch.stack([oc + t_k * dc for oc, dc in zip(o_c, d_c)])  # (3, m)
            s = tables.scale[k][:, None]
            n_local = canonical_normal(body.shape, p_c.T, hits.face[idx], body.r_top).T / s
            n_world = torch.stack(_rotate(tables.rotation[k].index_select(1, fr), n_local))
            n_world = n_world / torch.sqrt(_dot(n_world, n_world))
            local[:, idx] = p_c * s
            normal[:, idx] = n_world
            if refine and body.shape not in CURVED:
                cos = _dot(n_world, d_k).abs() / torch.sqrt(_dot(d_k, d_k))
                grazing = idx[cos < GRAZING_COS]
                if grazing.numel():
                    self._refine(k, grazing, frames, origins, dirs, t, t_exact, lost)
        if exact_depth and not refine:
            t_exact = t.to(torch.float64)
        out = {"t": t, "world_point": (o_all + t * d_all).T, "world_normal": normal.T, "local_point": local.T}
        if exact_depth:
            out["t_exact"], out["lost"] = t_exact, lost
        return out

    def _refine(self, k, idx, frames, origins, dirs, t, t_exact, lost) -> None:
        """Intersect rays ``idx`` with body k alone in float64; update t_exact, t and lost in place."""
        a64 = self._tables[torch.float64].canon[k].index_select(1, frames[idx])
        o64, d64 = (x[idx].to(torch.float64).T for x in (origins, dirs))
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
        cc = apply_rotation(rot.transpose(-1, -2)[:, None], centers - cam_to_world[:, None, :3, 3])  # camera frame
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
    """Per-body tables over frames in one dtype, component-major so per-ray gathers are contiguous:
    canonical maps [L | t] (12, T), body-to-world rotations (9, T), body origins (3, T); and the
    (K, 3) half-extents."""

    def __init__(self, to_canon, rot, trans, scale, dtype, device):
        def split(array):  # (T, K, ...) -> per body (prod(...), T)
            t_count, k_count = array.shape[:2]
            flat = array.reshape(t_count, k_count, -1)
            return [torch.as_tensor(np.ascontiguousarray(flat[:, k].T), dtype=dtype, device=device)
                    for k in range(k_count)]

        self.canon, self.rotation, self.translation = split(to_canon), split(rot), split(trans)
        self.scale = torch.as_tensor(scale, dtype=dtype, device=device)


def present_ids(obj: torch.Tensor) -> list[int]:
    """Sorted body ids that occur in ``obj`` (bincount: much cheaper than a sort-based unique)."""
    return torch.nonzero(torch.bincount(obj.reshape(-1).long())).squeeze(1).tolist()


def _linear(a: torch.Tensor, v) -> tuple:
    """The linear part L of maps a = [L | t] (12, ...) applied to vectors given as 3 components."""
    x, y, z = v
    return tuple(a[4 * i] * x + a[4 * i + 1] * y + a[4 * i + 2] * z for i in range(3))


def _affine(a: torch.Tensor, p) -> tuple:
    """Maps a = [L | t] (12, ...) applied to points given as 3 components: L (p - t)."""
    x, y, z = (p[i] - a[4 * i + 3] for i in range(3))
    return tuple(a[4 * i] * x + a[4 * i + 1] * y + a[4 * i + 2] * z for i in range(3))


def _rotate(r: torch.Tensor, v) -> tuple:
    """Rotations r (9, ...) (row-major 3x3) applied to vectors given as 3 components."""
    x, y, z = v
    return tuple(r[3 * i] * x + r[3 * i + 1] * y + r[3 * i + 2] * z for i in range(3))


def _dot(a, b) -> torch.Tensor:
    """Dot products of vectors given as 3 components each."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
