"""Depth maps as 16-bit PNGs with one scale per clip, the layout of TUM RGB-D and Open3D
(``depth = value / depth_scale``; 0 = no depth)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

MAX_VALUE = 65535
SCALE_FILE = "depth_scale.json"


def write_depth_pngs(directory: str | Path, depth: np.ndarray, valid: np.ndarray) -> float:
    """Write ``directory/000000.png`` ... (uint16) and ``directory/depth_scale.json``.

    depth: (T, H, W) z-depth; valid: (T, H, W) bool (False, or non-finite or non-positive depth, is
    written as 0). The scale maps the largest valid depth to 65535, so the quantisation step is
    max_depth / 65535. Returns the scale: depth = value / depth_scale.
    """
    directory = Path(directory)
    directory.mkdir()
    valid = valid & np.isfinite(depth) & (depth > 0)
    largest = float(depth[valid].max()) if valid.any() else 1.0
    scale = MAX_VALUE / largest
    values = np.where(valid, np.round(np.where(valid, depth, 0) * scale), 0).astype(np.uint16)
    for t, frame in enumerate(values):
        Image.fromarray(frame).save(directory / f"{t:06d}.png")
    (directory / SCALE_FILE).write_text(json.dumps({
        "depth_scale": scale,
        "meaning": "depth = png_value / depth_scale, in the reconstruction's units (z in the camera "
                   "frame, like reconstruction.npz); 0 = no depth (not valid or below the confidence threshold)",
    }, indent=1))
    return scale


def read_depth_png(path: str | Path, scale: float) -> np.ndarray:
    """One depth PNG back as float (H, W) depth (0 where there is none)."""
    return np.asarray(Image.open(path), dtype=np.float64) / scale
