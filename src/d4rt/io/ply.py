"""Point clouds as binary little-endian PLY files (readable by MeshLab, Open3D, CloudCompare, Blender)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.disk_array import frame_blocks

_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                    ("confidence", "<f4"), ("frame", "<i4")])


def write_ply(path: str | Path, points: np.ndarray, colors: np.ndarray, confidence: np.ndarray,
              frames: np.ndarray) -> Path:
    """Write a coloured point cloud.

    points: (M, 3) float (numpy arrays or DiskArrays, read a block at a time); colors: (M, 3) uint8 RGB; confidence: (M,); frames: (M,) the frame each point
    was seen in. Each vertex has x, y, z (float32), red, green, blue (uint8), confidence (float32) and
    frame (int32).
    """
    m = len(points)
    if points.shape != (m, 3) or colors.shape != (m, 3) or confidence.shape != (m,) or frames.shape != (m,):
        raise UserError(f"point cloud arrays disagree: points {points.shape}, colors {colors.shape}, "
                        f"confidence {confidence.shape}, frames {frames.shape}")
    header = ["ply", "format binary_little_endian 1.0", "comment written by d4rt", f"element vertex {m}"]
    header += [f"property {kind} {name}" for name, kind in
               (("x", "float"), ("y", "float"), ("z", "float"), ("red", "uchar"), ("green", "uchar"),
                ("blue", "uchar"), ("confidence", "float"), ("frame", "int"))]
    header.append("end_header")
    path = Path(path)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        for a, b in frame_blocks(points, frames_per_block=1 << 20):  # a block at a time: it may live on disk
            vertices = np.empty(b - a, dtype=_VERTEX)
            xyz = points[a:b]
            for i, axis in enumerate("xyz"):
                vertices[axis] = xyz[:, i]
            rgb = colors[a:b]
            for i, channel in enumerate(("red", "green", "blue")):
                vertices[channel] = rgb[:, i]
            vertices["confidence"] = confidence[a:b]
            vertices["frame"] = frames[a:b]
            f.write(vertices.tobytes())
    return path
