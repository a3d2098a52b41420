"""Colour maps for depth, normals and object ids (numpy in, uint8 RGB out)."""

from __future__ import annotations

import numpy as np

# Anchor colours of a perceptually ordered map (dark blue -> cyan -> yellow -> dark red), interpolated.
_ANCHORS = np.array([
    [48, 18, 59], [65, 69, 171], [70, 117, 237], [57, 162, 252], [27, 207, 212], [36, 236, 166],
    [97, 252, 108], [164, 252, 59], [209, 232, 52], [243, 198, 58], [254, 155, 45], [243, 99, 21],
    [217, 56, 6], [177, 25, 1], [122, 4, 3],
], dtype=np.float64)


def colormap(values: np.ndarray) -> np.ndarray:
    """Map values in [0, 1] (any shape) to uint8 RGB (..., 3)."""
    x = np.clip(np.nan_to_num(values, nan=0.0), 0.0, 1.0) * (len(_ANCHORS) - 1)
    i = np.minimum(np.floor(x).astype(int), len(_ANCHORS) - 2)
    f = (x - i)[..., None]
    return np.round(_ANCHORS[i] * (1 - f) + _ANCHORS[i + 1] * f).astype(np.uint8)


def depth_range(depth: np.ndarray) -> tuple[float, float]:
    """(near, far) of the colour scale: the 98th and 2nd percentiles of inverse depth over the valid
    (finite, positive) values, so a few outliers do not wash the colours out."""
    valid = np.isfinite(depth) & (depth > 0)
    if not valid.any():
        return 1.0, np.inf
    inv = 1.0 / depth[valid]
    lo, hi = np.percentile(inv, 2), np.percentile(inv, 98)
    return float(1.0 / hi) if hi > 0 else 1.0, float(1.0 / lo) if lo > 0 else np.inf


def depth_to_rgb(depth: np.ndarray, near: float | None = None, far: float | None = None) -> np.ndarray:
    """Colour depth maps (..., H, W) by inverse depth (near = warm), one range for the whole input
    (default: :func:`depth_range`); invalid pixels are black."""
    valid = np.isfinite(depth) & (depth > 0)
    inv = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0)
    if near is None or far is None:
        auto_near, auto_far = depth_range(depth)
        near, far = near or auto_near, far or auto_far
    lo, hi = 1.0 / far, 1.0 / near
    rgb = colormap((inv - lo) / max(hi - lo, 1e-12))
    rgb[~valid] = 0
    return rgb


def normals_to_rgb(normals: np.ndarray) -> np.ndarray:
    """Unit normals (..., 3) -> RGB as (n + 1) / 2."""
    return np.round((np.clip(normals, -1, 1) + 1) * 127.5).astype(np.uint8)


def ids_to_rgb(ids: np.ndarray) -> np.ndarray:
    """Integer ids (...) -> distinct RGB colours; id 0 (the environment) is dark grey."""
    palette = np.random.default_rng(12345).integers(60, 256, size=(256, 3)).astype(np.uint8)
    palette[0] = 40
    return palette[np.asarray(ids).astype(np.int64) % 256]
