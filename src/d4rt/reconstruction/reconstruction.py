"""Everything from queries: depth, point clouds, 3D tracks, cameras and dense tracking (paper Sec. 2.1,
Tab. 1, Alg. 1, App. B and C), and moving-object masks (not in the paper), over anything that answers queries.

The same recipes run on the trained model's encoded scene and on the synthetic engine's exact oracle;
on the oracle they must be exact, which tests the recipes independently of how well a model is
trained.

Long videos are cut into overlapping windows the answerer can take (the model's ``max_frames``), each
aligned to the global world (camera 0) by Sim(3) and answering the frames it owns
(:mod:`d4rt.reconstruction.windows`, App. B).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import torch

from d4rt.config import MOTION_TARGETS, MOTION_THRESHOLD, check_motion_options, check_pose_pairs
from d4rt.errors import UserError
from d4rt.disk_array import DiskArray
from d4rt.geometry.camera import cell_centres_uv, pixel_grid, pixel_to_uv
from d4rt.geometry.transforms import invert_rigid
from d4rt.geometry.umeyama import Similarity
from d4rt.progress import progress_bar
from d4rt.reconstruction.cameras import intrinsics_from_points
from d4rt.reconstruction.dense import occupancy_tracking
from d4rt.reconstruction.motion import target_frames, window_relative_motion
from d4rt.reconstruction.results import Cameras, DenseTracks, Depth, MotionMasks, PointCloud, Tracks
from d4rt.reconstruction.query_patterns import grid_queries, track_queries
from d4rt.reconstruction.sources import AnswererSource, ModelSource, as_source
from d4rt.reconstruction.windows import (align_windows, hand_off, keeping_windows, owned, owners, plan_windows,
                                         window_camera_grid, window_depth)

KEYS = ("points", "uv", "visibility", "confidence")


# Depth maps are decoded this many pixels at a time (whole frames): the float64 answers of a whole window
# of VGA frames would be some 800 MB.
DEPTH_QUERIES_PER_STEP = 262_144
# How many pinhole cameras the intrinsics recipe fits: one per frame (the paper) or one for the video.
CAMERA_MODELS = ("single", "per-frame")

# Points per side of the coarse grid of the camera recipe and of window alignment (paper Sec. 2.1).
DEFAULT_GRID = 12


class Reconstruction:
    """The 4D outputs of one video, decoded on demand from an answerer.

    answerer: anything with ``query(queries (N, 5)) -> dict`` and ``num_frames`` (an encoded scene, an
    oracle), or a window source (``d4rt.reconstruction.sources``). video: (T, H, W, 3) uint8 or float
    in [0, 1]: the frames the answers refer to; its size is the default output resolution and its
    colours colour the point cloud. window / overlap: frames per window and frames shared by
    consecutive windows (default: one window if the answerer takes the whole video, else the
    answerer's maximum with a quarter of it as overlap). chunk_size: queries per call to the answerer
    (bounds memory). grid: points per side of the grid used for cameras and window alignment.
    pose_pairs: which camera each frame's pose is fitted against: "first" (the paper's recipe: the window's
    first camera) or "adjacent" (the previous frame's camera, the fits chained; see
    ``d4rt.reconstruction.windows.POSE_PAIRS``). motion_threshold: the default of :meth:`motion_masks` (a model's
    own, from its config, with :meth:`from_model`). progress: show progress bars (default: only for long work).
    """

    def __init__(self, answerer, video, *, window: int | None = None, overlap: int | None = None,
                 chunk_size: int = 1 << 16, grid: int = DEFAULT_GRID, align_fraction: float = 0.85,
                 pose_pairs: str = "first", motion_threshold: float = MOTION_THRESHOLD, progress: bool | None = None):
        self.video = _as_uint8_video(video)
        self.source = as_source(answerer)
        self.num_frames, self.height, self.width = self.video.shape[:3]
        if self.source.num_frames != self.num_frames:
            raise UserError(f"the answerer covers {self.source.num_frames} frames but the video has {self.num_frames}")
        if chunk_size < 1 or grid < 2 or not 0 < align_fraction <= 1:
            raise UserError("chunk_size must be >= 1, grid >= 2 and align_fraction in (0, 1]")
        self.pose_pairs = check_pose_pairs(pose_pairs)
        check_motion_options(motion_threshold, MOTION_TARGETS)
        self.motion_threshold = float(motion_threshold)
        self.chunk_size, self.grid, self.align_fraction, self.progress = chunk_size, grid, align_fraction, progress
        self.windows = plan_windows(self.num_frames, window or self.source.max_window, overlap)
        self.queries_decoded = 0  # every query answered so far (the recipes' cost)

    @classmethod
    def from_model(cls, model, video, *, window: int | None = None, overlap: int | None = None,
                   on_encode=None, flip_average: bool | None = None, **options) -> "Reconstruction":
        """The recipes over a D4RT model (anything with ``encode(video) -> answerer`` and ``config``):
        each window of ``video`` (T, H, W, 3) is encoded when first asked for (:class:`ModelSource`);
        ``on_encode`` is called after each encode (a progress bar's update, say); ``options`` as for
        the constructor, with ``pose_pairs`` and ``motion_threshold`` (or None) defaulting to the model's own
        (``config.pose_pairs``, ``config.motion_threshold``);
        ``flip_average`` (None: the model's ``config.flip_average``) averages every answer with the mirrored
        video's (:mod:`d4rt.reconstruction.flip_average`)."""
        source = ModelSource(model, video, max_window=window, on_encode=on_encode, flip_average=flip_average)
        if options.get("pose_pairs") is None:
            options["pose_pairs"] = model.config.pose_pairs
        if options.get("motion_threshold") is None:
            options["motion_threshold"] = model.config.motion_threshold
        return cls(source, video, window=window, overlap=overlap, **options)

    @classmethod
    def from_clip(cls, clip, *, window: int | None = None, overlap: int | None = None, **options) -> "Reconstruction":
        """The recipes over a clip's exact oracle (a :class:`d4rt.synthetic.Clip`, or anything with
        ``oracle`` and ``rgb``): depth, cameras, tracks and point clouds are its ground truth; ``window``
        splits it into overlapping windows, to test long-video stitching exactly."""
        return cls(AnswererSource(clip.oracle, max_window=window), clip.rgb, window=window, overlap=overlap, **options)

    # ------------------------------------------------------------------------------------------------
    # Asking

    def _ask(self, w: int, queries: np.ndarray) -> dict:
        """Answer (N, 5) queries with GLOBAL frame indices in window w; numpy float64 arrays back."""
        start, stop = self.windows[w]
        q = np.array(queries, dtype=np.float64, copy=True)
        if len(q) and (q[:, 2:].min() < start or q[:, 2:].max() >= stop):
            raise AssertionError("query frames outside their window")  # a bug here, not bad input
        q[:, 2:] -= start
        self.queries_decoded += len(q)
        show = self.progress if self.progress is not None else len(q) > 8 * self.chunk_size
        return ask_in_chunks(self.source.window(start, stop), q, self.chunk_size, show)

    # ------------------------------------------------------------------------------------------------
    # Window alignment (App. B; d4rt.reconstruction.windows)

    @cached_property
    def window_to_world(self) -> list[Similarity]:
        """Sim(3) from each window's world (camera of its first frame) to the global world (camera 0)."""
        return align_windows(self.windows, self._ask, cell_centres_uv(self.grid), self.align_fraction)

    def _window_scale(self, w: int) -> float:
        return float(self.window_to_world[w].scale)

    def _window_to_reference(self, w: int, points: np.ndarray, world_to_ref: np.ndarray) -> np.ndarray:
        """Points (..., 3) in window w's world -> the reference camera: the window's Sim(3) into the
        global world, then the rigid global-world-to-reference-camera ``world_to_ref`` (4, 4)."""
        p = self.window_to_world[w].apply(torch.from_numpy(points)).numpy()
        return p @ world_to_ref[:3, :3].T + world_to_ref[:3, 3]

    # ------------------------------------------------------------------------------------------------
    # Recipes

    def depth(self, resolution: tuple[int, int] | str | None = None) -> Depth:
        """Depth of every frame: all pixels with t_src = t_tgt = t_cam = t; keep z.

        resolution: None (the input video's own size), "encoder" (about the answerer's encoder input's
        pixel count at the video's aspect ratio, see :meth:`output_size`) or (H, W): queries are
        continuous, so any size works (App. C).
        Returns Depth(depth (T, H, W), confidence (T, H, W)), float32.
        """
        h, w = self.output_size(resolution)
        depth = np.zeros((self.num_frames, h, w), dtype=np.float32)
        conf = np.zeros_like(depth)
        for frames, part in self.depth_by_window(resolution):
            depth[frames], conf[frames] = part.depth, part.confidence
        return Depth(depth, conf)

    def depth_by_window(self, resolution: tuple[int, int] | str | None = None):
        """The depth maps of :meth:`depth`, a few frames at a time (so a long video's maps, and the answers
        of a whole window's pixels, need not be held together): yields ``(frames (F,), Depth(depth (F, H,
        W), confidence (F, H, W)))`` for consecutive frames of one window, at most DEPTH_QUERIES_PER_STEP
        pixels' worth (one frame at least), in increasing frame order."""
        h, w = self.output_size(resolution)
        uv = pixel_to_uv(pixel_grid(h, w), h, w)
        step = max(1, DEPTH_QUERIES_PER_STEP // (h * w))
        for win in range(len(self.windows)):
            owned_frames = np.array(owned(self.windows, win))
            for i in range(0, len(owned_frames), step):
                frames = owned_frames[i:i + step]
                yield frames, Depth(*window_depth(lambda q: self._ask(win, q), frames, uv, self._window_scale(win),
                                                  h, w))

    def motion_masks(self, resolution: tuple[int, int] | str | None = None, threshold: float | None = None,
                     targets: int = MOTION_TARGETS) -> MotionMasks:
        """Moving-object masks (not in the paper; :mod:`d4rt.reconstruction.motion`): every pixel of frame t
        asked at its own time and at ``targets`` frames t' spread over its window, all in camera t
        ((u, v, t, t, t) and (u, v, t, t', t)): a static surface answers the same point each time, whatever
        the camera does, so the largest distance between the answers, divided by the depth, is the surface's
        own motion. ``dynamic`` = that fraction > ``threshold`` (None: the reconstruction's ``motion_threshold``,
        a model's own from its config). Costs ``targets`` + 1 queries per pixel.

        resolution: as for :meth:`depth`. With several windows a pixel is compared with frames of the window
        that owns its frame. Returns MotionMasks(relative_motion (T, H, W) float32, dynamic (T, H, W) bool,
        threshold, target_frames (T, K) int64).
        """
        threshold = self.motion_threshold if threshold is None else threshold
        check_motion_options(threshold, targets)
        h, w = self.output_size(resolution)
        uv = pixel_to_uv(pixel_grid(h, w), h, w)
        relative = np.full((self.num_frames, h, w), np.nan, dtype=np.float32)
        # Every window but a video's only one has the same length, hence the same number of targets.
        compared = np.zeros((self.num_frames, len(target_frames(*self.windows[0], targets))), dtype=np.int64)
        for win, (start, stop) in enumerate(self.windows):
            goals = target_frames(start, stop, targets)
            owned_frames = np.array(owned(self.windows, win))
            step = max(1, DEPTH_QUERIES_PER_STEP // (h * w * (len(goals) + 1)))
            for i in range(0, len(owned_frames), step):
                frames = owned_frames[i:i + step]
                part = window_relative_motion(lambda q: self._ask(win, q), frames, uv, goals)
                relative[frames] = part.reshape(-1, h, w)
            compared[owned_frames] = goals
        dynamic = np.nan_to_num(relative, nan=0.0) > threshold
        return MotionMasks(relative, dynamic, float(threshold), compared)

    @cached_property
    def _camera_grid(self) -> tuple[list[dict], np.ndarray]:
        """Per frame i, the grid points seen in camera i (t_src = t_tgt = t_cam = i) and the rigid fit
        of camera i to the global world; the same answers serve intrinsics and poses."""
        uv = cell_centres_uv(self.grid)
        per_frame: list[dict] = [{} for _ in range(self.num_frames)]
        c2w = np.zeros((self.num_frames, 4, 4))
        for win in range(len(self.windows)):
            frames = np.array(owned(self.windows, win))
            points, confidence, c2w[frames] = window_camera_grid(lambda q: self._ask(win, q), self.windows[win][0],
                                                                 frames, uv, self.window_to_world[win], self.pose_pairs)
            for j, f in enumerate(frames):
                per_frame[f] = {"points": points[j], "confidence": confidence[j]}
        return per_frame, c2w

    def cameras(self, intrinsics=None, method: str = "median", reference_frame: int = 0, camera: str = "per-frame",
                square_pixels: bool = False) -> Cameras:
        """Intrinsics and camera-to-world poses of every frame, the world being camera ``reference_frame``.

        Intrinsics: from a grid of points of frame i seen in camera i (t_src = t_tgt = t_cam = i), with
        the paper's pinhole-median recipe (principal point at the image centre) or a least-squares fit
        of fx, fy, cx, cy (``method="lstsq"``); known intrinsics ((3, 3) or (T, 3, 3), pixels of the
        input video) replace the estimate. camera="per-frame" (the paper's recipe) fits each frame on its
        own; camera="single" fits one camera to the grid points of every frame together (a video shot
        without zooming: steadier, and what splatting and MVS tools expect). square_pixels: fx = fy.
        Poses: the same grid queried as (i, i, i) and (i, i, r) is one set of points at one time in two
        cameras, so moving objects cannot corrupt the rigid Umeyama fit between them (r = the window's
        first frame, or frame i - 1 with the fits chained when the reconstruction's ``pose_pairs`` is
        "adjacent"; windows are then chained by their Sim(3)).
        """
        self._check_frame(reference_frame, "reference_frame")
        if camera not in CAMERA_MODELS:
            raise UserError(f"camera must be one of {', '.join(CAMERA_MODELS)}, got {camera!r}")
        t = self.num_frames
        per_frame, c2w = self._camera_grid
        if intrinsics is not None:
            k_all = np.asarray(intrinsics, dtype=np.float64)
            if k_all.shape == (3, 3):
                k_all = np.broadcast_to(k_all, (t, 3, 3)).copy()
            if k_all.shape != (t, 3, 3) or not np.isfinite(k_all).all():
                raise UserError(f"intrinsics must be finite (3, 3) or ({t}, 3, 3), got shape {k_all.shape}")
        elif camera == "single":
            uv = np.tile(cell_centres_uv(self.grid), (t, 1))
            points = np.concatenate([f["points"] for f in per_frame])
            confidence = np.concatenate([f["confidence"] for f in per_frame])
            k = intrinsics_from_points(points, uv, confidence, self.height, self.width, method, square_pixels)
            k_all = np.broadcast_to(k, (t, 3, 3)).copy()
        else:
            uv = cell_centres_uv(self.grid)
            k_all = np.stack([intrinsics_from_points(f["points"], uv, f["confidence"], self.height, self.width, method,
                                                     square_pixels) for f in per_frame])
        return Cameras(k_all, invert_rigid(c2w[reference_frame]) @ c2w, reference_frame)

    def point_cloud(self, reference_frame: int = 0, stride: int = 1, min_confidence: float | None = None,
                    visible_only: bool = False, frames=None) -> PointCloud:
        """All (or every ``stride``-th) pixels of all frames, each at its own time (t_tgt = t_src), in the
        camera of ``reference_frame`` directly (t_cam = reference: no explicit transforms, the paper's
        recipe). With several windows, points are queried in their window's world and mapped by its
        Sim(3) and the reference camera's pose.

        min_confidence drops points below it; visible_only keeps points the answerer sees from the
        reference frame (visibility > 0.5 at t_tgt = reference, one more query per point).
        """
        self._check_frame(reference_frame, "reference_frame")
        if stride < 1:
            raise UserError(f"stride must be >= 1, got {stride}")
        frame_list = np.arange(self.num_frames) if frames is None else np.asarray(frames, dtype=np.int64)
        for f in frame_list:
            self._check_frame(int(f), "frames")
        pixels = pixel_grid(self.height, self.width, stride)
        uv = pixel_to_uv(pixels, self.height, self.width)
        single = len(self.windows) == 1
        if not single:
            world_to_ref = invert_rigid(self._global_pose(reference_frame))
        pts, conf, fr, pix = [], [], [], []
        for win in range(len(self.windows)):
            mine = frame_list[owners(self.windows, frame_list) == win].astype(np.int64)
            if not len(mine):
                continue
            cam = reference_frame if single else self.windows[win][0]
            out = self._ask(win, grid_queries(uv, mine, mine, np.full_like(mine, cam)))
            p = out["points"]
            if not single:
                p = self._window_to_reference(win, p, world_to_ref)
            c = out["confidence"]
            if visible_only:
                seen = self._visible_from(reference_frame, uv, mine)
                c = np.where(seen, c, -np.inf)
            pts.append(p)
            conf.append(c)
            fr.append(np.repeat(mine, len(uv)))
            pix.append(np.tile(pixels.astype(np.int64), (len(mine), 1)))
        points, confidence = np.concatenate(pts), np.concatenate(conf)
        frames_out, pixels = np.concatenate(fr), np.concatenate(pix)
        keep = np.isfinite(points).all(1) & np.isfinite(confidence) & (confidence > 0)
        if min_confidence is not None:
            keep &= confidence >= min_confidence
        colors = self.video[frames_out[keep], pixels[keep, 1], pixels[keep, 0]]
        return PointCloud(points[keep].astype(np.float32), colors, confidence[keep].astype(np.float32),
                          frames_out[keep], pixels[keep], reference_frame)

    def _visible_from(self, reference_frame: int, uv: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """Whether each (frame, pixel) point is visible in frame ``reference_frame`` (its window must
        contain both; otherwise False)."""
        seen = np.zeros(len(frames) * len(uv), dtype=bool)
        for win, (a, b) in enumerate(self.windows):
            if not a <= reference_frame < b:
                continue
            inside = (frames >= a) & (frames < b)
            if inside.any():
                fr = frames[inside]
                out = self._ask(win, grid_queries(uv, fr, np.full_like(fr, reference_frame), np.full_like(fr, reference_frame)))
                mask = np.repeat(inside, len(uv))
                seen[mask] |= out["visibility"] > 0.5
            break
        return seen

    def tracks(self, points, frame: str = "camera", reference_frame: int = 0) -> Tracks:
        """Full-video 3D tracks of points given as (N, 3) [t_src, x, y] (pixels of the input video,
        OpenCV pixel centres).

        frame="camera": at every frame k the point in camera k (t_tgt = t_cam = k);
        frame="world": in the camera of ``reference_frame`` (t_cam fixed, t_tgt = k).
        With several windows a track is carried into the next (previous) window from the shared frame
        where it is most visible; if it is hidden in every shared frame it cannot be carried, and its
        positions beyond are NaN with visibility 0 (the frames its own window shares with the previous
        one keep that window's answers).
        """
        if frame not in ("camera", "world"):
            raise UserError(f"frame must be 'camera' or 'world', got {frame!r}")
        self._check_frame(reference_frame, "reference_frame")
        src = self._check_track_points(points)
        n, t = len(src), self.num_frames
        out = {"points": np.full((n, t, 3), np.nan), "uv": np.full((n, t, 2), np.nan), "visibility": np.zeros((n, t)),
               "confidence": np.zeros((n, t))}
        uv0 = pixel_to_uv(src[:, 1:3], self.height, self.width)
        t0 = src[:, 0].astype(np.int64)
        home = owners(self.windows, t0)
        if frame == "world" and len(self.windows) > 1:
            world_to_ref = invert_rigid(self._global_pose(reference_frame))
        # Every track is decoded once in each window it reaches: its home window, then the windows after
        # it (forward), then the windows before it (backward). A window writes the frames it owns and
        # hands the tracks on through a shared frame; the home window's answers also start the backward
        # hand-off, so no window decodes a track twice.
        handle_uv, handle_t = uv0.copy(), t0.copy()
        forward = np.zeros(n, dtype=bool)  # holds a handle into the window being processed
        back_uv, back_t = np.zeros((n, 2)), np.zeros(n, dtype=np.int64)
        back_window = np.full(n, -1)  # the earlier window a track is handed back to (-1: none)
        passes = [(win, 1) for win in range(len(self.windows))] + [(win, -1) for win in range(len(self.windows) - 2, -1, -1)]
        for win, direction in passes:
            if direction == 1:
                idx = np.nonzero((home == win) | forward)[0]
                starts_uv, starts_t = handle_uv[idx], handle_t[idx]
            else:
                idx = np.nonzero(back_window == win)[0]
                starts_uv, starts_t = back_uv[idx], back_t[idx]
            if len(idx) == 0:
                continue
            a, b = self.windows[win]
            frames = np.arange(a, b)
            if frame == "camera":
                cam = frames
            else:
                cam = np.full_like(frames, reference_frame if len(self.windows) == 1 else a)
            q = track_queries(starts_uv, starts_t, frames, cam)
            ans = {k: v.reshape(len(idx), len(frames), *v.shape[1:]) for k, v in self._ask(win, q).items()}
            p = ans["points"]
            if len(self.windows) > 1:
                if frame == "camera":
                    p = p * self._window_scale(win)
                else:
                    p = self._window_to_reference(win, p, world_to_ref)
            mine = np.array(owned(self.windows, win)) - a  # the window's own frames, window-relative
            values = (("points", p), ("uv", ans["uv"]), ("visibility", ans["visibility"]),
                      ("confidence", ans["confidence"]))
            if direction == 1 and mine[0] > 0:
                # The home window's answers for the frames it shares with earlier windows: kept where the
                # backward hand-off fails (those windows then never see the track), overwritten where not.
                home_rows = np.nonzero(home[idx] == win)[0]
                for key, value in values:
                    out[key][idx[home_rows, None], np.arange(mine[0]) + a] = value[home_rows, :mine[0]]
            for key, value in values:
                out[key][idx[:, None], mine + a] = value[:, mine]
            if direction == 1:
                forward[:] = False
                ok, new_uv, new_t = hand_off(self.windows, ans, win, win + 1)
                handle_uv[idx[ok]], handle_t[idx[ok]] = new_uv[ok], new_t[ok]
                forward[idx[ok]] = True
                starting = home[idx] == win  # their backward journey starts from these answers
            else:
                starting = np.ones(len(idx), dtype=bool)
                back_window[idx] = -1
            ok, new_uv, new_t = hand_off(self.windows, ans, win, win - 1)
            go = starting & ok
            back_uv[idx[go]], back_t[idx[go]], back_window[idx[go]] = new_uv[go], new_t[go], win - 1
        return Tracks(out["points"], out["visibility"], out["confidence"], out["uv"], frame, reference_frame)

    def observe(self, points, targets, reference_frame: int = 0) -> Tracks:
        """Points given as (N, 3) [t_src, x, y] (input-video pixels) at chosen frames only, in the camera of
        ``reference_frame`` (t_cam fixed): a sparse :meth:`tracks` for when a few frames per point are
        enough (multi-view observations for a COLMAP model) and every frame would cost T queries each.

        targets: (N, K) int frames per point, -1 for none; each must lie in the window that owns the
        point's source frame (no hand-off between windows), else it is an error.
        Returns Tracks whose columns are the K targets: points (N, K, 3), uv (N, K, 2), visibility and
        confidence (N, K); NaN / 0 where the target is -1.
        """
        self._check_frame(reference_frame, "reference_frame")
        src = self._check_track_points(points)
        targets = np.asarray(targets)
        if targets.ndim != 2 or len(targets) != len(src) or not np.issubdtype(targets.dtype, np.integer):
            raise UserError(f"targets must be (N, K) integer frames for N = {len(src)} points, got {targets.shape}")
        n, k = targets.shape
        out = {"points": np.full((n, k, 3), np.nan), "uv": np.full((n, k, 2), np.nan), "visibility": np.zeros((n, k)),
               "confidence": np.zeros((n, k))}
        t0 = src[:, 0].astype(np.int64)
        uv0 = pixel_to_uv(src[:, 1:3], self.height, self.width)
        home = owners(self.windows, t0)
        single = len(self.windows) == 1
        if not single:
            world_to_ref = invert_rigid(self._global_pose(reference_frame))
        for win in np.unique(home):
            a, b = self.windows[win]
            rows = np.nonzero(home == win)[0]
            wanted = targets[rows]
            if ((wanted != -1) & ((wanted < a) | (wanted >= b))).any():
                raise UserError(f"targets must lie in the window of their source frame ({a}..{b - 1} here) or be -1")
            r, c = np.nonzero(wanted != -1)
            frames = wanted[r, c]
            cam = reference_frame if single else a
            q = np.concatenate([uv0[rows[r]], t0[rows[r], None], frames[:, None], np.full((len(r), 1), cam)], 1)
            ans = self._ask(win, q.astype(np.float64))
            p = ans["points"] if single else self._window_to_reference(win, ans["points"], world_to_ref)
            for key, value in (("points", p), ("uv", ans["uv"]), ("visibility", ans["visibility"]),
                               ("confidence", ans["confidence"])):
                out[key][rows[r], c] = value
        return Tracks(out["points"], out["visibility"], out["confidence"], out["uv"], "world", reference_frame)

    def dense_tracks(self, resolution: tuple[int, int] | None = None, batch_size: int = 1024,
                     visibility_threshold: float = 0.5) -> DenseTracks:
        """Camera-frame tracks of every pixel of every frame with the occupancy grid (Alg. 1).

        resolution: (H, W) of the grid (default: the input video's). Each batch of sources is decoded as
        full-video camera-frame tracks (:meth:`tracks`); a video of several windows is tracked as a
        whole, tracks carried from window to window, so the grid spans every frame; the encoded windows are kept for the
        whole run (memory grows with the number of windows) rather than re-encoded for every batch.
        ``num_queries`` counts the tracking queries actually decoded (window alignment, shared with the
        other recipes, is not counted). The tracks are float32 (N tracks of T frames each add up).
        """
        h, w = self.output_size(resolution)
        t = self.num_frames
        if len(self.windows) > 1:
            _ = self.window_to_world  # align the windows first, so that the count below is tracking alone
        start = self.queries_decoded

        def ask(src: np.ndarray) -> dict:
            # Grid cells to input-video pixels (OpenCV centres): the same normalised (u, v).
            pixels = np.stack([src[:, 0], (src[:, 1] + 0.5) * self.width / w - 0.5,
                               (src[:, 2] + 0.5) * self.height / h - 0.5], 1).astype(np.float64)
            tr = self.tracks(pixels, frame="camera")
            # Kept as float32 (the model answers in float32; T * H * W tracks of float64 would double the peak).
            return {"points": tr.points.astype(np.float32), "uv": tr.uv.astype(np.float32),
                    "visibility": tr.visibility.astype(np.float32), "confidence": tr.confidence.astype(np.float32)}

        with keeping_windows(self.source, len(self.windows)):
            res = occupancy_tracking(ask, t, h, w, batch_size, visibility_threshold, progress=bool(self.progress))
        tracks = Tracks(res["points"], res["visibility"], res["confidence"], res["uv"], "camera", 0)
        return DenseTracks(tracks, res["sources"], self.queries_decoded - start, t * t * h * w,
                           float(res["grid"].mean()), (h, w))

    # ------------------------------------------------------------------------------------------------

    def _global_pose(self, frame: int) -> np.ndarray:
        """Camera-to-global-world pose of one frame (through its window's Sim(3))."""
        return self._camera_grid[1][frame]

    def output_size(self, resolution) -> tuple[int, int]:
        """(H, W) of an output resolution: None = the input video's, "encoder" = as many pixels as the
        answerer's encoder input with the input video's aspect ratio (a 2.35:1 clip and a 64x64 encoder
        give 42x98, not 64x64: the encoder's square is a resize, not the scene's shape), or an explicit
        (H, W)."""
        if resolution is None:
            return self.height, self.width
        if resolution == "encoder":
            if self.source.encoder_size is None:
                raise UserError("this answerer has no encoder resolution; pass (height, width) instead")
            return encoder_resolution(self.height, self.width, self.source.encoder_size)
        if (not isinstance(resolution, (tuple, list)) or len(resolution) != 2
                or not all(isinstance(v, (int, np.integer)) and v > 0 for v in resolution)):
            raise UserError(f"resolution must be None, 'encoder' or (height, width) positive ints, got {resolution!r}")
        return int(resolution[0]), int(resolution[1])

    def _check_frame(self, frame: int, name: str) -> None:
        if not isinstance(frame, (int, np.integer)) or not 0 <= frame < self.num_frames:
            raise UserError(f"{name} must be a frame index in [0, {self.num_frames - 1}], got {frame!r}")

    def _check_track_points(self, points) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise UserError(f"track points must have shape (N, 3) = [t_src, x, y], got {p.shape}")
        if not np.isfinite(p).all():
            raise UserError("track points contain NaN or infinite values")
        t = p[:, 0]
        if ((t != np.round(t)) | (t < 0) | (t >= self.num_frames)).any():
            raise UserError(f"track t_src must be integer frames in [0, {self.num_frames - 1}]")
        if ((p[:, 1] < -0.5) | (p[:, 1] > self.width - 0.5) | (p[:, 2] < -0.5) | (p[:, 2] > self.height - 0.5)).any():
            raise UserError(f"track (x, y) must lie in the {self.width}x{self.height} image "
                            "(pixel centres at integers, edges at -0.5 and size - 0.5)")
        return p


def encoder_resolution(height: int, width: int, encoder_size: tuple[int, int]) -> tuple[int, int]:
    """(h, w) with about as many pixels as the encoder input ``encoder_size`` (H, W) and the aspect ratio of
    a height x width video."""
    pixels = encoder_size[0] * encoder_size[1]
    aspect = width / height
    return max(1, round(np.sqrt(pixels / aspect))), max(1, round(np.sqrt(pixels * aspect)))


def ask_in_chunks(answerer, queries: np.ndarray, chunk_size: int, progress: bool = False) -> dict:
    """Answer (N, 5) queries (the answerer's own frame indices) ``chunk_size`` at a time (bounded memory):
    the KEYS as numpy float64 arrays (N, ...)."""
    answers: dict[str, np.ndarray] = {}  # filled chunk by chunk (no per-chunk copies kept to concatenate)
    for i in progress_bar(range(0, max(len(queries), 1), chunk_size), desc="decoding queries", unit="chunk",
                          disable=not progress, leave=False):
        out = answerer.query(queries[i:i + chunk_size])
        for k in KEYS:
            part = out[k].detach().cpu().double().numpy()
            if k not in answers:
                answers[k] = np.empty((len(queries), *part.shape[1:]))
            answers[k][i:i + len(part)] = part
    return answers


def _as_uint8_video(video) -> np.ndarray:
    if isinstance(video, DiskArray):  # frames read from disk window by window (d4rt.io.frames, lazy=True)
        if video.ndim != 4 or video.shape[-1] != 3 or min(video.shape[:3]) < 1 or video.dtype != np.uint8:
            raise UserError(f"video must be uint8 frames (T, H, W, 3), got {video.shape} {video.dtype}")
        return video
    v = video.detach().cpu().numpy() if isinstance(video, torch.Tensor) else np.asarray(video)
    if v.ndim != 4 or v.shape[-1] != 3 or min(v.shape[:3]) < 1:
        raise UserError(f"video must have shape (T, H, W, 3), got {v.shape}")
    if v.dtype == np.uint8:
        return v
    if np.issubdtype(v.dtype, np.floating):
        if not np.isfinite(v).all() or v.min() < 0 or v.max() > 1:
            raise UserError("float video values must be finite and in [0, 1]")
        return np.round(v * 255).astype(np.uint8)
    raise UserError(f"video must be uint8 or float in [0, 1], got dtype {v.dtype}")
