"""Camera frusta as line segments, for the 3D exports and viewers."""

from __future__ import annotations

import numpy as np

from d4rt.geometry.camera import pixel_rays
from d4rt.geometry.transforms import apply_transform


def frustum_segments(intrinsics: np.ndarray, cam_to_world: np.ndarray, height: int, width: int,
                     depth: float) -> np.ndarray:
    """The pyramid of each camera, from its centre to the image corners at z = ``depth``, plus the image
    rectangle: (T, 8, 2, 3) world-space segments. intrinsics: (T, 3, 3) pixels; cam_to_world: (T, 4, 4)."""
    corners_px = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [width - 0.5, height - 0.5], [-0.5, height - 0.5]])
    corners = pixel_rays(corners_px[None], intrinsics[:, None]) * depth  # (T, 4, 3) camera frame
    corners = apply_transform(cam_to_world[:, None], corners)
    centre = np.broadcast_to(cam_to_world[:, None, :3, 3], corners.shape)
    rays = np.stack([centre, corners], 2)
    rim = np.stack([corners, np.roll(corners, -1, axis=1)], 2)
    return np.concatenate([rays, rim], 1)
