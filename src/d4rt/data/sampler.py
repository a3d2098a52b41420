"""The paper's training-query sampler (App. A).

Per clip, ``num_queries`` queries (u, v, t_src, t_tgt, t_cam):
- t_src, t_tgt, t_cam uniform over the frames, then t_cam := t_tgt with probability 0.4;
  (not in paper, both off by default) a ``depth_fraction`` of depth queries and an
  ``adjacent_camera_fraction`` of camera-pair queries (t_tgt = t_src, t_cam a neighbouring frame, or up to
  ``camera_pair_max_gap`` frames away);
- a ``boundary_fraction`` (30%) of the (u, v) drawn from pixels within ``boundary_radius`` pixels of a
  depth or motion boundary (Sobel filter on log-depth and on the scene flow), the rest uniform;
  (not in paper, off by default) an ``object_fraction`` of the others drawn from the pixels of foreground
  bodies (``object_ids`` > 0), the rest uniform.
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
    # Share of queries made depth queries (t_src = t_tgt = t_cam), drawn before the rule above; 0 is the
    # paper's sampler, where they are only the ~1/T^2 that the uniform draws give.
    depth_fraction: float = 0.0
    # Share of queries made camera-pair queries (t_tgt = t_src, t_cam = t_src +- 1), drawn after the two rules
    # above (it overrides them); 0 is the paper's sampler. Why: Reconstruction's pose_pairs="adjacent" asks
    # exactly these, and the uniform draws give them only ~2/T of the time.
    adjacent_camera_fraction: float = 0.0
    # (not in paper) The largest gap k of those camera pairs: t_cam = t_src +- k with k drawn uniformly from
    # 1..camera_pair_max_gap (1: the neighbouring frame only, as before). Why: one frame's true travel is a
    # twentieth of the clip's mean depth, half what the tiny models' two answers about one point disagree by,
    # so a one-frame pair prices mostly that disagreement; over k frames the travel and its parallax grow k-fold.
    # Measured (stage 124, docs/training.md): the disagreement grew with the gap as the travel did, the depth paid
    # for it, and no shipped recipe uses it.
    camera_pair_max_gap: int = 1
    # (not in paper, off by default) Give each camera-pair query a twin: another query of the same pixel and
    # frame seen in its own camera (t_tgt = t_cam = t_src), written over a query that is not a pair. Why: the
    # camera chain reads a step's travel from exactly such twins (the same surface point in cameras i and
    # i - 1), and a loss on the pair (``loss.weight_camera_pair``) needs both answers. Stage 86.
    camera_pair_twins: bool = False
    # Share of queries whose (u, v) is drawn from foreground-body pixels (object_ids > 0), among those not drawn
    # from a boundary; 0 is the paper's sampler. Why: uniform draws land mostly on the environment (sky, ground,
    # walls), while a depth map's worst errors are on the bodies in front of it (stage 22's notes: a large
    # object close to the camera, seen against the sky, predicted as far as the sky).
    object_fraction: float = 0.0
    boundary_radius: int = 2  # "within a few pixels" (not in paper): pixels
    depth_edge_threshold: float = 0.05  # Sobel of log-depth per pixel (about a 10% depth step)
    motion_edge_threshold: float = 0.01  # Sobel of scene flow / depth per pixel
    subpixel: bool = True

    def validate(self) -> None:
        if self.num_queries < 1:
            raise UserError(f"num_queries must be >= 1, got {self.num_queries}")
        for name in ("boundary_fraction", "tgt_equals_cam_prob", "depth_fraction", "adjacent_camera_fraction",
                     "object_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise UserError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if not isinstance(self.camera_pair_max_gap, int) or self.camera_pair_max_gap < 1:
            raise UserError(f"camera_pair_max_gap must be an integer >= 1, got {self.camera_pair_max_gap!r}")
        if self.camera_pair_twins and self.adjacent_camera_fraction <= 0:
            raise UserError("camera_pair_twins needs adjacent_camera_fraction > 0 (the pairs it twins)")
        if self.boundary_radius < 0:
            raise UserError(f"boundary_radius must be >= 0, got {self.boundary_radius}")


def _sobel_magnitude(x: torch.Tensor) -> torch.Tensor:
    """Per-pixel gradient magnitude of (T, C, H, W) maps with the 3x3 Sobel filter (/8: units per pixel),
    summed over channels in quadrature -> (T, H, W). Borders replicate."""
    t, c, h, w = x.shape
    p = F.pad(x.reshape(t * c, 1, h, w), (1, 1, 1, 1), mode="replicate")[:, 0]  # (T*C, H+2, W+2)
    # The filter is separable ([1, 2, 1] smoothing times a [-1, 0, 1] difference), and shifted slices of the
    # padded maps do it in a few passes: a one-channel conv2d took about 70% of a loader's sampling time.
    rows = p[:, :-2] + 2 * p[:, 1:-1] + p[:, 2:]                   # (T*C, H, W+2) smoothed down columns
    cols = p[:, :, :-2] + 2 * p[:, :, 1:-1] + p[:, :, 2:]          # (T*C, H+2, W) smoothed along rows
    gx = (rows[:, :, 2:] - rows[:, :, :-2]) / 8.0
    gy = (cols[:, 2:] - cols[:, :-2]) / 8.0
    return torch.sqrt((gx * gx + gy * gy).reshape(t, c, h, w).sum(1))


def scene_flow(clip: Clip, frames=None, window: tuple[int, int, int, int] | None = None) -> torch.Tensor:
    """World-frame 3D motion of every pixel's surface point over one frame step: (F, h, w, 3) float32.

    Frame k uses the step k -> k + 1 (the last frame the step before it); exact from depth, object ids
    and body poses, since the point moves with its rigid body. ``frames`` (default all) and ``window``
    (x0, y0, w, h; default the whole frame) restrict the computation.
    """
    t_count = clip.num_frames
    frames = np.arange(t_count) if frames is None else np.asarray(frames, dtype=np.int64)
    x0, y0, w, h = window or (0, 0, clip.width, clip.height)
    depth = torch.from_numpy(clip.depth[frames, y0:y0 + h, x0:x0 + w]).float()
    if t_count < 2:
        return torch.zeros(depth.shape + (3,))
    k = torch.from_numpy(clip.intrinsics[frames].copy())
    k[:, 0, 2] -= x0  # the window's own pixel grid
    k[:, 1, 2] -= y0
    cam = unproject_depth(depth, k.float())  # (F, h, w, 3)
    c2w = torch.from_numpy(clip.cam_to_world[frames]).float()
    world = torch.einsum("fij,fhwj->fhwi", c2w[:, :3, :3], cam) + c2w[:, None, None, :3, 3]
    a = np.minimum(frames, t_count - 2)
    o2w = clip.object_to_world
    step = torch.from_numpy((o2w[a + 1] @ np.linalg.inv(o2w[a]))[..., :3, :]).float()  # (F, K, 3, 4)
    # One gather of every pixel's body motion: row (frame, body) of the flattened table.
    ids = torch.from_numpy(clip.object_ids[frames, y0:y0 + h, x0:x0 + w].astype(np.int64))
    row = (torch.arange(len(frames))[:, None, None] * o2w.shape[1] + ids).reshape(-1)
    m = step.reshape(-1, 12).index_select(0, row).reshape(depth.shape + (3, 4))
    moved = torch.einsum("fhwij,fhwj->fhwi", m[..., :3], world) + m[..., 3]
    return moved - world


def boundary_mask(clip: Clip, config: QuerySamplerConfig | None = None, frames=None,
                  window: tuple[int, int, int, int] | None = None) -> torch.Tensor:
    """Pixels within ``boundary_radius`` of a depth or motion boundary: (F, h, w) bool for ``frames``
    (default all) inside ``window`` (x0, y0, w, h; default the whole frame).

    The filters run on the window grown by their reach, so a window's mask equals the same crop of the
    whole frame's mask.
    """
    config = config or QuerySamplerConfig()
    x0, y0, w, h = window or (0, 0, clip.width, clip.height)
    r = config.boundary_radius
    margin = 1 + r  # Sobel reach + dilation reach
    gx0, gy0 = max(0, x0 - margin), max(0, y0 - margin)
    gx1, gy1 = min(clip.width, x0 + w + margin), min(clip.height, y0 + h + margin)
    frames = np.arange(clip.num_frames) if frames is None else np.asarray(frames, dtype=np.int64)
    depth = torch.from_numpy(clip.depth[frames, gy0:gy1, gx0:gx1]).float()
    valid = torch.isfinite(depth) & (depth > 0)
    safe = torch.where(valid, depth, torch.ones_like(depth))
    edges = _sobel_magnitude(torch.log(safe)[:, None]) > config.depth_edge_threshold
    flow = scene_flow(clip, frames, (gx0, gy0, gx1 - gx0, gy1 - gy0)) / safe[..., None]
    edges |= _sobel_magnitude(flow.permute(0, 3, 1, 2)) > config.motion_edge_threshold
    if r > 0:
        edges = F.max_pool2d(edges[:, None].float(), 2 * r + 1, stride=1, padding=r)[:, 0] > 0
    return edges[:, y0 - gy0:y0 - gy0 + h, x0 - gx0:x0 - gx0 + w]


def _draw_inside(rng: np.random.Generator, mask: np.ndarray, flagged: np.ndarray, t_src: np.ndarray,
                 rows: np.ndarray, cols: np.ndarray, origin: tuple[int, int]) -> None:
    """Redraw, in place, the pixel of every ``flagged`` query uniformly from ``mask[t_src]`` ((T_view, h, w),
    the crop at ``origin`` = (x0, y0)); a frame whose mask is empty keeps its uniform draws and unflags them."""
    x0, y0 = origin
    for f in np.unique(t_src[flagged]):
        pick = np.nonzero(flagged & (t_src == f))[0]
        ys, xs = np.nonzero(mask[f])
        if ys.size == 0:
            flagged[pick] = False
            continue
        j = rng.integers(0, ys.size, pick.size)
        rows[pick], cols[pick] = ys[j] + y0, xs[j] + x0


class QuerySampler:
    """Draws training queries for a clip (or a view of it) following the paper's recipe."""

    def __init__(self, config: QuerySamplerConfig | None = None):
        self.config = config or QuerySamplerConfig()
        self.config.validate()

    def sample(self, clip: Clip, rng: np.random.Generator, view: View | None = None) -> dict:
        """Queries for ``clip`` seen through ``view`` (default: the whole clip).

        Returns ``queries (N, 5)`` float64 in the view's coordinates and frame indices,
        ``source_queries (N, 5)`` the same queries in the clip's own coordinates, and the per-query flags
        ``from_boundary (N,)``, ``from_object (N,)`` and ``forced_tgt_equals_cam (N,)`` (bool numpy arrays);
        with ``camera_pair_twins`` also ``twin (N,)`` int64, the index of a camera-pair query's twin (the same
        pixel of frame t_src in camera t_src) and -1 for every other query.
        """
        cfg = self.config
        view = view or View.full(clip.num_frames, clip.height, clip.width)
        view.check_frames(clip.num_frames)
        n, t_view = cfg.num_queries, view.num_frames
        x0, y0, w, h = view.crop
        frames = np.asarray(view.frames)
        band = boundary_mask(clip, cfg, frames, view.crop).numpy()  # (T_view, h, w)

        t_src = rng.integers(0, t_view, n)
        t_tgt = rng.integers(0, t_view, n)
        t_cam = rng.integers(0, t_view, n)
        forced = rng.uniform(size=n) < cfg.tgt_equals_cam_prob
        t_cam = np.where(forced, t_tgt, t_cam)
        if cfg.depth_fraction > 0:  # drawn only when asked for: the paper's stream stays as it was
            depth = rng.uniform(size=n) < cfg.depth_fraction
            t_tgt = np.where(depth, t_src, t_tgt)
            t_cam = np.where(depth, t_src, t_cam)
        if cfg.adjacent_camera_fraction > 0 and t_view > 1:  # likewise drawn only when asked for
            pair = rng.uniform(size=n) < cfg.adjacent_camera_fraction
            step = np.where(rng.uniform(size=n) < 0.5, -1, 1)
            if cfg.camera_pair_max_gap > 1:  # drawn only when asked for: the one-frame stream stays as it was
                gap = rng.integers(1, cfg.camera_pair_max_gap + 1, n)
                # No longer than the frames on the longer side of t_src, so one direction always fits.
                step = step * np.minimum(gap, np.maximum(t_src, t_view - 1 - t_src))
            neighbour = t_src + step
            neighbour = np.where((neighbour < 0) | (neighbour >= t_view), t_src - step, neighbour)
            t_tgt = np.where(pair, t_src, t_tgt)
            t_cam = np.where(pair, neighbour, t_cam)
        twin = np.full(n, -1, dtype=np.int64)
        if cfg.camera_pair_twins and t_view > 1:
            pairs, others = np.nonzero(pair)[0], rng.permutation(np.nonzero(~pair)[0])
            k = min(len(pairs), len(others))  # at most half the queries: a pair and its twin
            pairs, twins = pairs[:k], others[:k]
            twin[pairs] = twins
            t_src[twins] = t_tgt[twins] = t_cam[twins] = t_src[pairs]

        n_boundary = int(round(cfg.boundary_fraction * n))
        from_boundary = np.zeros(n, dtype=bool)
        from_boundary[rng.permutation(n)[:n_boundary]] = True
        cols = rng.integers(0, w, n) + x0
        rows = rng.integers(0, h, n) + y0
        _draw_inside(rng, band, from_boundary, t_src, rows, cols, (x0, y0))
        from_object = np.zeros(n, dtype=bool)
        if cfg.object_fraction > 0:  # drawn only when asked for: the paper's stream stays as it was
            others = np.nonzero(~from_boundary)[0]
            from_object[rng.permutation(others)[:int(round(cfg.object_fraction * n))]] = True
            bodies = clip.object_ids[frames, y0:y0 + h, x0:x0 + w] > 0  # (T_view, h, w)
            _draw_inside(rng, bodies, from_object, t_src, rows, cols, (x0, y0))

        jitter = cfg.subpixel and isinstance(clip.oracle, AnalyticOracle)
        ox = rng.uniform(-0.5, 0.5, n) if jitter else np.zeros(n)
        oy = rng.uniform(-0.5, 0.5, n) if jitter else np.zeros(n)
        paired = twin >= 0  # a twin is its pair's very pixel (drawn above with the pair's own rule)
        for values in (cols, rows, ox, oy, from_boundary, from_object):
            values[twin[paired]] = values[paired]
        u_src = (cols + 0.5 + ox) / clip.width
        v_src = (rows + 0.5 + oy) / clip.height
        source = np.stack([u_src, v_src, frames[t_src], frames[t_tgt], frames[t_cam]], 1).astype(np.float64)
        uv_view = view.uv_from_source(source[:, :2])
        queries = np.concatenate([np.clip(uv_view, 0.0, 1.0), np.stack([t_src, t_tgt, t_cam], 1)], 1)
        # The clip above only absorbs float rounding: pixels are drawn inside the crop.
        assert np.abs(queries[:, :2] - uv_view).max() < 1e-9
        drawn = {"queries": queries, "source_queries": source, "from_boundary": from_boundary,
                 "from_object": from_object, "forced_tgt_equals_cam": forced}
        return drawn | {"twin": twin} if cfg.camera_pair_twins else drawn
