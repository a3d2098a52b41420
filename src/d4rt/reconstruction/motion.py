"""Moving-object masks from queries (not in the paper; a pattern of its queries): which pixels show a surface
that moves in the world.

A pixel's surface point asked at its own time and at another time t', both in the camera of its own frame
(``(u, v, t, t, t)`` and ``(u, v, t, t', t)``), is one point at two times in one camera: a static point gives
the same answer twice, whatever the camera does, so their difference is the point's own motion, free of the
camera's (the same reason the pose recipe fixes t_tgt). Divided by the point's depth it is scale-free, so one
threshold serves a model's arbitrary units, a stitched window's Sim(3) scale and the oracle's metres alike.
The defaults (``d4rt.config.MOTION_TARGETS``, ``MOTION_THRESHOLD``) live in the torch-free config, for the command line.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from d4rt.reconstruction.query_patterns import grid_queries


def target_frames(start: int, stop: int, count: int) -> np.ndarray:
    """``count`` frames (fewer if the window is shorter) spread evenly over the window [start, stop), its
    first and last among them: (K,) int64, increasing."""
    return np.unique(np.round(np.linspace(start, stop - 1, count)).astype(np.int64))


def window_relative_motion(ask: Callable[[np.ndarray], dict], frames: np.ndarray, uv: np.ndarray,
                           targets: np.ndarray) -> np.ndarray:
    """How far each pixel's surface point travels, as a fraction of its depth, at most over ``targets``.

    ask: answers (N, 5) queries of one window (global frame indices) with at least ``points`` (N, 3).
    frames: (F,) frames of that window; uv: (P, 2) normalised positions; targets: (K,) frames of that
    window. Returns (F, P) float64: max over t' of |X(t, t', t) - X(t, t, t)| / z(t, t, t); NaN where the
    point has no finite positive depth (no surface, or the answer says it is behind the camera).
    """
    f, p, k = len(frames), len(uv), len(targets)
    t_src = np.repeat(frames, k + 1)
    t_tgt = np.concatenate([np.concatenate([[t], targets]) for t in frames])
    points = ask(grid_queries(uv, t_src, t_tgt, t_src))["points"].reshape(f, k + 1, p, 3)
    here = points[:, 0]
    depth = here[..., 2]
    travel = np.linalg.norm(points[:, 1:] - here[:, None], axis=-1).max(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        relative = travel / depth
    return np.where(np.isfinite(relative) & (depth > 0), relative, np.nan)
