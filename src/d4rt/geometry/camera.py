"""The pinhole camera model and the project's image-coordinate conventions.

Conventions (README.md, "Conventions"):
- OpenCV camera axes: x right, y down, z forward; depth is z in the camera frame.
- Intrinsics K (3, 3) map camera points to continuous pixel coordinates in which the centre of pixel
  (row i, column j) is (x, y) = (j, i), as in OpenCV. So a principal point at the image centre is
  ((W - 1) / 2, (H - 1) / 2).
- Normalised coordinates: u = (x + 0.5) / W, v = (y + 0.5) / H, so the image spans [0, 1] and pixel
  centres sit at (j + 0.5) / W.
All functions work on numpy arrays or torch tensors of any leading shape.
"""

from __future__ import annotations

import numpy as np
import torch

Array = np.ndarray | torch.Tensor


def uv_to_pixel(uv: Array, height: int, width: int) -> Array:
    """Normalised (u, v) -> continuous pixel (x, y). uv: (..., 2) -> (..., 2)."""
    x = uv[..., 0] * width - 0.5
    y = uv[..., 1] * height - 0.5
    return _stack([x, y], uv)


def pixel_to_uv(xy: Array, height: int, width: int) -> Array:
    """Continuous pixel (x, y) -> normalised (u, v). xy: (..., 2) -> (..., 2)."""
    u = (xy[..., 0] + 0.5) / width
    v = (xy[..., 1] + 0.5) / height
    return _stack([u, v], xy)


def pixel_grid(height: int, width: int, stride: int = 1) -> np.ndarray:
    """Every ``stride``-th pixel centre of an image, row-major: (N, 2) float64 (x, y), N = ceil(H / stride)
    * ceil(W / stride)."""
    ys, xs = np.meshgrid(np.arange(0, height, stride), np.arange(0, width, stride), indexing="ij")
    return np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)


def cell_centres_uv(n: int) -> np.ndarray:
    """The centres of an n x n grid of equal cells over the image in normalised (u, v), row-major:
    (n * n, 2) float64. A grid independent of the image's size (the camera recipe's and the track grid)."""
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c)
    return np.stack([u.ravel(), v.ravel()], 1)


def project(points: Array, intrinsics: Array) -> tuple[Array, Array]:
    """Camera-frame points -> pixel coordinates and depth.

    points: (..., 3) camera frame; intrinsics: (..., 3, 3) broadcastable to the points.
    Returns (xy (..., 2), z (...)). Points with z <= 0 get non-finite or meaningless xy: mask on z.
    """
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    fx, fy = intrinsics[..., 0, 0], intrinsics[..., 1, 1]
    cx, cy, skew = intrinsics[..., 0, 2], intrinsics[..., 1, 2], intrinsics[..., 0, 1]
    px = (fx * x + skew * y) / z + cx
    py = fy * y / z + cy
    return _stack([px, py], points), z


def pixel_rays(xy: Array, intrinsics: Array) -> Array:
    """Pixel (x, y) -> camera-frame ray directions with z = 1, so that depth * ray is the 3D point.

    xy: (..., 2); intrinsics: (..., 3, 3) broadcastable. Returns (..., 3).
    """
    fx, fy = intrinsics[..., 0, 0], intrinsics[..., 1, 1]
    cx, cy, skew = intrinsics[..., 0, 2], intrinsics[..., 1, 2], intrinsics[..., 0, 1]
    ry = (xy[..., 1] - cy) / fy
    rx = (xy[..., 0] - cx - skew * ry) / fx
    one = rx * 0 + 1
    return _stack([rx, ry, one], xy)


def unproject_depth(depth: Array, intrinsics: Array) -> Array:
    """Depth map(s) -> camera-frame points of every pixel centre.

    depth: (..., H, W) z-depth; intrinsics: (..., 3, 3). Returns (..., H, W, 3).
    """
    h, w = depth.shape[-2:]
    if isinstance(depth, torch.Tensor):
        ys, xs = torch.meshgrid(
            torch.arange(h, dtype=depth.dtype, device=depth.device),
            torch.arange(w, dtype=depth.dtype, device=depth.device),
            indexing="ij",
        )
        xy = torch.stack([xs, ys], -1)
        k = intrinsics.to(depth.dtype)[..., None, None, :, :]
    else:
        ys, xs = np.meshgrid(np.arange(h, dtype=depth.dtype), np.arange(w, dtype=depth.dtype), indexing="ij")
        xy = np.stack([xs, ys], -1)
        k = np.asarray(intrinsics)[..., None, None, :, :]
    return pixel_rays(xy, k) * depth[..., None]


def _stack(parts: list, like: Array) -> Array:
    if isinstance(like, torch.Tensor):
        return torch.stack(parts, -1)
    return np.stack(parts, -1)
