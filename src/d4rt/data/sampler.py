"""The paper's training-query sampler (App. A).

Per clip, ``num_queries`` queries (u, v, t_src, t_tgt, t_cam):
- t_src, t_tgt, t_cam uniform over the frames, then t_cam := t_tgt with probability 0.4;
- a ``boundary_fraction`` (30%) of the (u, v) drawn from pixels within ``boundary_radius`` pixels of a
  depth or motion boundary (Sobel filter on log-depth and on the scene flow), the rest uniform.
Pixels are drawn on the source clip's pixel grid (inside a view's crop when one is given) and then
expressed in the view's coordinates, so every query stays exactly answerable by the oracle; with an
analytic oracle the position is jittered uniformly inside its pixel (``subpixel``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from d4rt.errors import UserError
from d4rt.geometry.camera import unproject_depth
from d4rt.geometry.view import View
from d4rt.synthetic.clip import Clip
from d4rt.synthetic.oracle import AnalyticOracle


@dataclass
class QuerySamplerConfig:
    """Knobs of the sampler; defaults are the paper's where it gives them."""

    num_queries: int = 2048
    boundary_fraction: float = 0.3
    tgt_equals_cam_prob: float = 0.4
    boundary_radius: int = 2  # "within a few pixels" (not in paper): pixels
    depth_edge_threshold: float = 0.05  # Sobel of log-depth per pixel (about a 10% depth step)
    motion_edge_threshold: float = 0.01  # Sobel of scene flow / depth per pixel
    subpixel: bool = True

    def validate(self) -> None:
        if self.num_queries < 1:
            raise UserError(f"num_queries must be >= 1, got {self.num_queries}")
        for name in ("boundary_fraction", "tgt_equals_cam_prob"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise UserError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if self.boundary_radius < 0:
            raise UserError(f"boundary_radius must be >= 0, got {self.boundary_radius}")


def _sobel_magnitude(x: torch.Tensor) -> torch.Tensor:
    """Per-pixel gradient magnitude of (T, C, H, W) maps with the 3x3 Sobel filter (/8: units per pixel),
    summed over channels in quadrature -> (T, H, W). Borders replicate."""
    kx = torch.tensor([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]], dtype=x.dtype) / 8.0
    k = torch.stack([kx, kx.T])[:, None]  # (2, 1, 3, 3)
    t, c, h, w = x.shape
    padded = F.pad(x.reshape(t * c, 1, h, w), (1, 1, 1, 1), mode="replicate")
    g = F.conv2d(padded, k).reshape(t, c, 2, h, w)
    return torch.sqrt((g * g).sum((1, 2)))


def scene_flow(clip: Clip) -> torch.Tensor:
    """World-frame 3D motion of every pixel's surface point over one frame step: (T, H, W, 3) float64.

    Frame k uses the step k -> k + 1 (the last frame the step before it). Exact from depth, object ids
    and body poses: the point moves with its rigid body.
    """
    t_count = clip.num_frames
    depth = torch.from_numpy(clip.depth).double()
    if t_count < 2:
        return torch.zeros(depth.shape + (3,), dtype=torch.float64)
    cam = unproject_depth(depth, torch.from_numpy(clip.intrinsics))  # (T, H, W, 3)
    c2w = torch.from_numpy(clip.cam_to_world)
    world = torch.einsum("tij,thwj->thwi", c2w[:, :3, :3], cam) + c2w[:, None, None, :3, 3]
    a = torch.clamp(torch.arange(t_count), max=t_count - 2)
    o2w = torch.from_numpy(clip.object_to_world)
    step = o2w[a + 1] @ torch.linalg.inv(o2w[a])  # (T, K, 4, 4): each body's motion over the step
    ids = torch.from_numpy(clip.object_ids).long()
    frame = torch.arange(t_count)[:, None, None].expand_as(ids)
    flow = torch.zeros_like(world)
    for k in torch.nonzero(torch.bincount(ids.reshape(-1))).squeeze(1).tolist():
        m = ids == k
        p, f = world[m], frame[m]
        r = step[f, k]
        flow[m] = torch.einsum("nij,nj->ni", r[:, :3, :3], p) + r[:, :3, 3] - p
    return flow


def boundary_mask(clip: Clip, config: QuerySamplerConfig | None = None) -> torch.Tensor:
    """Pixels within ``boundary_radius`` of a depth or motion boundary: (T, H, W) bool."""
    config = config or QuerySamplerConfig()
    depth = torch.from_numpy(clip.depth).double()
    valid = torch.isfinite(depth) & (depth > 0)
    log_depth = torch.log(torch.where(valid, depth, torch.ones_like(depth)))
    edges = _sobel_magnitude(log_depth[:, None]) > config.depth_edge_threshold
    flow = scene_flow(clip) / torch.where(valid, depth, torch.ones_like(depth))[..., None]
    edges |= _sobel_magnitude(flow.permute(0, 3, 1, 2)) > config.motion_edge_threshold
    r = config.boundary_radius
    if r > 0:
        edges = F.max_pool2d(edges[:, None].float(), 2 * r + 1, stride=1, padding=r)[:, 0] > 0
    return edges


class QuerySampler:
    """Draws training queries for a clip (or a view of it) following the paper's recipe."""

    def __init__(self, config: QuerySamplerConfig | None = None):
        self.config = config or QuerySamplerConfig()
        self.config.validate()

    def sample(self, clip: Clip, rng: np.random.Generator, view: View | None = None,
               boundaries: torch.Tensor | None = None) -> dict:
        """Queries for ``clip`` seen through ``view`` (default: the whole clip).

        Returns ``queries (N, 5)`` float64 in the view's coordinates and frame indices,
        ``source_queries (N, 5)`` the same queries in the clip's own coordinates, and the per-query flags
        ``from_boundary (N,)`` and ``forced_tgt_equals_cam (N,)`` (bool numpy arrays).
        """
        cfg = self.config
        view = view or View.full(clip.num_frames, clip.height, clip.width)
        view.check_frames(clip.num_frames)
        if boundaries is None:
            boundaries = boundary_mask(clip, cfg)
        n, t_view = cfg.num_queries, view.num_frames
        x0, y0, w, h = view.crop
        frames = np.asarray(view.frames)

        t_src = rng.integers(0, t_view, n)
        t_tgt = rng.integers(0, t_view, n)
        t_cam = rng.integers(0, t_view, n)
        forced = rng.uniform(size=n) < cfg.tgt_equals_cam_prob
        t_cam = np.where(forced, t_tgt, t_cam)

        n_boundary = int(round(cfg.boundary_fraction * n))
        from_boundary = np.zeros(n, dtype=bool)
        from_boundary[rng.permutation(n)[:n_boundary]] = True
        cols = rng.integers(0, w, n) + x0
        rows = rng.integers(0, h, n) + y0
        band = boundaries[frames][:, y0:y0 + h, x0:x0 + w].numpy()
        for f in np.unique(t_src[from_boundary]):
            pick = np.nonzero(from_boundary & (t_src == f))[0]
            ys, xs = np.nonzero(band[f])
            if ys.size == 0:  # no boundary in this frame of the crop: these queries stay uniform
                from_boundary[pick] = False
                continue
            j = rng.integers(0, ys.size, pick.size)
            rows[pick], cols[pick] = ys[j] + y0, xs[j] + x0

        jitter = cfg.subpixel and isinstance(clip.oracle, AnalyticOracle)
        ox = rng.uniform(-0.5, 0.5, n) if jitter else np.zeros(n)
        oy = rng.uniform(-0.5, 0.5, n) if jitter else np.zeros(n)
        u_src = (cols + 0.5 + ox) / clip.width
        v_src = (rows + 0.5 + oy) / clip.height
        source = np.stack([u_src, v_src, frames[t_src], frames[t_tgt], frames[t_cam]], 1).astype(np.float64)
        uv_view = view.uv_from_source(source[:, :2])
        queries = np.concatenate([np.clip(uv_view, 0.0, 1.0), np.stack([t_src, t_tgt, t_cam], 1)], 1)
        # The clip above only absorbs float rounding: pixels are drawn inside the crop.
        assert np.abs(queries[:, :2] - uv_view).max() < 1e-9
        return {"queries": queries, "source_queries": source, "from_boundary": from_boundary,
                "forced_tgt_equals_cam": forced}
