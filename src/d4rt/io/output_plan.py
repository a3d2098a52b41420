"""What to decode for a set of output formats: only the recipes (depth, cameras, point cloud, tracks,
COLMAP points, dense tracks) that the chosen formats need, each once, at the resolutions asked for;
the result is a :class:`d4rt.io.outputs.ReconstructionOutputs` that every writer reads."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from d4rt.config import MOTION_TARGETS, check_motion_options
from d4rt.errors import UserError
from d4rt.geometry.camera import cell_centres_uv, uv_to_pixel
from d4rt.geometry.known_poses import similarity_to_known_poses
from d4rt.geometry.transforms import apply_transform, similarity_times_pose
from d4rt.geometry.view import View
from d4rt.geometry.voxel import voxel_subsample
from d4rt.io.colmap_export import multiview_points
from d4rt.disk_array import DiskArray, frame_blocks, ranges
from d4rt.io.formats import CAMERA_CHOICES, COLMAP_VIEWS, DEFAULT_FPS, DEFAULT_MAX_POINTS, FORMAT_NEEDS, POINT_SOURCES, ZOOM_SPREAD
from d4rt.io.outputs import ReconstructionOutputs
from d4rt.progress import progress_bar
from d4rt.reconstruction.point_clouds import point_cloud_from_depth
from d4rt.reconstruction.windows import owners


def compute_outputs(rec, formats=("npz",), *, resolution=None, intrinsics=None, camera: str = "auto",
                    square_pixels: bool = True, min_confidence: float | None = None,
                    point_stride: int | None = None, track_grid: int = 16, track_frame: int = 0,
                    dense_resolution=None, max_points: int = DEFAULT_MAX_POINTS, points_from: str = "depth",
                    motion_resolution=None, motion_threshold: float | None = None, known_poses=None,
                    scale: float | None = None, timestamps=None,
                    fps: float | None = None, progress: bool = False, spool=None) -> ReconstructionOutputs:
    """Decode what ``formats`` need from a :class:`d4rt.reconstruction.Reconstruction`.

    resolution: depth maps at None (the input's size, continuous queries), "encoder" or (H, W).
    intrinsics: known (3, 3) or (T, 3, 3) intrinsics in pixels of the input frames (OpenCV centres);
    they replace the estimate and are rescaled for the depth maps' resolution. camera: "single" (one
    camera for the whole video, what splatting and MVS tools expect), "per-frame" (the paper's recipe,
    for zooming shots) or "auto" (the default: single where the per-frame focal lengths agree, see
    :func:`choose_camera_model`); square_pixels: fx = fy (the default); both apply to estimated
    intrinsics only, and every export uses the same ones. min_confidence: points and depth pixels below
    it are dropped (None: keep every positive confidence); if nothing is left, a UserError gives the
    range of confidences found (the scale is the model's: see docs/outputs.md). points_from: "depth"
    (the default: the depth maps unprojected through the cameras, no further query; the depth maps are
    decoded for it if no format needs them) or "queries" (the paper's direct recipe: every pixel queried
    again with t_cam = 0). point_stride: point cloud from every n-th pixel of the input (default: one
    point per depth-map pixel, or for "queries" the input-to-output size ratio, so the cloud is about
    as dense as the depth maps). track_grid: tracks start from a track_grid x track_grid grid of
    pixels of frame ``track_frame`` (0: no tracks). dense_resolution: the dense-tracking grid, (H, W),
    "encoder" or "original" (the input's size); None: the encoder's input size where the model has one
    (the input's size for an oracle): every pixel of a full-size video is rarely what is wanted, and
    costs T * H * W tracks. max_points: at most this many points in the COLMAP model: pixels of the
    point cloud, one per voxel (the most confident), each observed in the world in COLMAP_VIEWS
    frames of its window and kept where seen in 2 or more (:func:`d4rt.io.colmap_export.multiview_points`).
    motion_resolution: the moving-object masks' size, as ``dense_resolution`` (each pixel costs MOTION_TARGETS
    + 1 queries); motion_threshold: a surface is moving when it travels more than this fraction of its depth
    (:meth:`d4rt.reconstruction.Reconstruction.motion_masks`; None: the reconstruction's own, a model's from its
    config).
    known_poses: (T, 4, 4) camera-to-world poses of the frames in a world and units of your own (SLAM, motion
    capture, GPS/IMU, ground truth): every output is carried into that world by the Sim(3) that maps the estimated
    cameras onto them (:func:`d4rt.geometry.known_poses.similarity_to_known_poses`: rotation from the orientations,
    scale and offset from the centres); the poses written are the estimated ones carried so (every file stays
    consistent with the geometry), ``alignment_rms`` says how far their centres lie from the known ones.
    scale: multiply every length (depth, points, tracks, camera positions) by it, e.g. a known distance over the
    reconstruction's; the world stays camera 0. At most one of the two; both are stored in ``alignment`` (4, 4).
    timestamps: (T,) seconds (default: frame numbers);
    fps: for the videos and the viewer (default: from the timestamps, else 10).
    spool: a folder for the arrays that grow with the video (depth maps, confidences, point cloud): they
    are then :class:`d4rt.disk_array.DiskArray` files there, written a window or a block of frames at
    a time, so memory does not grow with the video's length (None: numpy arrays in memory). The folder
    must outlive the outputs.
    """
    t, h, w = rec.video.shape[:3]
    needs = set().union(*(FORMAT_NEEDS[f] for f in formats))
    if min_confidence is not None and not np.isfinite(min_confidence):
        raise UserError(f"the confidence threshold must be a finite number, got {min_confidence}")
    if camera not in CAMERA_CHOICES:
        raise UserError(f"camera must be one of {', '.join(CAMERA_CHOICES)}, got {camera!r}")
    if track_grid < 0:
        raise UserError(f"the track grid must be >= 0 points per side, got {track_grid}")
    if not 0 <= track_frame < t:
        raise UserError(f"the track frame must be in [0, {t - 1}], got {track_frame}")
    if points_from not in POINT_SOURCES:
        raise UserError(f"points_from must be one of {', '.join(POINT_SOURCES)}, got {points_from!r}")
    if max_points < 1:
        raise UserError(f"the maximum number of COLMAP points must be >= 1, got {max_points}")
    if point_stride is not None and point_stride < 1:
        raise UserError(f"the point stride must be >= 1, got {point_stride}")
    stamps = np.arange(t, dtype=np.float64) if timestamps is None else np.asarray(timestamps, dtype=np.float64)
    if stamps.shape != (t,):
        raise UserError(f"timestamps must have one entry per frame ({t}), got shape {stamps.shape}")
    out = ReconstructionOutputs(rec.video, stamps, float(fps or (DEFAULT_FPS if timestamps is None else _rate(stamps))),
                                min_confidence)
    out_h, out_w = rec.output_size(resolution)
    if known_poses is not None and scale is not None:
        raise UserError("give known poses or a scale, not both (known poses fix the scale themselves)")
    if scale is not None and not (isinstance(scale, (int, float)) and np.isfinite(scale) and scale > 0):
        raise UserError(f"the scale must be a finite number > 0, got {scale!r}")
    if known_poses is not None:
        known_poses = np.asarray(known_poses, dtype=np.float64)
        if known_poses.shape != (t, 4, 4):
            raise UserError(f"known poses must be ({t}, 4, 4) camera-to-world matrices, one per frame, got shape "
                            f"{known_poses.shape}")
        needs.add("cameras")
    if "dense" in needs:  # checked before any decoding
        dense_size = _grid_size(rec, dense_resolution, "dense_resolution")
    if "motion" in needs:
        motion_size = _grid_size(rec, motion_resolution, "motion_resolution")
        if motion_threshold is not None:
            check_motion_options(motion_threshold, MOTION_TARGETS)
    if "points" in needs and points_from == "depth":
        needs.add("depth")
    if "depth" in needs:
        needs.add("cameras")  # the depth maps' intrinsics
    stages = [s for s in ("cameras", "depth", "points", "tracks", "colmap-points", "dense", "motion") if s in needs]
    bar = progress_bar(stages, desc="query", unit="stage", disable=not progress)
    for stage in bar:
        bar.set_postfix_str(stage)
        if stage == "cameras":
            if camera == "auto" and intrinsics is None:
                camera = choose_camera_model(rec, square_pixels)
            cams = rec.cameras(intrinsics=intrinsics, camera="single" if camera == "auto" else camera,
                               square_pixels=square_pixels)
            out.video_intrinsics, out.cam_to_world = cams.intrinsics, cams.cam_to_world
            if known_poses is not None:  # fitted at once: a hopeless fit stops before the long stages
                out.alignment, out.alignment_rms = similarity_to_known_poses(out.cam_to_world, known_poses)
                fitted = np.cbrt(np.linalg.det(out.alignment[:3, :3]))
                print(f"d4rt: outputs carried into the known poses' world: scale {fitted:.4g}; the known camera "
                      f"centres lie {out.alignment_rms:.3g} (RMS, in their units) from the estimated ones",
                      file=sys.stderr)
        elif stage == "depth":
            out.depth = _new_array(spool, "depth", (t, out_h, out_w), np.float32)
            out.confidence = _new_array(spool, "confidence", (t, out_h, out_w), np.float32)
            found = ConfidenceRange()
            for frames, part in rec.depth_by_window(resolution):  # a window at a time: bounded memory
                rows = slice(int(frames[0]), int(frames[-1]) + 1)  # a window owns consecutive frames
                out.depth[rows], out.confidence[rows] = part.depth, part.confidence
                found.add(part.confidence)
            found.check(min_confidence, "depth pixel")
            resize = View((h, w), (0, 0, w, h), (out_h, out_w), tuple(range(t)))
            out.intrinsics = resize.intrinsics(out.video_intrinsics)
        elif stage == "points":
            _point_cloud(rec, out, points_from, point_stride, min_confidence, spool)
        elif stage == "tracks":
            xy = uv_to_pixel(cell_centres_uv(track_grid), h, w)
            out.track_queries = np.concatenate([np.full((len(xy), 1), float(track_frame)), xy], 1)
            if track_grid:
                tracks = rec.tracks(out.track_queries, frame="world")
                out.tracks, out.track_visibility = tracks.points, tracks.visibility
                out.track_confidence, out.track_uv = tracks.confidence, tracks.uv
            else:
                out.tracks, out.track_uv = np.zeros((0, t, 3)), np.zeros((0, t, 2))
                out.track_visibility, out.track_confidence = np.zeros((0, t)), np.zeros((0, t))
        elif stage == "colmap-points":
            out.colmap = _colmap_points(rec, out, max_points)
        elif stage == "dense":
            out.dense = _dense_arrays(rec.dense_tracks(dense_size), out.cam_to_world)
        elif stage == "motion":
            masks = rec.motion_masks(motion_size, threshold=motion_threshold)
            out.motion = {"dynamic": masks.dynamic, "relative_motion": masks.relative_motion,
                          "threshold": np.float64(masks.threshold), "target_frames": masks.target_frames,
                          "resolution": np.array(motion_size)}
            if out.points is not None:
                out.point_dynamic = points_on_masks(out, masks.dynamic)
    if scale is not None:
        out.alignment = np.diag([scale, scale, scale, 1.0])
    if out.alignment is not None:
        carry_outputs(out, out.alignment)
    return out


def points_on_masks(out: ReconstructionOutputs, dynamic: np.ndarray) -> np.ndarray:
    """(M,) bool: whether each point of the cloud lies on a moving surface, read from the masks ``dynamic``
    (T, h, w) at the mask cell under its input pixel (the static / dynamic split of the cloud)."""
    t, mask_h, mask_w = dynamic.shape
    height, width = out.rgb.shape[1:3]
    flags = np.zeros(len(out.points), dtype=bool)
    for a, b in ranges(len(out.points), POINT_BLOCK_PIXELS):
        x, y = np.asarray(out.point_pixels[a:b], dtype=np.float64).T
        cells_x = ((x + 0.5) * mask_w / width).astype(np.int64)  # a pixel centre's cell: always inside the grid
        cells_y = ((y + 0.5) * mask_h / height).astype(np.int64)
        flags[a:b] = dynamic[np.asarray(out.point_frames[a:b]), cells_y, cells_x]
    return flags


def carry_outputs(out: ReconstructionOutputs, sim: np.ndarray) -> None:
    """Map every output in place by the Sim(3) ``sim`` (4, 4) [sR | t]: world positions (points, tracks, COLMAP and
    dense-track world points) and camera poses by the whole of it, lengths in a camera's frame (depth maps,
    dense-track camera points) by its scale; intrinsics, confidences and masks do not change. Arrays on disk are
    rewritten a block at a time."""
    scale = float(np.cbrt(np.linalg.det(sim[:3, :3])))

    def move(points):
        return points @ sim[:3, :3].T + sim[:3, 3]

    if out.cam_to_world is not None:
        out.cam_to_world = np.stack([similarity_times_pose(sim, pose) for pose in out.cam_to_world])
    if out.depth is not None:
        for a, b in frame_blocks(out.depth):
            out.depth[a:b] = out.depth[a:b] * np.float32(scale)
    if out.points is not None:
        for a, b in ranges(len(out.points), POINT_BLOCK_PIXELS):
            out.points[a:b] = move(np.asarray(out.points[a:b], dtype=np.float64)).astype(np.float32)
    if out.tracks is not None:
        out.tracks = move(out.tracks)
    if out.colmap is not None:
        out.colmap["xyz"] = move(out.colmap["xyz"])
    if out.dense is not None:
        out.dense["points_world"] = move(out.dense["points_world"].astype(np.float64)).astype(np.float32)
        out.dense["points_camera"] = out.dense["points_camera"] * np.float32(scale)


def choose_camera_model(rec, square_pixels: bool = True, spread: float = ZOOM_SPREAD) -> str:
    """"single" when the per-frame focal lengths agree (90th / 10th percentile within ``spread``), else
    "per-frame" (a zoom), with a one-line notice. Costs no queries: the camera grid is cached."""
    per_frame = rec.cameras(camera="per-frame", square_pixels=square_pixels).intrinsics[:, 0, 0]
    low, high = np.percentile(per_frame, [10, 90])
    if low > 0 and high / low <= spread:
        return "single"
    print(f"d4rt: the per-frame focal lengths range from {low:.0f} to {high:.0f} px (10th-90th percentile), so each "
          "frame keeps its own camera; --camera single forces one", file=sys.stderr)
    return "per-frame"


class ConfidenceRange:
    """The range of the finite confidences seen, block by block, so that an empty output is an error that
    says what range the confidences have, not an empty file."""

    def __init__(self):
        self.low, self.high, self.count = np.inf, -np.inf, 0

    def add(self, confidence: np.ndarray) -> None:
        self.count += confidence.size
        finite = confidence[np.isfinite(confidence)]
        if finite.size:
            self.low, self.high = min(self.low, float(finite.min())), max(self.high, float(finite.max()))

    def check(self, min_confidence: float | None, what: str) -> None:
        if min_confidence is None or not self.count or self.high >= min_confidence:
            return
        if not np.isfinite(self.high):
            found = "all non-finite"
        elif self.low == self.high:
            found = f"all {self.low:.3g}"
        else:
            found = f"between {self.low:.3g} and {self.high:.3g}"
        raise UserError(f"no {what} has confidence >= {min_confidence:g} (this reconstruction's confidences are "
                        f"{found}); lower --min-confidence")


# A long video's point cloud is made, filtered and stored this many frames' worth of pixels at a time.
POINT_BLOCK_PIXELS = 250_000
POINT_FIELDS = {"points": ((3,), np.float32), "point_colors": ((3,), np.uint8), "point_confidence": ((), np.float32),
                "point_frames": ((), np.int64), "point_pixels": ((2,), np.int64)}


def _point_cloud(rec, out: ReconstructionOutputs, points_from: str, point_stride, min_confidence, spool) -> None:
    """The point cloud, a block of frames at a time, into ``out.points`` ... (and ``out.point_offsets``)."""
    t, h, w = rec.video.shape[:3]
    out_h, out_w = out.depth.shape[1:] if out.depth is not None else (h, w)
    if points_from == "depth":  # no query: the depth maps and cameras already decoded
        stride = max(1, round(point_stride * min(out_h / h, out_w / w))) if point_stride else 1
    else:
        stride = point_stride or max(1, int(min(h / out_h, w / out_w)))
    columns = {name: _growing(spool, name, shape, dtype) for name, (shape, dtype) in POINT_FIELDS.items()}
    counts = np.zeros(t, dtype=np.int64)
    found = ConfidenceRange()
    rows, cols = (out_h, out_w) if points_from == "depth" else (h, w)  # the grid the points are taken from
    per_frame = -(-rows // stride) * -(-cols // stride)
    for a, b in ranges(t, max(1, POINT_BLOCK_PIXELS // per_frame)):
        if points_from == "depth":
            cloud = point_cloud_from_depth(out.depth[a:b], out.confidence[a:b], out.intrinsics[a:b],
                                           out.cam_to_world[a:b], rec.video[a:b], stride)
            cloud.frames = cloud.frames + a
        else:
            cloud = rec.point_cloud(stride=stride, frames=np.arange(a, b))
        found.add(cloud.confidence)
        if min_confidence is not None:
            cloud = cloud.filtered(cloud.confidence >= min_confidence)
        counts += np.bincount(cloud.frames, minlength=t)
        for name, values in zip(POINT_FIELDS, (cloud.points, cloud.colors, cloud.confidence, cloud.frames,
                                               cloud.pixels)):
            columns[name].append(values)
    found.check(min_confidence, "point")
    for name, column in columns.items():
        setattr(out, name, column.finish())
    out.point_offsets = np.concatenate([[0], np.cumsum(counts)])


def _new_array(spool, name: str, shape: tuple, dtype):
    """A zero array in memory, or in a file of the spool folder (:class:`d4rt.disk_array.DiskArray`)."""
    return np.zeros(shape, dtype) if spool is None else DiskArray.create(Path(spool) / f"{name}.raw", shape, dtype)


def _growing(spool, name: str, row_shape: tuple, dtype):
    return _Rows(row_shape, dtype) if spool is None else _DiskRows(Path(spool) / f"{name}.raw", row_shape, dtype)


class _Rows:
    """Rows gathered in memory, one array at the end (of the first block's dtype; ``dtype`` if none came)."""

    def __init__(self, row_shape, dtype):
        self.parts, self.row_shape, self.dtype = [], row_shape, dtype

    def append(self, rows) -> None:
        self.parts.append(np.asarray(rows).reshape(-1, *self.row_shape))

    def finish(self) -> np.ndarray:
        return np.concatenate(self.parts) if self.parts else np.zeros((0, *self.row_shape), self.dtype)


class _DiskRows:
    """Rows appended to a file as they come (a DiskArray at the end, of the first block's dtype)."""

    def __init__(self, path, row_shape, dtype):
        self.path, self.row_shape, self.dtype, self.array = path, row_shape, dtype, None

    def append(self, rows) -> None:
        rows = np.asarray(rows).reshape(-1, *self.row_shape)
        if self.array is None:
            self.array = DiskArray.growable(self.path, self.row_shape, rows.dtype)
        self.array.append(rows)

    def finish(self):
        return self.array if self.array is not None else np.zeros((0, *self.row_shape), self.dtype)


def _colmap_points(rec, out: ReconstructionOutputs, max_points: int) -> dict:
    """Multi-view points for the COLMAP model: an evenly spread, confident subset of the point cloud,
    each pixel observed in the world (camera 0) in COLMAP_VIEWS frames of its window."""
    if not len(out.points):
        return multiview_points(np.zeros((0, rec.num_frames, 3)), np.zeros((0, rec.num_frames, 2)),
                                np.zeros((0, rec.num_frames)), np.zeros(0, dtype=np.int64), out.video_intrinsics,
                                out.cam_to_world, rec.height, rec.width) | {"colors": np.zeros((0, 3), np.uint8)}
    pick = spread_subset(out.points, out.point_confidence, max_points)
    sources = out.point_frames[pick]
    starts = np.concatenate([sources[:, None].astype(np.float64), out.point_pixels[pick].astype(np.float64)], 1)
    targets = observation_frames(rec.windows, sources, COLMAP_VIEWS)
    seen = rec.observe(starts, targets)
    found = multiview_points(seen.points, seen.uv, seen.visibility, sources, out.video_intrinsics,
                             out.cam_to_world, rec.height, rec.width, frames=targets)
    if len(found["index"]) < len(pick) / 2:
        print(f"d4rt: {len(found['index']):,} of {len(pick):,} points observed in up to {targets.shape[1]} frames each "
              f"were seen consistently (reprojecting within {0.01 * max(rec.height, rec.width):.1f} px) in 2 or more: "
              "the COLMAP model keeps only those (the whole cloud is in points.ply)", file=sys.stderr)
    return found | {"colors": out.point_colors[pick][found["index"]]}


def spread_subset(points, score, max_points: int, block: int = POINT_BLOCK_PIXELS) -> np.ndarray:
    """Indices of at most ``max_points`` points spread evenly over the scene, the best-scored per voxel
    (:func:`d4rt.geometry.voxel.voxel_subsample`), for clouds held in memory or on disk: a cloud larger than
    ``block`` is reduced a block at a time, the winners of each block competing again with the next."""
    if len(points) <= block:
        return voxel_subsample(np.asarray(points), np.asarray(score), max_points)
    kept = np.zeros(0, dtype=np.int64)
    for a, b in ranges(len(points), block):
        candidates = np.sort(np.concatenate([kept, a + voxel_subsample(points[a:b], score[a:b], max_points)]))
        kept = candidates[voxel_subsample(points[candidates], score[candidates], max_points)]
    return kept


def observation_frames(windows, sources: np.ndarray, views: int) -> np.ndarray:
    """(N, views) frames for points of the given source frames (N,): ``views`` frames spread evenly over
    the window that owns each source (d4rt.reconstruction.windows.owners), the source frame among them
    (it replaces the nearest of the even spread); a window shorter than ``views`` gives all its frames
    and -1 for the rest."""
    sources = np.asarray(sources, dtype=np.int64)
    out = np.full((len(sources), views), -1, dtype=np.int64)
    home = owners(windows, sources)
    for win in np.unique(home):
        a, b = windows[win]
        rows = np.nonzero(home == win)[0]
        if b - a <= views:
            out[rows, :b - a] = np.arange(a, b)
            continue
        spread = np.round(np.linspace(a, b - 1, views)).astype(np.int64)  # distinct: steps are over 1 frame
        out[rows] = spread
        nearest = np.abs(spread[None] - sources[rows, None]).argmin(1)
        out[rows, nearest] = sources[rows]
    return out


def _grid_size(rec, resolution, name: str) -> tuple[int, int]:
    """(H, W) of an output that costs many queries per pixel (dense tracks, moving-object masks): None is the
    encoder's input size where the answerer has one (the input's size for an oracle)."""
    if resolution is None:
        return rec.output_size("encoder" if rec.source.encoder_size is not None else None)
    if isinstance(resolution, str) and resolution not in ("encoder", "original"):
        raise UserError(f"{name} must be 'encoder', 'original' or (H, W), got {resolution!r}")
    return rec.output_size(None if resolution == "original" else resolution)


def _dense_arrays(dense, cam_to_world: np.ndarray) -> dict:
    """The contents of dense_tracks.npz (see docs/outputs.md): tracks in camera k at frame k and in the
    world (camera 0), float32."""
    cam = dense.tracks.points
    world = apply_transform(cam_to_world[None], cam)
    return {"sources": dense.sources.astype(np.int32), "points_camera": cam.astype(np.float32),
            "points_world": world.astype(np.float32), "uv": dense.tracks.uv.astype(np.float32),
            "visibility": dense.tracks.visibility.astype(np.float32),
            "confidence": dense.tracks.confidence.astype(np.float32),
            "resolution": np.array(dense.resolution), "num_queries": np.int64(dense.num_queries),
            "naive_num_queries": np.int64(dense.naive_num_queries), "coverage": np.float64(dense.coverage)}


def _rate(stamps: np.ndarray) -> float:
    steps = np.diff(stamps)
    return 1.0 / float(np.median(steps)) if len(steps) and np.median(steps) > 0 else DEFAULT_FPS
