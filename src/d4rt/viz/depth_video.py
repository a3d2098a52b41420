"""The frames of depth.mp4: the input frame and its depth map side by side, with a colour bar that says
which colour is which depth (in the reconstruction's units)."""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from d4rt.viz.colormaps import colormap, depth_range, depth_to_rgb

BAR_TICKS = 5  # labelled depths on the colour bar, near to far


def depth_video_frames(rgb: np.ndarray, depth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """rgb: (T, H, W, 3) uint8 input frames; depth: (T, h, w); valid: (T, h, w) bool (invalid: black).
    Returns (T, h', 2 w' + bar, 3) uint8: each frame resized to the depth maps' size, beside its depth
    coloured by inverse depth (near = warm, one scale for the whole video), beside a labelled colour bar.
    Panels are at least 160 pixels high (enlarged with nearest-neighbour) so the labels stay readable."""
    t, h, w = depth.shape
    scale = max(1, int(np.ceil(160 / h)))
    height, width = h * scale, w * scale
    near, far = depth_range(np.where(valid, depth, np.nan))
    coloured = depth_to_rgb(np.where(valid, depth, 0.0), near, far)
    bar = _colour_bar(height, near, far)
    out = np.empty((t, height, 2 * width + bar.shape[1], 3), dtype=np.uint8)
    for k in range(t):
        out[k, :, :width] = np.asarray(Image.fromarray(rgb[k]).resize((width, height), Image.BILINEAR))
        out[k, :, width:2 * width] = np.repeat(np.repeat(coloured[k], scale, 0), scale, 1)
    out[:, :, 2 * width:] = bar
    return out


def _colour_bar(height: int, near: float, far: float) -> np.ndarray:
    """(height, width, 3): near (top) to far (bottom), evenly spaced in inverse depth as the map is, with
    BAR_TICKS depth labels."""
    font = ImageFont.load_default()
    labels = [_format_depth(1.0 / v) for v in np.linspace(1.0 / near, 1.0 / far if np.isfinite(far) else 0.0,
                                                           BAR_TICKS) if v > 0]
    text_width = max(int(font.getlength(s)) for s in labels + ["far"]) + 4
    strip = 12
    image = Image.new("RGB", (strip + text_width + 4, height), (255, 255, 255))
    ramp = colormap(np.linspace(1.0, 0.0, height))  # top: near (warm)
    image.paste(Image.fromarray(np.repeat(ramp[:, None], strip, 1)), (2, 0))
    draw = ImageDraw.Draw(image)
    for i, label in enumerate(labels):
        y = int(round(i * (height - 1) / (BAR_TICKS - 1)))
        draw.line([(strip + 2, y), (strip + 5, y)], fill=(0, 0, 0))
        draw.text((strip + 6, min(max(y - 5, 0), height - 11)), label, fill=(0, 0, 0), font=font)
    return np.asarray(image)


def _format_depth(value: float) -> str:
    return f"{value:.3g}"
