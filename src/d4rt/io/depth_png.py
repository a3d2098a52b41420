"""Depth maps as 16-bit PNGs with one scale per clip, the layout of TUM RGB-D and Open3D
(``depth = value / depth_scale``; 0 = no depth)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from d4rt.disk_array import frame_blocks

MAX_VALUE = 65535
SCALE_FILE = "depth_scale.json"
# zlib level 1: a 16-bit depth map hardly compresses at any level (measured on 48 maps of 128x128: 3% larger
# files than level 6, written 2.8x faster).
PNG_LEVEL = 1


def write_depth_pngs(directory: str | Path, depth, valid) -> float:
    """Write ``directory/000000.png`` ... (uint16) and ``directory/depth_scale.json``.

    depth: (T, H, W) z-depth (numpy or DiskArray); valid: (T, H, W) bool, or a function (start, stop) ->
    the rows [start, stop) of it (False, or non-finite or non-positive depth, is written as 0). The scale
    maps the largest valid depth to 65535, so the quantisation step is max_depth / 65535. Returns the
    scale: depth = value / depth_scale. Frames are read a block at a time (two passes: the scale first).
    """
    directory = Path(directory)
    directory.mkdir()
    rows_of = valid if callable(valid) else (lambda a, b: valid[a:b])

    def blocks():
        for a, b in frame_blocks(depth):
            d = depth[a:b]
            yield a, d, rows_of(a, b) & np.isfinite(d) & (d > 0)

    largest = max((float(d[ok].max()) for _, d, ok in blocks() if ok.any()), default=1.0)
    scale = MAX_VALUE / largest
    for a, d, ok in blocks():
        values = np.where(ok, np.round(np.where(ok, d, 0) * scale), 0).astype(np.uint16)
        for k, frame in enumerate(values):
            Image.fromarray(frame).save(directory / f"{a + k:06d}.png", compress_level=PNG_LEVEL)
    (directory / SCALE_FILE).write_text(json.dumps({
        "depth_scale": scale,
        "meaning": "depth = png_value / depth_scale, in the reconstruction's units (z in the camera "
                   "frame, like reconstruction.npz); 0 = no depth (not valid or below the confidence threshold)",
    }, indent=1))
    return scale


def read_depth_png(path: str | Path, scale: float) -> np.ndarray:
    """One depth PNG back as float (H, W) depth (0 where there is none)."""
    return np.asarray(Image.open(path), dtype=np.float64) / scale
