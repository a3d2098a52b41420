"""Shot cuts in a video: where the picture jumps to another view, so that each shot is reconstructed on
its own instead of being stitched through the cut (one world, one camera path per shot).

The test is a frame difference: the distance between the colour histograms of consecutive frames (8
levels per channel, 512 bins; half the L1 distance, in [0, 1]: 0 same colours, 1 none shared). A cut is
a difference that is both large (above ``threshold``) and a spike: ``contrast`` times the median of the
differences around it, so fast camera motion, which changes every frame a lot, is not taken for cuts.
Measured on 80 synthetic clips (d4rt generate) and their 79 junctions: junctions 0.62-1.0 (spike >= 11),
within clips at most 0.51 (spike <= 4.7); the bundled TUM frames at most 0.40 (spike 2.3).
"""

from __future__ import annotations

import numpy as np

from d4rt.disk_array import frame_blocks

DEFAULT_THRESHOLD = 0.3
DEFAULT_CONTRAST = 5.0
NEIGHBOURS = 3  # differences on each side that a spike is compared with


def frame_differences(rgb) -> np.ndarray:
    """rgb: (T, H, W, 3) uint8 (numpy or DiskArray, read a block of frames at a time) -> (T - 1,)
    colour-histogram distance between frames k and k + 1, in [0, 1]."""
    hist = np.zeros((len(rgb), 512))
    for a, b in frame_blocks(rgb, bytes_per_block=16 << 20):
        levels = (rgb[a:b] >> 5).astype(np.int32)  # 8 levels per channel
        bins = (levels[..., 0] * 64 + levels[..., 1] * 8 + levels[..., 2]).reshape(b - a, -1)
        hist[a:b] = np.stack([np.bincount(row, minlength=512) for row in bins]) / bins.shape[1]
    return 0.5 * np.abs(np.diff(hist, axis=0)).sum(1)


def detect_cuts(rgb: np.ndarray, threshold: float = DEFAULT_THRESHOLD, contrast: float = DEFAULT_CONTRAST) -> list[int]:
    """The frames that start a new shot (never 0), in order. rgb: (T, H, W, 3) uint8."""
    diff = frame_differences(rgb)
    cuts = []
    for k, d in enumerate(diff):
        around = np.concatenate([diff[max(0, k - NEIGHBOURS):k], diff[k + 1:k + 1 + NEIGHBOURS]])
        typical = max(float(np.median(around)), 0.02) if len(around) else 0.0  # 0.02: a floor for still video
        if d > threshold and d > contrast * typical:
            cuts.append(k + 1)
    return cuts


def shot_ranges(num_frames: int, cuts: list[int]) -> list[tuple[int, int]]:
    """[start, stop) of each shot of a video of ``num_frames`` frames cut before the frames in ``cuts``."""
    edges = [0, *cuts, num_frames]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:])]
