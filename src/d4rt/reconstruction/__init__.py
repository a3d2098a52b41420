"""Everything from queries: depth, point clouds, 3D tracks, cameras, dense tracking, moving-object masks, long
videos."""

from d4rt.reconstruction.reconstruction import Reconstruction
from d4rt.reconstruction.results import Cameras, DenseTracks, Depth, MotionMasks, PointCloud, Tracks
from d4rt.reconstruction.sources import AnswererSource, ModelSource
from d4rt.reconstruction.windows import plan_windows

__all__ = [
    "AnswererSource",
    "Cameras",
    "DenseTracks",
    "Depth",
    "ModelSource",
    "MotionMasks",
    "PointCloud",
    "Reconstruction",
    "Tracks",
    "plan_windows",
]
