"""One evaluation sequence: frames plus whatever ground truth its benchmark provides.

Every reader returns these, in the project's conventions (README "Conventions"): depth is z in metres
(or the dataset's native unit where it has no metric scale, e.g. Sintel) with 0 where there is no
ground truth; intrinsics are 3x3 pixel matrices with OpenCV pixel centres; poses are camera-to-world
in OpenCV axes; frames are 0-indexed in the order read.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from d4rt.errors import UserError
from d4rt.geometry.camera import unproject_depth
from d4rt.geometry.transforms import apply_transform, invert_rigid
from d4rt.synthetic.clip import Clip


@dataclass(eq=False)
class TrackAnnotations:
    """Ground-truth 3D tracks (TAPVid-3D layout, transposed to this project's names).

    points: (T, N, 3) float64, each frame's point in that frame's camera. visible: (T, N) bool.
    query_frames: (N,) int, the frame each track is queried at. query_xy: (N, 2) float64 pixel (x, y) of
    the query in that frame (OpenCV pixel centres).
    """

    points: np.ndarray
    visible: np.ndarray
    query_frames: np.ndarray
    query_xy: np.ndarray

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64)
        self.visible = np.asarray(self.visible, dtype=bool)
        self.query_frames = np.asarray(self.query_frames, dtype=np.int64)
        self.query_xy = np.asarray(self.query_xy, dtype=np.float64)
        t, n = self.points.shape[:2] if self.points.ndim == 3 else (None, None)
        if self.points.shape != (t, n, 3) or t is None:
            raise UserError(f"track points must have shape (T, N, 3), got {self.points.shape}")
        if self.visible.shape != (t, n):
            raise UserError(f"track visibility must have shape {(t, n)}, got {self.visible.shape}")
        if self.query_frames.shape != (n,) or self.query_xy.shape != (n, 2):
            raise UserError(f"track queries must be ({n},) frames and ({n}, 2) pixels, got "
                            f"{self.query_frames.shape} and {self.query_xy.shape}")
        if n and (self.query_frames.min() < 0 or self.query_frames.max() >= t):
            raise UserError(f"track query frames must lie in [0, {t - 1}]")

    @property
    def num_tracks(self) -> int:
        return self.points.shape[1]


@dataclass(eq=False)
class EvalSequence:
    """Frames and ground truth of one benchmark sequence (shapes as in the module docstring).

    rgb: (T, H, W, 3) uint8. depth: (T, H, W) float32 or None. intrinsics: (T, 3, 3) float64 or None.
    cam_to_world: (T, 4, 4) float64 or None. tracks: :class:`TrackAnnotations` or None. clip: the
    synthetic clip (exact oracle) when the sequence is synthetic. frame_names: one label per frame
    (source file names), for reports. notes: what the reader had to leave out, in words.
    """

    name: str
    rgb: np.ndarray
    depth: np.ndarray | None = None
    intrinsics: np.ndarray | None = None
    cam_to_world: np.ndarray | None = None
    tracks: TrackAnnotations | None = None
    clip: Clip | None = None
    frame_names: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.rgb = np.ascontiguousarray(self.rgb, dtype=np.uint8)
        if self.rgb.ndim != 4 or self.rgb.shape[-1] != 3 or self.rgb.shape[0] == 0:
            raise UserError(f"{self.name}: rgb must have shape (T, H, W, 3) with T >= 1, got {self.rgb.shape}")
        t, h, w = self.rgb.shape[:3]
        for attr, dtype, shape in (("depth", np.float32, (t, h, w)), ("intrinsics", np.float64, (t, 3, 3)),
                                   ("cam_to_world", np.float64, (t, 4, 4))):
            value = getattr(self, attr)
            if value is None:
                continue
            value = np.ascontiguousarray(value, dtype=dtype)
            if value.shape != shape:
                raise UserError(f"{self.name}: {attr} must have shape {shape}, got {value.shape}")
            setattr(self, attr, value)
        if self.tracks is not None and self.tracks.points.shape[0] != t:
            raise UserError(f"{self.name}: tracks have {self.tracks.points.shape[0]} frames, the video {t}")
        if not self.frame_names:
            self.frame_names = [str(i) for i in range(t)]
        if len(self.frame_names) != t:
            raise UserError(f"{self.name}: {len(self.frame_names)} frame names for {t} frames")

    @property
    def num_frames(self) -> int:
        return self.rgb.shape[0]

    @property
    def image_size(self) -> tuple[int, int]:
        """(H, W)."""
        return self.rgb.shape[1], self.rgb.shape[2]

    def world_tracks(self) -> np.ndarray | None:
        """Ground-truth tracks (T, N, 3) moved into the camera of frame 0 (needs tracks and poses)."""
        if self.tracks is None or self.cam_to_world is None:
            return None
        to_first = invert_rigid(self.cam_to_world[0]) @ self.cam_to_world  # camera k -> camera 0
        return apply_transform(to_first[:, None], self.tracks.points)

    def point_map(self) -> np.ndarray | None:
        """Every pixel's ground-truth point (T, H, W, 3) in the camera of frame 0 (needs depth,
        intrinsics and poses); NaN where there is no ground-truth depth."""
        if self.depth is None or self.intrinsics is None or self.cam_to_world is None:
            return None
        depth = np.where(self.depth > 0, self.depth, np.nan).astype(np.float64)
        to_first = invert_rigid(self.cam_to_world[0]) @ self.cam_to_world
        return apply_transform(to_first[:, None, None], unproject_depth(depth, self.intrinsics))
