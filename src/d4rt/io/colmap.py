"""A COLMAP sparse model (binary ``cameras.bin``, ``images.bin``, ``points3D.bin``) plus its images, in
the layout Gaussian-splatting and NeRF tools read: ``images/`` and ``sparse/0/``.

COLMAP's conventions differ from d4rt's in two ways, both converted here:
- poses are world-to-camera (rotation as a quaternion w, x, y, z, and a translation);
- pixel coordinates put the centre of the top-left pixel at (0.5, 0.5) (d4rt / OpenCV: (0, 0)), so
  principal points and 2D observations are shifted by +0.5.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from d4rt.geometry.transforms import invert_rigid, rotation_to_quaternion

PINHOLE = 1  # COLMAP camera model id: params fx, fy, cx, cy
_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("point3D_id", "<i8")])
_POINT3D = np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("error", "<f8"), ("track_length", "<u8"),
                     ("image_id", "<i4"), ("point2D_idx", "<i4")])


def write_colmap(directory: str | Path, rgb: np.ndarray, intrinsics: np.ndarray, cam_to_world: np.ndarray,
                 points: np.ndarray, colors: np.ndarray, frames: np.ndarray, pixels: np.ndarray) -> Path:
    """Write a COLMAP model of every frame.

    rgb: (T, H, W, 3) uint8 frames (written as ``images/000000.png`` ...); intrinsics: (T, 3, 3) pixels
    (OpenCV centres); cam_to_world: (T, 4, 4); points: (M, 3) world points, each observed once, in
    frame ``frames (M,)`` at OpenCV pixel ``pixels (M, 2)``; colors: (M, 3) uint8. One shared PINHOLE
    camera when every frame has the same intrinsics, else one per frame. Image i has id i + 1, point j
    has id j + 1; the reprojection error is not known and is written as 0.
    """
    directory = Path(directory)
    sparse = directory / "sparse" / "0"
    images = directory / "images"
    sparse.mkdir(parents=True)
    images.mkdir()
    t, h, w = rgb.shape[:3]
    names = [f"{i:06d}.png" for i in range(t)]
    for frame, name in zip(rgb, names):
        Image.fromarray(frame).save(images / name)

    shared = bool(np.all(intrinsics == intrinsics[:1]))
    camera_of = np.ones(t, dtype=np.int32) if shared else np.arange(1, t + 1, dtype=np.int32)
    with open(sparse / "cameras.bin", "wb") as f:
        ks = intrinsics[:1] if shared else intrinsics
        f.write(np.uint64(len(ks)).tobytes())
        for cam_id, k in enumerate(ks, start=1):
            f.write(np.array([cam_id, PINHOLE], dtype="<i4").tobytes() + np.array([w, h], dtype="<u8").tobytes())
            f.write(np.array([k[0, 0], k[1, 1], k[0, 2] + 0.5, k[1, 2] + 0.5], dtype="<f8").tobytes())

    world_to_cam = invert_rigid(cam_to_world)
    quats = rotation_to_quaternion(world_to_cam[:, :3, :3])[:, [3, 0, 1, 2]]  # COLMAP stores (w, x, y, z)
    order = np.argsort(frames, kind="stable")
    starts = np.searchsorted(frames[order], np.arange(t + 1))
    point2d_idx = np.empty(len(points), dtype=np.int32)
    with open(sparse / "images.bin", "wb") as f:
        f.write(np.uint64(t).tobytes())
        for i in range(t):
            mine = order[starts[i]:starts[i + 1]]
            point2d_idx[mine] = np.arange(len(mine))
            f.write(np.array([i + 1], dtype="<i4").tobytes())
            f.write(np.concatenate([quats[i], world_to_cam[i, :3, 3]]).astype("<f8").tobytes())
            f.write(np.array([camera_of[i]], dtype="<i4").tobytes() + names[i].encode() + b"\0")
            obs = np.empty(len(mine), dtype=_POINT2D)
            obs["x"], obs["y"] = pixels[mine, 0] + 0.5, pixels[mine, 1] + 0.5
            obs["point3D_id"] = mine + 1
            f.write(np.uint64(len(mine)).tobytes() + obs.tobytes())

    records = np.zeros(len(points), dtype=_POINT3D)
    records["id"] = np.arange(1, len(points) + 1)
    records["xyz"], records["rgb"], records["track_length"] = points, colors, 1
    records["image_id"], records["point2D_idx"] = frames + 1, point2d_idx
    with open(sparse / "points3D.bin", "wb") as f:
        f.write(np.uint64(len(points)).tobytes() + records.tobytes())
    return directory
