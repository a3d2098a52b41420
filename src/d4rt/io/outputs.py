"""The arrays a reconstruction's files are written from (the contents of ``reconstruction.npz``):
decoded once by :mod:`d4rt.io.output_plan`, written by :mod:`d4rt.io.writers`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ReconstructionOutputs:
    """Every array the exports write (the contents of ``reconstruction.npz``); None where not computed.

    The arrays that grow with the video (rgb, depth, confidence and the point cloud) may be
    :class:`d4rt.disk_array.DiskArray` s (``compute_outputs(..., spool=DIR)``): the writers read them a
    block of frames at a time.

    Input: rgb (T, H, W, 3) uint8; timestamps (T,) seconds (or frame numbers); fps.
    Depth at the output resolution (h, w): depth (T, h, w) z-depth (all of it: the confidence threshold
    applies to the PNGs and the video), confidence (T, h, w), intrinsics (T, 3, 3) in pixels of the
    depth maps.
    Cameras: video_intrinsics (T, 3, 3) in pixels of the input frames; cam_to_world (T, 4, 4), the world
    being camera 0 (OpenCV axes).
    Point cloud (world, confidence-filtered): points (M, 3), point_colors (M, 3) uint8,
    point_confidence (M,), point_frames (M,) frame seen in (and time shown at), point_pixels (M, 2) its
    (x, y) pixel there.
    Tracks: track_queries (N, 3) [t_src, x, y] input pixels; tracks (N, T, 3) world positions;
    track_visibility (N, T) probability; track_confidence (N, T); track_uv (N, T, 2) normalised 2D
    position (NaN where unknown).
    """

    rgb: np.ndarray
    timestamps: np.ndarray
    fps: float
    min_confidence: float | None = None
    depth: np.ndarray | None = None
    confidence: np.ndarray | None = None
    intrinsics: np.ndarray | None = None
    video_intrinsics: np.ndarray | None = None
    cam_to_world: np.ndarray | None = None
    points: np.ndarray | None = None
    point_colors: np.ndarray | None = None
    point_confidence: np.ndarray | None = None
    point_frames: np.ndarray | None = None
    point_pixels: np.ndarray | None = None
    track_queries: np.ndarray | None = None
    tracks: np.ndarray | None = None
    track_visibility: np.ndarray | None = None
    track_confidence: np.ndarray | None = None
    track_uv: np.ndarray | None = None
    point_dynamic: np.ndarray | None = None  # (M,) bool: on a moving surface (only with the motion-masks output)
    point_offsets: np.ndarray | None = None  # (T + 1,): frame k's points are [offsets[k], offsets[k + 1]) (frame order)
    dense: dict | None = None  # the arrays of dense_tracks.npz (written by that format alone)
    motion: dict | None = None  # the arrays of motion/motion.npz (written by that format alone)
    alignment: np.ndarray | None = None  # (4, 4) Sim(3) every output was carried by (known poses or a scale)
    alignment_rms: float | None = None  # RMS distance of the known camera centres from the carried estimate
    colmap: dict | None = None  # the multi-view points of the COLMAP model (io.colmap_export.multiview_points, colors)

    @property
    def num_frames(self) -> int:
        return self.rgb.shape[0]

    def depth_valid(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """(stop - start, h, w) bool for frames [start, stop) (default: all): finite positive depth at or
        above the confidence threshold."""
        depth = self.depth[start:stop]
        ok = np.isfinite(depth) & (depth > 0)
        if self.min_confidence is not None:
            ok &= self.confidence[start:stop] >= self.min_confidence
        return ok
