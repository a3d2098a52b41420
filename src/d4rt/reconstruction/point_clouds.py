"""Point clouds from depth maps and cameras: once depth and cameras are decoded, every depth pixel
unprojected and moved into the world is a point cloud that costs no further query.

The paper's direct recipe (:meth:`d4rt.reconstruction.Reconstruction.point_cloud`: each pixel queried
with t_cam fixed) decodes every pixel a second time; on exact answers (the oracle) both give the same
points, on a model they differ by how well its depth and its cameras agree with its direct answers.
"""

from __future__ import annotations

import numpy as np

from d4rt.geometry.camera import pixel_rays
from d4rt.geometry.transforms import apply_transform
from d4rt.reconstruction.results import PointCloud


def point_cloud_from_depth(depth: np.ndarray, confidence: np.ndarray, intrinsics: np.ndarray,
                           cam_to_world: np.ndarray, video: np.ndarray, stride: int = 1) -> PointCloud:
    """Every ``stride``-th pixel of every depth map, unprojected and mapped into the world.

    depth, confidence: (T, h, w); intrinsics: (T, 3, 3) in pixels of the depth maps; cam_to_world:
    (T, 4, 4); video: (T, H, W, 3) uint8, the input frames (any size: each point takes the colour of the
    input pixel under its depth pixel's centre). Points with non-finite or non-positive depth or
    confidence are dropped. Returns a PointCloud in the world of ``cam_to_world`` (reference frame 0), its
    ``pixels`` in input-frame pixels (integers) and its ``frames`` the frame of each point.
    """
    t, h, w = depth.shape
    height, width = video.shape[1:3]
    rows, cols = np.arange(0, h, stride), np.arange(0, w, stride)
    d = depth[:, rows][:, :, cols].astype(np.float64)
    c = confidence[:, rows][:, :, cols]
    # Only the strided pixel centres are unprojected (the intrinsics are those of the h x w maps).
    pixel_x, pixel_y = np.meshgrid(cols.astype(np.float64), rows.astype(np.float64))
    rays = pixel_rays(np.stack([pixel_x, pixel_y], -1)[None], intrinsics[:, None, None])
    world = apply_transform(cam_to_world[:, None, None], rays * d[..., None])
    ys = np.minimum(((rows + 0.5) * height / h).astype(np.int64), height - 1)
    xs = np.minimum(((cols + 0.5) * width / w).astype(np.int64), width - 1)
    grid_y, grid_x = np.meshgrid(ys, xs, indexing="ij")
    frames = np.broadcast_to(np.arange(t)[:, None, None], d.shape)
    keep = np.isfinite(d) & (d > 0) & np.isfinite(c) & (c > 0) & np.isfinite(world).all(-1)
    f, py, px = frames[keep], np.broadcast_to(grid_y, d.shape)[keep], np.broadcast_to(grid_x, d.shape)[keep]
    return PointCloud(world[keep].astype(np.float32), video[f, py, px], c[keep].astype(np.float32), f.astype(np.int64),
                      np.stack([px, py], 1), 0)
