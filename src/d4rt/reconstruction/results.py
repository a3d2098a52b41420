"""The results of the query recipes: plain containers of numpy arrays with documented shapes.

Conventions as everywhere in d4rt: OpenCV camera axes, camera-to-world 4x4 poses, intrinsics in pixels
(OpenCV pixel centres), frames 0-indexed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Depth:
    """depth: (T, H, W) z-depth; confidence: (T, H, W) (higher is more certain)."""

    depth: np.ndarray
    confidence: np.ndarray


@dataclass
class MotionMasks:
    """Which pixels show a moving surface (``Reconstruction.motion_masks``).

    relative_motion: (T, H, W) float32, how far each pixel's surface point travels in the world between its
    frame and the target frames of its window, as a fraction of its depth (NaN: no surface); dynamic: (T, H, W)
    bool, relative_motion > threshold; target_frames: (T, K) int64, the frames each frame was compared with."""

    relative_motion: np.ndarray
    dynamic: np.ndarray
    threshold: float
    target_frames: np.ndarray


@dataclass
class Cameras:
    """intrinsics: (T, 3, 3) pixels, for the input video's size; cam_to_world: (T, 4, 4), where the
    world is the camera of ``reference_frame`` (identity there)."""

    intrinsics: np.ndarray
    cam_to_world: np.ndarray
    reference_frame: int = 0


@dataclass
class PointCloud:
    """points: (M, 3) in the camera of ``reference_frame``; colors: (M, 3) uint8; confidence: (M,);
    frames: (M,) the frame each point was seen in (and the time it is shown at); pixels: (M, 2) its
    (x, y) pixel there."""

    points: np.ndarray
    colors: np.ndarray
    confidence: np.ndarray
    frames: np.ndarray
    pixels: np.ndarray
    reference_frame: int = 0

    def filtered(self, keep: np.ndarray) -> PointCloud:
        """The points where ``keep (M,)`` is True."""
        return PointCloud(self.points[keep], self.colors[keep], self.confidence[keep], self.frames[keep],
                          self.pixels[keep], self.reference_frame)


@dataclass
class Tracks:
    """points: (N, T, 3) position at every frame k, in camera k (``frame == "camera"``) or in the camera
    of ``reference_frame`` (``frame == "world"``); visibility: (N, T) probability of being visible in
    frame k; confidence: (N, T); uv: (N, T, 2) normalised position in frame k. NaN where a track could
    not be carried into a window (see Reconstruction.tracks)."""

    points: np.ndarray
    visibility: np.ndarray
    confidence: np.ndarray
    uv: np.ndarray
    frame: str = "camera"
    reference_frame: int = 0


@dataclass
class DenseTracks:
    """Algorithm 1 of the paper: tracks started from unvisited (t, x, y) cells of an occupancy grid
    until every cell of every frame is covered.

    tracks: the full-video tracks (N tracks); sources: (N, 3) [t, x, y] they start from;
    num_queries: queries decoded; naive_num_queries: T * T * H * W (every pixel of every frame tracked
    through every frame); coverage: fraction of the (T, H, W) cells a track passes through visibly (or
    starts from); resolution: (H, W) of the grid.
    """

    tracks: Tracks
    sources: np.ndarray
    num_queries: int
    naive_num_queries: int
    coverage: float
    resolution: tuple[int, int]

    @property
    def query_reduction(self) -> float:
        """How many times fewer queries than the naive all-pairs recipe."""
        return self.naive_num_queries / max(self.num_queries, 1)
