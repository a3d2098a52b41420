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

from d4rt.geometry.camera import project
from d4rt.geometry.transforms import apply_transform, invert_rigid, rotation_to_quaternion

PINHOLE = 1  # COLMAP camera model id: params fx, fy, cx, cy
_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("point3D_id", "<i8")])


def multiview_points(world: np.ndarray, uv: np.ndarray, visibility: np.ndarray, sources: np.ndarray,
                     intrinsics: np.ndarray, cam_to_world: np.ndarray, height: int, width: int,
                     max_error: float | None = None, frames: np.ndarray | None = None) -> dict:
    """COLMAP points from 3D tracks: each track's position at its source frame, observed at its 2D track
    position in every frame where it is visible, inside the image, and where that position reprojects
    within ``max_error`` pixels (default: 1% of the longer image side) - the filter COLMAP itself applies.
    A moving point is so one 3D point only while it stays put, and a poorly tracked one is dropped.

    world: (N, K, 3) track positions in the world; uv: (N, K, 2) normalised 2D positions (the observed
    pixels); visibility: (N, K); sources: (N,) source frames; frames: (N, K) the frame of each column
    (-1: none; default: column k is frame k, K = T), the source frame among them; intrinsics (T, 3, 3),
    cam_to_world (T, 4, 4); height, width: of the frames. Tracks observed in fewer than 2 frames are dropped.
    Returns the kept track indices ``index (P,)``, ``xyz (P, 3)``, the observations ``obs_point (K,)``
    (into the kept points), ``obs_frame (K,)``, ``obs_xy (K, 2)`` OpenCV pixels, and ``error (P,)`` each
    point's mean reprojection error in pixels (xyz through each observing camera vs. its observation).
    """
    n, k = visibility.shape
    frames = np.broadcast_to(np.arange(k), (n, k)) if frames is None else np.asarray(frames)
    max_error = 0.01 * max(height, width) if max_error is None else max_error
    at_source = frames == np.asarray(sources)[:, None]
    if n and not at_source.any(1).all():
        raise ValueError("every track needs its source frame among its columns")
    xyz = world[np.arange(n), at_source.argmax(1)]
    xy = uv * [width, height] - 0.5
    world_to_cam = invert_rigid(cam_to_world)
    residual, z = np.full((n, k), np.inf), np.zeros((n, k))
    for f in np.unique(frames[frames >= 0]):  # one camera at a time: no (N, K, 4, 4) pose array
        rows, cols = np.nonzero(frames == f)
        projected, z[rows, cols] = project(apply_transform(world_to_cam[f], xyz[rows]), intrinsics[f])
        residual[rows, cols] = np.linalg.norm(projected - xy[rows, cols], axis=-1)
    inside = np.all((uv >= 0) & (uv <= 1), axis=-1)
    with np.errstate(invalid="ignore"):
        seen = (frames >= 0) & (visibility > 0.5) & inside & (z > 0) & (residual <= max_error)
    seen &= np.isfinite(xyz).all(-1)[:, None]
    keep = np.nonzero(seen.sum(1) >= 2)[0]
    rows, cols = np.nonzero(seen[keep])
    error = np.bincount(rows, residual[keep][rows, cols], len(keep)) / np.maximum(np.bincount(rows, minlength=len(keep)), 1)
    return {"index": keep, "xyz": xyz[keep], "obs_point": rows, "obs_frame": frames[keep][rows, cols],
            "obs_xy": xy[keep][rows, cols], "error": error}


def write_colmap(directory: str | Path, rgb: np.ndarray, intrinsics: np.ndarray, cam_to_world: np.ndarray,
                 xyz: np.ndarray, colors: np.ndarray, obs_point: np.ndarray, obs_frame: np.ndarray,
                 obs_xy: np.ndarray, error: np.ndarray) -> Path:
    """Write a COLMAP model of every frame.

    rgb: (T, H, W, 3) uint8 frames (written as ``images/000000.png`` ...); intrinsics: (T, 3, 3) pixels
    (OpenCV centres); cam_to_world: (T, 4, 4); xyz: (P, 3) world points, colors: (P, 3) uint8, error:
    (P,) mean reprojection error in pixels; their observations: point ``obs_point (K,)`` seen in frame
    ``obs_frame (K,)`` at OpenCV pixel ``obs_xy (K, 2)`` (see :func:`multiview_points`). One shared
    PINHOLE camera when every frame has the same intrinsics, else one per frame. Image i has id i + 1,
    point j has id j + 1.
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
    order = np.lexsort((obs_point, obs_frame))  # observations grouped by image
    starts = np.searchsorted(obs_frame[order], np.arange(t + 1))
    obs_index = np.empty(len(obs_point), dtype=np.int32)  # each observation's index in its image
    with open(sparse / "images.bin", "wb") as f:
        f.write(np.uint64(t).tobytes())
        for i in range(t):
            mine = order[starts[i]:starts[i + 1]]
            obs_index[mine] = np.arange(len(mine))
            f.write(np.array([i + 1], dtype="<i4").tobytes())
            f.write(np.concatenate([quats[i], world_to_cam[i, :3, 3]]).astype("<f8").tobytes())
            f.write(np.array([camera_of[i]], dtype="<i4").tobytes() + names[i].encode() + b"\0")
            obs = np.empty(len(mine), dtype=_POINT2D)
            obs["x"], obs["y"] = obs_xy[mine, 0] + 0.5, obs_xy[mine, 1] + 0.5
            obs["point3D_id"] = obs_point[mine] + 1
            f.write(np.uint64(len(mine)).tobytes() + obs.tobytes())

    by_point = np.argsort(obs_point, kind="stable")
    track_length = np.bincount(obs_point, minlength=len(xyz))
    with open(sparse / "points3D.bin", "wb") as f:
        f.write(np.uint64(len(xyz)).tobytes())
        track_starts = np.concatenate([[0], np.cumsum(track_length)])
        for j in range(len(xyz)):
            mine = by_point[track_starts[j]:track_starts[j + 1]]
            f.write(np.array([j + 1], dtype="<u8").tobytes() + np.asarray(xyz[j], dtype="<f8").tobytes()
                    + np.asarray(colors[j], dtype="u1").tobytes() + np.array([error[j]], dtype="<f8").tobytes()
                    + np.array([len(mine)], dtype="<u8").tobytes())
            pairs = np.empty(len(mine), dtype=[("image_id", "<i4"), ("point2D_idx", "<i4")])
            pairs["image_id"], pairs["point2D_idx"] = obs_frame[mine] + 1, obs_index[mine]
            f.write(pairs.tobytes())
    return directory
