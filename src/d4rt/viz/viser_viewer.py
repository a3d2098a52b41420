"""An interactive viewer of a finished reconstruction in the browser, driven from Python (viser).

``d4rt view OUT_DIR`` reads what ``d4rt reconstruct`` wrote (``reconstruction.npz``, and the frames from
``colmap/images/`` when present) and serves a 3D scene: a timeline (play / pause / scrub / speed), the
points of the current frame or of every frame so far, a confidence threshold, the point size, camera
frusta (with the frame image) and the camera path, and 3D tracks with trails of a chosen length,
coloured moving (orange) or static (blue) by how far each travels in the world.

Scene axes are d4rt's world (camera 0, OpenCV: y down), shown with -y up. Researchers can script it:
``Viewer(ViewerData.load(path), server)`` adds everything to any ``viser.ViserServer``, and ``viewer.frame``
sets the time.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.geometry.transforms import rotation_to_quaternion

MAX_POINTS_PER_FRAME = 60_000  # sent to the browser per frame (more are subsampled): scrubbing stays smooth
IMAGE_SIDE = 160  # frustum images are downsized to this longer side
MOVING_FRACTION = 0.03  # a track is moving when it travels more than this fraction of the scene's extent


@dataclass
class ViewerData:
    """What the viewer shows, from a ``d4rt reconstruct`` output folder.

    cam_to_world: (T, 4, 4); intrinsics: (T, 3, 3) of the input frames; size: (H, W) of the input;
    points: (N, 3) world; colors: (N, 3) uint8; confidence: (N,); frames: (N,) the frame of each point;
    tracks: (M, T, 3) world (NaN where unknown); track_visibility: (M, T); images: (T, h, w, 3) uint8 or
    None; fps: playback rate of the video.
    """

    cam_to_world: np.ndarray
    intrinsics: np.ndarray
    size: tuple[int, int]
    points: np.ndarray
    colors: np.ndarray
    confidence: np.ndarray
    frames: np.ndarray
    tracks: np.ndarray
    track_visibility: np.ndarray
    images: np.ndarray | None
    fps: float

    @property
    def num_frames(self) -> int:
        return len(self.cam_to_world)

    @classmethod
    def load(cls, folder: str | Path) -> "ViewerData":
        folder = Path(folder)
        npz = folder / "reconstruction.npz"
        if not folder.is_dir():
            raise UserError(f"{folder} is not a folder (d4rt view takes the output folder of d4rt reconstruct)")
        if not npz.is_file():
            shots = sorted(folder.glob("shot_*/reconstruction.npz"))
            hint = f"; this video was cut into shots: view one of {', '.join(p.parent.name for p in shots)}" if shots else ""
            raise UserError(f"{folder} has no reconstruction.npz (written by d4rt reconstruct with the npz output){hint}")
        try:
            with np.load(npz, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as err:
            raise UserError(f"cannot read {npz}: {err}") from err
        needed = ("cam_to_world", "video_intrinsics", "video_size", "points", "point_colors", "point_confidence",
                  "point_frames", "tracks", "track_visibility", "fps")
        missing = [k for k in needed if k not in data]
        if missing:
            raise UserError(f"{npz} lacks {', '.join(missing)}: not an output of this version of d4rt reconstruct")
        t = len(data["cam_to_world"])
        return cls(data["cam_to_world"], data["video_intrinsics"], tuple(int(v) for v in data["video_size"]),
                   data["points"], data["point_colors"], data["point_confidence"], data["point_frames"],
                   data["tracks"], data["track_visibility"], _frame_images(folder / "colmap" / "images", t),
                   float(data["fps"]))


def _frame_images(folder: Path, count: int) -> np.ndarray | None:
    """The input frames written beside the COLMAP model, downsized; None when they are not all there."""
    from PIL import Image

    files = sorted(folder.glob("*.png")) + sorted(folder.glob("*.jpg"))
    if len(files) != count:
        return None
    images = []
    for path in files:
        with Image.open(path) as image:
            scale = IMAGE_SIDE / max(image.size)
            small = image.convert("RGB").resize((max(1, round(image.width * scale)), max(1, round(image.height * scale))))
            images.append(np.asarray(small))
    return np.stack(images)


def moving_tracks(tracks: np.ndarray, extent: float, fraction: float = MOVING_FRACTION) -> np.ndarray:
    """(M,) bool: tracks whose world positions spread over more than ``fraction`` of ``extent``."""
    spread = np.nanmax(tracks, axis=1) - np.nanmin(tracks, axis=1) if tracks.size else np.zeros((0, 3))
    return np.nan_to_num(np.linalg.norm(spread, axis=-1)) > fraction * extent


class Viewer:
    """The scene and its controls on a viser server (see the module docstring)."""

    def __init__(self, data: ViewerData, server):
        self.data, self.server = data, server
        self._lock = threading.Lock()
        self._stop = threading.Event()
        finite = data.points[np.isfinite(data.points).all(1)]
        centre = np.median(finite, 0) if len(finite) else np.zeros(3)
        self.extent = float(np.percentile(np.linalg.norm(finite - centre, axis=1), 90)) if len(finite) else 1.0
        server.scene.set_up_direction("-y")
        # Start behind and above camera 0 (at the origin, looking along +z), looking at the scene's middle.
        server.initial_camera.look_at = centre
        server.initial_camera.position = np.array([0.0, -0.6, -1.2]) * max(self.extent, float(np.linalg.norm(centre)))
        self._build_gui()
        self._build_static_scene()
        self._clouds: list = []
        self._rebuild_clouds()
        self._track_handle = None
        self._show(0)
        self._player = threading.Thread(target=self._play_loop, daemon=True)
        self._player.start()

    # -------------------------------------------------------------------------------------------- GUI
    def _build_gui(self) -> None:
        gui, t = self.server.gui, self.data.num_frames
        with gui.add_folder("Playback"):
            self.timeline = gui.add_slider("Frame", 0, max(t - 1, 1), 1, 0, disabled=t < 2)
            self.playing = gui.add_checkbox("Playing", False)
            self.speed = gui.add_slider("Speed (x)", 0.25, 4.0, 0.25, 1.0)
        with gui.add_folder("Points"):
            low, high = (float(np.min(self.data.confidence)), float(np.max(self.data.confidence))) \
                if len(self.data.confidence) else (0.0, 1.0)
            step = max((high - low) / 100, 1e-6)
            self.min_confidence = gui.add_slider("Min confidence", low, max(high, low + step), step, low,
                                                 hint="the model's own scale: higher is more certain")
            self.point_size = gui.add_slider("Point size", 0.001, 0.05, 0.001, 0.01)
            self.accumulate = gui.add_checkbox("All frames so far", False)
        with gui.add_folder("Cameras and tracks"):
            self.show_cameras = gui.add_checkbox("Camera frusta", True)
            self.trail = gui.add_slider("Track trail (frames)", 0, max(t - 1, 1), 1, min(8, max(t - 1, 1)))
            self.show_tracks = gui.add_checkbox("3D tracks", len(self.data.tracks) > 0)
        self.timeline.on_update(lambda _: self._show(int(self.timeline.value)))
        for control in (self.accumulate, self.show_tracks, self.trail, self.show_cameras):
            control.on_update(lambda _: self._show(int(self.timeline.value)))
        for control in (self.min_confidence, self.point_size):
            control.on_update(lambda _: self._restyle())

    # ------------------------------------------------------------------------------------------ scene
    def _build_static_scene(self) -> None:
        d, scene = self.data, self.server.scene
        h, w = d.size
        positions = d.cam_to_world[:, :3, 3]
        if len(positions) > 1:
            segments = np.stack([positions[:-1], positions[1:]], 1)
            scene.add_line_segments("/camera_path", segments, (40, 160, 80), thickness=2, thickness_units="screen")
        self._frusta = []
        scale = 0.1 * self.extent
        for k in range(d.num_frames):
            fov = 2 * np.arctan2(h / 2, d.intrinsics[k, 1, 1])
            image = d.images[k] if d.images is not None else None
            self._frusta.append(scene.add_camera_frustum(
                f"/cameras/{k:05d}", fov=float(fov), aspect=w / h, scale=scale, image=image,
                wxyz=rotation_to_quaternion(d.cam_to_world[k, :3, :3])[[3, 0, 1, 2]], position=d.cam_to_world[k, :3, 3],
                color=(120, 120, 120), thickness=1.5, thickness_units="screen"))
        self._moving = moving_tracks(d.tracks, self.extent)

    def _rebuild_clouds(self) -> None:
        """One point cloud per frame (confidence-filtered, subsampled), shown or hidden as time moves."""
        with self._lock:
            for handle in self._clouds:
                handle.remove()
            d, self._clouds = self.data, []
            rng = np.random.default_rng(0)
            keep = np.isfinite(d.points).all(1) & (d.confidence >= float(self.min_confidence.value))
            for k in range(d.num_frames):
                index = np.nonzero(keep & (d.frames == k))[0]
                if len(index) > MAX_POINTS_PER_FRAME:
                    index = np.sort(rng.choice(index, MAX_POINTS_PER_FRAME, replace=False))
                self._clouds.append(self.server.scene.add_point_cloud(
                    f"/points/{k:05d}", d.points[index].astype(np.float32), d.colors[index],
                    point_size=float(self.point_size.value) * self.extent, point_shape="rounded", visible=False))

    def _restyle(self) -> None:
        self._rebuild_clouds()
        self._show(int(self.timeline.value))

    def _show(self, frame: int) -> None:
        """Everything of time ``frame``: its points (or all up to it), frusta, track trails."""
        with self._lock:
            frame = int(np.clip(frame, 0, self.data.num_frames - 1))
            for k, handle in enumerate(self._clouds):
                handle.visible = k == frame or (bool(self.accumulate.value) and k < frame)
            for k, handle in enumerate(self._frusta):
                handle.visible = bool(self.show_cameras.value) and (k <= frame)
                handle.color = (230, 60, 60) if k == frame else (120, 120, 120)
            self._draw_tracks(frame)
            self._frame = frame

    def _draw_tracks(self, frame: int) -> None:
        d = self.data
        if self._track_handle is not None:
            self._track_handle.remove()
            self._track_handle = None
        if not bool(self.show_tracks.value) or not len(d.tracks):
            return
        start = max(0, frame - int(self.trail.value))
        a, b = d.tracks[:, start:frame], d.tracks[:, start + 1:frame + 1]
        seen = (d.track_visibility[:, start + 1:frame + 1] > 0.5) & np.isfinite(a).all(-1) & np.isfinite(b).all(-1)
        if start == frame:  # no trail: a dot-like stub at the current position
            a, b = d.tracks[:, frame:frame + 1], d.tracks[:, frame:frame + 1] + 1e-3 * self.extent
            seen = (d.track_visibility[:, frame:frame + 1] > 0.5) & np.isfinite(a).all(-1)
        rows, cols = np.nonzero(seen)
        if not len(rows):
            return
        segments = np.stack([a[rows, cols], b[rows, cols]], 1).astype(np.float32)
        palette = np.array([[60, 120, 230], [250, 140, 30]], dtype=np.uint8)  # static blue, moving orange
        colors = np.repeat(palette[self._moving[rows].astype(int)][:, None], 2, axis=1)
        self._track_handle = self.server.scene.add_line_segments("/tracks", segments, colors, thickness=3,
                                                                 thickness_units="screen")

    # ----------------------------------------------------------------------------------------- timing
    @property
    def frame(self) -> int:
        return self._frame

    @frame.setter
    def frame(self, value: int) -> None:
        self.timeline.value = int(value)  # viser calls its on_update (which draws the frame) when it changes

    def _play_loop(self) -> None:
        while not self._stop.is_set():
            if bool(self.playing.value) and self.data.num_frames > 1:
                self.frame = (self._frame + 1) % self.data.num_frames
                time.sleep(1.0 / max(self.data.fps * float(self.speed.value), 1e-3))
            else:
                time.sleep(0.05)

    def close(self) -> None:
        self._stop.set()
        self._player.join(timeout=1)


def serve(folder: str | Path, host: str = "127.0.0.1", port: int = 8080, block: bool = True):
    """Load ``folder`` and serve its viewer at http://host:port; blocks until Ctrl-C when ``block``.
    Returns (server, viewer)."""
    try:
        import viser
    except ImportError:
        raise UserError("d4rt view needs viser: pip install 'd4rt[viewer]'") from None
    data = ViewerData.load(folder)
    try:
        server = viser.ViserServer(host=host, port=port, verbose=False)
    except OSError as err:
        raise UserError(f"cannot serve on {host}:{port}: {err.strerror or err} (choose another --port)") from err
    viewer = Viewer(data, server)
    if block:
        print(f"d4rt view: {folder} ({data.num_frames} frames, {len(data.points):,} points, {len(data.tracks)} tracks) "
              f"at http://{host}:{server.get_port()} - Ctrl-C stops it", flush=True)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            viewer.close()
            server.stop()
    return server, viewer
