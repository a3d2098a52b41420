"""The frames of depth.mp4: the input frame and its depth map side by side, with a colour bar that says
which colour is which depth (in the reconstruction's units)."""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from d4rt.disk_array import frame_blocks

from d4rt.viz.colormaps import colormap, depth_range, depth_to_rgb

BAR_TICKS = 5  # labelled depths on the colour bar, near to far


def depth_video_frames(rgb, depth, valid) -> np.ndarray:
    """rgb: (T, H, W, 3) uint8 input frames; depth: (T, h, w); valid: (T, h, w) bool (invalid: black).
    Returns (T, h', 2 w' + bar, 3) uint8: each frame resized to the depth maps' size, beside its depth
    coloured by inverse depth (near = warm, one scale for the whole video), beside a labelled colour bar.
    Panels are at least 160 pixels high (enlarged with nearest-neighbour) so the labels stay readable.
    (:func:`iter_depth_video_frames` gives the same frames one at a time.)"""
    return np.stack(list(iter_depth_video_frames(rgb, depth, valid)))


# Inverse depths the colour scale's percentiles are taken from: all of them up to this many, else an even
# sample (a long video's maps are not gathered in memory for it).
RANGE_SAMPLES = 1_000_000


def iter_depth_video_frames(rgb, depth, valid):
    """The frames of :func:`depth_video_frames`, one at a time, reading the inputs a block of frames at a
    time (numpy arrays or DiskArrays); valid may be a function (start, stop) -> its rows [start, stop)."""
    rows_of = valid if callable(valid) else (lambda a, b: valid[a:b])
    t, h, w = depth.shape
    scale = max(1, int(np.ceil(160 / h)))
    height, width = h * scale, w * scale
    every = max(1, -(-t * h * w // RANGE_SAMPLES))
    sample = [d[ok][::every] for d, ok in ((depth[a:b], rows_of(a, b)) for a, b in frame_blocks(depth))]
    near, far = depth_range(np.concatenate(sample) if sample else np.zeros(0))
    del sample
    bar = _colour_bar(height, near, far)
    for a, b in frame_blocks(depth):
        coloured = depth_to_rgb(np.where(rows_of(a, b), depth[a:b], 0.0), near, far)
        frames = rgb[a:b]
        for k in range(b - a):
            out = np.empty((height, 2 * width + bar.shape[1], 3), dtype=np.uint8)
            out[:, :width] = np.asarray(Image.fromarray(frames[k]).resize((width, height), Image.BILINEAR))
            out[:, width:2 * width] = np.repeat(np.repeat(coloured[k], scale, 0), scale, 1)
            out[:, 2 * width:] = bar
            yield out


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
