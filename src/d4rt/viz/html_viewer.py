"""A self-contained HTML page to explore a reconstruction offline: per-frame point clouds, camera frusta
and track trails, with play/pause, a frame slider and orbit / pan / zoom. Everything (data and the small
canvas renderer in ``d4rt/assets/viewer/``) is inlined: no network, no libraries, any modern browser."""

from __future__ import annotations

import base64
import html
import json
from importlib.resources import files
from pathlib import Path

import numpy as np

MAX_POINTS = 200_000  # the page stays a few MB and renders interactively


def even_subset(count: int, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` of ``count`` points, evenly spaced (every point when they fit):
    a cloud stored frame by frame keeps every frame's share, and no index array as long as the cloud is
    made."""
    if count <= max_points:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, max_points).round().astype(np.int64))


def _b64(array: np.ndarray, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode("ascii")


def write_html(path: str | Path, points: np.ndarray, colors: np.ndarray, point_frames: np.ndarray,
               cam_to_world: np.ndarray, frusta: np.ndarray, tracks: np.ndarray, track_visible: np.ndarray,
               track_colors: np.ndarray, fps: float, timestamps: np.ndarray | None = None, title: str = "d4rt",
               max_points: int = MAX_POINTS) -> Path:
    """points: (M, 3) world, colors: (M, 3) uint8, point_frames: (M,) frame of each point; cam_to_world:
    (T, 4, 4); frusta: (T, S, 2, 3) world segments; tracks: (N, T, 3) world, track_visible: (N, T) bool,
    track_colors: (N, 3) uint8; fps: playback rate; timestamps: (T,) seconds or None. At most
    ``max_points`` points are kept (:func:`even_subset`: the point arrays may be DiskArrays)."""
    t = len(cam_to_world)
    keep = even_subset(len(points), max_points)
    points, colors, point_frames = points[keep], colors[keep], point_frames[keep]
    order = np.argsort(point_frames, kind="stable")
    points, colors = points[order], colors[order]
    offsets = np.searchsorted(point_frames[order], np.arange(t + 1))
    centres = cam_to_world[:, :3, 3]
    scene = np.concatenate([points, centres]) if len(points) else centres
    # Start behind and a little above camera 0, looking at the middle of the scene.
    target = np.median(scene, axis=0)
    ahead = target - centres[0]
    reach = float(np.linalg.norm(ahead))
    if reach < 1e-9:
        ahead, reach = np.array([0.0, 0.0, 1.0]), float(np.percentile(np.linalg.norm(scene - target, axis=1), 90))
    ahead = ahead / np.linalg.norm(ahead)
    data = {
        "num_frames": t,
        "fps": float(fps),
        "timestamps": None if timestamps is None else [float(s) for s in timestamps],
        "points": _b64(points, "<f4"),
        "colors": _b64(colors, np.uint8),
        "frame_offsets": [int(o) for o in offsets],
        "camera_centres": _b64(centres, "<f4"),
        "frusta": _b64(frusta, "<f4"),
        "frustum_segments": int(frusta.shape[1]),
        "num_tracks": int(len(tracks)),
        "tracks": _b64(tracks, "<f4"),
        "track_visible": _b64(track_visible, np.uint8),
        "track_colors": _b64(track_colors, np.uint8),
        "view_target": [float(v) for v in target],
        "view_yaw": float(np.arctan2(ahead[0], ahead[2])),
        "view_pitch": float(np.arcsin(np.clip(ahead[1], -1, 1)) + 0.35),
        "view_distance": float(max(1.8 * reach, 1e-6)),
    }
    viewer = files("d4rt") / "assets" / "viewer"
    page = (viewer / "viewer.html").read_text(encoding="utf-8")
    script = (viewer / "viewer.js").read_text(encoding="utf-8")
    # JSON of numbers, base64 and escaped titles cannot contain "</script>"; the script is ours.
    page = page.replace("__SCRIPT__", script)
    page = page.replace("__DATA__", json.dumps(data, separators=(",", ":")).replace("</", "<\\/"))
    page = page.replace("__TITLE__", html.escape(title))  # last: a title cannot name a placeholder
    path = Path(path)
    path.write_text(page, encoding="utf-8")
    return path
