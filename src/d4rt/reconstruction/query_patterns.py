"""The query patterns the recipes are made of: arrays of (u, v, t_src, t_tgt, t_cam) rows (paper Tab. 1)."""

from __future__ import annotations

import numpy as np


def grid_queries(uv: np.ndarray, t_src, t_tgt, t_cam) -> np.ndarray:
    """Every position of ``uv`` (P, 2) for every (t_src, t_tgt, t_cam) triple (three (K,) arrays):
    (K * P, 5), frame-major."""
    t_src, t_tgt, t_cam = (np.asarray(x, dtype=np.float64) for x in (t_src, t_tgt, t_cam))
    n = len(uv)
    times = np.stack([t_src, t_tgt, t_cam], 1)
    return np.concatenate([np.tile(uv, (len(times), 1)), np.repeat(times, n, axis=0)], 1)


def track_queries(uv: np.ndarray, t_src: np.ndarray, frames: np.ndarray, cams: np.ndarray) -> np.ndarray:
    """For each source (uv (N, 2), t_src (N,)), one query per frame k of ``frames`` (K,) in camera
    ``cams`` (K,): (N * K, 5), source-major."""
    n, k = len(uv), len(frames)
    q = np.empty((n, k, 5))
    q[..., :2] = uv[:, None]
    q[..., 2] = np.asarray(t_src)[:, None]
    q[..., 3] = frames[None]
    q[..., 4] = cams[None]
    return q.reshape(-1, 5)
