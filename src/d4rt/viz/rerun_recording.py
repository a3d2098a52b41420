"""A rerun recording (.rrd) of a reconstruction, with a ``frame`` timeline: per frame, the camera (pose,
pinhole, image), that frame's points, the depth map, and the tracks' recent trails. Open it with
``rerun reconstruction.rrd``. Needs the optional ``rerun-sdk`` package (``pip install 'd4rt[viewer]'``).

Rerun's pinhole puts the centre of the top-left pixel at (0.5, 0.5), so principal points are shifted by
+0.5 from d4rt's OpenCV convention; the world is camera 0 with OpenCV axes (rerun's "RDF").
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

FLUSH_EVERY = 8  # frames
TRAIL = 8  # frames of track history drawn at each time


def rerun_available() -> bool:
    return importlib.util.find_spec("rerun") is not None


def write_rrd(path: str | Path, rgb: np.ndarray, depth: np.ndarray, intrinsics: np.ndarray, cam_to_world: np.ndarray,
              points: np.ndarray, colors: np.ndarray, point_frames: np.ndarray, tracks: np.ndarray,
              track_visible: np.ndarray, track_colors: np.ndarray, timestamps: np.ndarray | None = None,
              point_offsets: np.ndarray | None = None) -> Path:
    """rgb: (T, H, W, 3) uint8; depth: (T, h, w) (0 = none); intrinsics: (T, 3, 3) for rgb's size;
    cam_to_world: (T, 4, 4); points: (M, 3) world, colors (M, 3) uint8, point_frames (M,); tracks:
    (N, T, 3) world, track_visible (N, T) bool, track_colors (N, 3) uint8; timestamps: (T,) seconds
    (adds a ``time`` timeline) or None; point_offsets: (T + 1,) when the points are in frame order (frame
    k's are [offsets[k], offsets[k + 1])): then each frame's are read alone (the arrays may be DiskArrays)."""
    import rerun as rr

    path = Path(path)
    rec = rr.RecordingStream("d4rt")
    rec.save(path)
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    t, h, w = rgb.shape[:3]
    if point_offsets is None:
        order = np.argsort(point_frames, kind="stable")
        starts = np.searchsorted(point_frames[order], np.arange(t + 1))
    for k in range(t):
        rec.set_time("frame", sequence=k)
        if timestamps is not None:
            rec.set_time("time", duration=float(timestamps[k] - timestamps[0]))
        rec.log("world/camera", rr.Transform3D(translation=cam_to_world[k, :3, 3], mat3x3=cam_to_world[k, :3, :3]))
        pinhole = intrinsics[k].copy()
        pinhole[:2, 2] += 0.5
        rec.log("world/camera/image", rr.Pinhole(image_from_camera=pinhole, resolution=[w, h],
                                                 camera_xyz=rr.ViewCoordinates.RDF))
        rec.log("world/camera/image", rr.Image(rgb[k]))
        rec.log("depth", rr.DepthImage(depth[k]))
        mine = slice(point_offsets[k], point_offsets[k + 1]) if point_offsets is not None else order[starts[k]:starts[k + 1]]
        rec.log("world/points", rr.Points3D(points[mine], colors=colors[mine]))
        if len(tracks):
            trails = []
            for n in range(len(tracks)):
                seen = track_visible[n, max(0, k - TRAIL):k + 1]
                trail = tracks[n, max(0, k - TRAIL):k + 1][seen]
                trails.append(trail if len(trail) > 1 else np.zeros((0, 3)))
            now = track_visible[:, k]
            rec.log("world/tracks", rr.LineStrips3D(trails, colors=track_colors))
            rec.log("world/tracks/now", rr.Points3D(tracks[now, k], colors=track_colors[now]))
        if k % FLUSH_EVERY == FLUSH_EVERY - 1:
            rec.flush()  # waits until the frames so far are on disk: rerun holds at most this many in memory
    rec.flush()
    rec.disconnect()
    return path
