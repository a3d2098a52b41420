"""Tracks drawn over the video: each 3D track projected into every frame's camera, as a dot where it is
visible and a fading tail of its recent visible positions."""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw

from d4rt.geometry.camera import project
from d4rt.geometry.transforms import apply_transform, invert_rigid
from d4rt.disk_array import frame_blocks
from d4rt.viz.colormaps import colormap


def project_tracks(points: np.ndarray, intrinsics: np.ndarray,
                   cam_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World tracks (N, T, 3) -> their pixel positions (N, T, 2) in each frame's camera (OpenCV centres)
    and depths (N, T). intrinsics: (T, 3, 3); cam_to_world: (T, 4, 4)."""
    in_camera = apply_transform(invert_rigid(cam_to_world)[None], points)
    return project(in_camera, intrinsics[None])


def track_colors(start_xy: np.ndarray, width: int) -> np.ndarray:
    """(N, 3) uint8: a rainbow over the tracks' starting columns, so neighbours share a hue."""
    return colormap(np.clip((start_xy[:, 0] + 0.5) / width, 0, 1))


def draw_tracks(rgb: np.ndarray, xy: np.ndarray, visible: np.ndarray, colors: np.ndarray, tail: int = 8) -> np.ndarray:
    """Frames (T, H, W, 3) uint8 with tracks drawn on them. xy: (N, T, 2) pixels; visible: (N, T) bool
    (NaN or hidden positions are not drawn); colors: (N, 3) uint8; tail: frames of trail behind each dot.
    (:func:`iter_drawn_tracks` gives the same frames one at a time.)"""
    return np.stack(list(iter_drawn_tracks(rgb, xy, visible, colors, tail)))


def iter_drawn_tracks(rgb, xy: np.ndarray, visible: np.ndarray, colors: np.ndarray, tail: int = 8):
    """The frames of :func:`draw_tracks` one at a time, reading ``rgb`` (numpy or DiskArray) a block of
    frames at a time."""
    t, h, w = rgb.shape[:3]
    radius = max(1.0, min(h, w) / 120)
    ok = visible & np.isfinite(xy).all(-1)
    for a, b in frame_blocks(rgb):
        block = rgb[a:b]
        for k in range(a, b):
            image = Image.fromarray(block[k - a])
            draw = ImageDraw.Draw(image, "RGBA")
            for j in range(max(0, k - tail), k):
                alpha = int(255 * (j - k + tail + 1) / (tail + 1))
                both = np.nonzero(ok[:, j] & ok[:, j + 1])[0]
                for n in both:
                    draw.line([tuple(xy[n, j]), tuple(xy[n, j + 1])], fill=(*colors[n], alpha),
                              width=max(1, int(radius)))
            for n in np.nonzero(ok[:, k])[0]:
                x, y = xy[n, k]
                draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=tuple(colors[n]))
            yield np.asarray(image)
