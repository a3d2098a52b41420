"""3D point-tracking metrics of TAPVid-3D (APD3D, 3D-AJ, OA), following google-deepmind/tapnet's
``tapvid3d/evaluation/metrics.py`` and ``evaluate_model.py``, plus a world-frame variant (APD3D and L1).

Conventions: tracks are (T, N, 3) arrays in the camera of each frame (OpenCV axes, ground-truth units),
visibility is (T, N) boolean (True = visible), intrinsics are (fx, fy, cx, cy) in pixels of the video's
own resolution. Per video:

1. Scale: the prediction is multiplied by one factor (``scaling="median"``: median |gt| / median |pred|
   over the points visible in both; see ``SCALINGS`` for the others).
2. Thresholds are depth-adaptive: for px in (1, 2, 4, 8, 16) a point is within threshold when
   |pred - gt| < px * z_gt / sqrt(fx * fy), with fx, fy rescaled to a video whose shorter side is 256 px.
3. APD3D = mean over thresholds of the fraction of ground-truth-visible points within threshold.
   3D-AJ = mean over thresholds of TP / (ground-truth visible + FP), TP = predicted visible, visible and
   within threshold; FP = predicted visible and (occluded or outside threshold).
   OA = fraction of (t, n) whose predicted visibility equals the ground truth's.
Query frames are not excluded. Benchmarks average these per-video numbers with a plain mean.
"""

from __future__ import annotations

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.metrics._arrays import as_array, check_finite, check_same_shape, check_shape

THRESHOLDS_PX = (1, 2, 4, 8, 16)
METRIC_SHORT_SIDE = 256
SCALINGS = ("median", "mean", "median_on_queries", "per_trajectory", "reproduce_2d", "none")


def tapvid3d_metrics(pred_points, pred_visible, gt_points, gt_visible, intrinsics, image_size,
                     scaling: str = "median", query_frames=None) -> dict[str, float]:
    """APD3D, 3D-AJ and OA of one video, as in TAPVid-3D.

    pred_points, gt_points: (T, N, 3) camera-frame tracks. pred_visible, gt_visible: (T, N) boolean.
    intrinsics: (fx, fy, cx, cy) pixels at ``image_size`` = (H, W) of the video (or (T, 4), one per
    frame, for a camera that zooms). scaling: one of
    ``SCALINGS``: "median" / "mean" (one factor per video from points visible in both), "median_on_queries"
    (median over each track's query frame), "per_trajectory" (each track matches the ground-truth depth at
    its query frame), "reproduce_2d" (every point takes the ground-truth depth along its own ray), "none".
    query_frames: (N,) query frame per track, needed by "median_on_queries" and "per_trajectory".
    Returns ``{"apd3d", "aj", "oa"}``; :func:`tapvid3d_threshold_metrics` has the per-threshold values.
    """
    m = tapvid3d_threshold_metrics(pred_points, pred_visible, gt_points, gt_visible, intrinsics, image_size,
                                   scaling, query_frames)
    return {"apd3d": m["apd3d"], "aj": m["aj"], "oa": m["oa"]}


def tapvid3d_threshold_metrics(pred_points, pred_visible, gt_points, gt_visible, intrinsics, image_size,
                               scaling: str = "median", query_frames=None) -> dict[str, float]:
    """:func:`tapvid3d_metrics` plus ``pts_within_{px}`` and ``jaccard_{px}`` for every threshold."""
    pred, pred_vis, gt, gt_vis = _check_tracks(pred_points, pred_visible, gt_points, gt_visible)
    focal = _check_focal(metric_focal_length(intrinsics, image_size), pred.shape[0])
    pred = pred * track_scale(pred, pred_vis, gt, gt_vis, scaling, query_frames)
    distance = np.linalg.norm(pred - gt, axis=-1)
    out = {"oa": float(np.mean(pred_vis == gt_vis))}
    within_all, jaccard_all = [], []
    for px in THRESHOLDS_PX:
        within = distance < px * gt[..., 2] / focal
        correct = within & gt_vis
        frac = correct.sum() / gt_vis.sum()
        false_pos = pred_vis & (~gt_vis | ~within)
        jaccard = (correct & pred_vis).sum() / (gt_vis.sum() + false_pos.sum())
        out[f"pts_within_{px}"], out[f"jaccard_{px}"] = float(frac), float(jaccard)
        within_all.append(frac)
        jaccard_all.append(jaccard)
    out["apd3d"] = float(np.mean(within_all))
    out["aj"] = float(np.mean(jaccard_all))
    return out


def world_track_metrics(pred_points, gt_points, gt_visible, gt_depth, intrinsics, image_size,
                        scaling: str = "median") -> dict[str, float]:
    """APD3D and L1 of tracks expressed in one shared frame (D4RT's world-coordinate tracking).

    pred_points, gt_points: (T, N, 3) in one frame for the whole video (this project uses the camera of
    frame 0). gt_visible: (T, N). gt_depth: (T, N) ground-truth depth of each point in its own frame's
    camera, which sets the depth-adaptive thresholds exactly as in :func:`tapvid3d_metrics`. scaling:
    "median", "mean" (over ground-truth-visible points) or "none". L1 is the mean over
    ground-truth-visible points of the L1 norm |dx| + |dy| + |dz| of the scaled error (the paper does not
    spell out its L1; this is the definition used here). Returns ``{"apd3d", "l1"}``.
    """
    ones = np.ones(np.shape(gt_visible), dtype=bool)
    pred, _, gt, gt_vis = _check_tracks(pred_points, ones, gt_points, gt_visible)
    depth = as_array(gt_depth, "gt_depth")
    check_same_shape(depth, gt_vis, "gt_depth", "gt_visible")
    check_finite(depth, "gt_depth", gt_vis)
    if scaling not in ("median", "mean", "none"):
        raise UserError(f"world-frame scaling must be 'median', 'mean' or 'none', got {scaling!r}")
    pred = pred * track_scale(pred, gt_vis, gt, gt_vis, scaling)
    focal = np.broadcast_to(_check_focal(metric_focal_length(intrinsics, image_size), pred.shape[0]), depth.shape)
    error = (pred - gt)[gt_vis]
    distance = np.linalg.norm(error, axis=-1)
    within = [np.mean(distance < px * depth[gt_vis] / focal[gt_vis]) for px in THRESHOLDS_PX]
    return {"apd3d": float(np.mean(within)), "l1": float(np.abs(error).sum(-1).mean())}


def metric_focal_length(intrinsics, image_size) -> float | np.ndarray:
    """sqrt(fx * fy) after rescaling the video so its shorter side is 256 px (TAPVid-3D's resolution).

    intrinsics: (fx, fy, cx, cy), or (T, 4) per frame for a zooming camera, which gives (T, 1) focal
    lengths that broadcast over the tracks of each frame.
    """
    k = as_array(intrinsics, "intrinsics")
    if k.shape[-1:] != (4,) or k.ndim > 2:
        raise UserError(f"intrinsics must be (fx, fy, cx, cy) or (T, 4) of them, got shape {k.shape}")
    if len(image_size) != 2 or min(image_size) <= 0:
        raise UserError(f"image_size must be (H, W) with positive sides, got {tuple(image_size)}")
    if not ((k[..., 0] > 0).all() and (k[..., 1] > 0).all()):
        raise UserError("focal lengths fx and fy must be positive")
    factor = METRIC_SHORT_SIDE / min(image_size)
    focal = np.sqrt(k[..., 0] * factor * k[..., 1] * factor)
    return float(focal) if k.ndim == 1 else focal[:, None]


def track_scale(pred: np.ndarray, pred_visible: np.ndarray, gt: np.ndarray, gt_visible: np.ndarray,
                scaling: str, query_frames=None) -> np.ndarray | float:
    """The factor(s) the predicted tracks are multiplied by: a float, (1, N, 1) or (T, N, 1) array."""
    if scaling not in SCALINGS:
        raise UserError(f"scaling must be one of {SCALINGS}, got {scaling!r}")
    if scaling == "none":
        return 1.0
    if scaling == "reproduce_2d":
        return gt[..., 2:] / pred[..., 2:]
    if scaling == "per_trajectory":
        frames = _query_frames(query_frames, pred.shape[:2])
        tracks = np.arange(pred.shape[1])
        z_gt = np.maximum(gt[frames, tracks, 2], 1e-12)
        return (z_gt / np.maximum(pred[frames, tracks, 2], 1e-12))[None, :, None]
    pred_norm = np.sqrt(np.maximum(1e-12, (pred ** 2).sum(-1)))
    gt_norm = np.sqrt(np.maximum(1e-12, (gt ** 2).sum(-1)))
    both = pred_visible & gt_visible
    if scaling == "median_on_queries":
        frames = _query_frames(query_frames, pred.shape[:2])
        tracks = np.arange(pred.shape[1])
        pred_norm, gt_norm, both = (a[frames, tracks] for a in (pred_norm, gt_norm, both))
    if not both.any():
        return float("nan")  # undefined: no point is visible in both; every metric becomes NaN
    reduce = np.mean if scaling == "mean" else np.median
    return float(reduce(gt_norm[both]) / reduce(pred_norm[both]))


def _check_focal(focal, frames: int):
    if isinstance(focal, np.ndarray) and focal.shape[0] != frames:
        raise UserError(f"per-frame intrinsics cover {focal.shape[0]} frames but the tracks have {frames}")
    return focal


def _query_frames(query_frames, tn: tuple[int, int]) -> np.ndarray:
    if query_frames is None:
        raise UserError("this scaling needs query_frames (the query frame of every track)")
    frames = np.round(as_array(query_frames, "query_frames")).astype(np.int64)
    if frames.shape != (tn[1],) or frames.min(initial=0) < 0 or frames.max(initial=0) >= tn[0]:
        raise UserError(f"query_frames must be ({tn[1]},) frame indices in [0, {tn[0] - 1}]")
    return frames


def _check_tracks(pred_points, pred_visible, gt_points, gt_visible):
    pred = as_array(pred_points, "pred_points")
    gt = as_array(gt_points, "gt_points")
    check_shape(pred, "pred_points", (None, None, 3))
    check_same_shape(pred, gt, "pred_points", "gt_points")
    pred_vis = _as_visibility(pred_visible, "pred_visible", pred.shape[:2])
    gt_vis = _as_visibility(gt_visible, "gt_visible", pred.shape[:2])
    if not gt_vis.any():
        raise UserError("gt_visible has no visible point: the metrics are undefined")
    check_finite(pred, "pred_points")
    check_finite(gt, "gt_points", gt_vis)
    # Ground truth of occluded points may be missing (NaN); it is never compared, so zero it.
    gt = np.where(gt_vis[..., None], gt, np.nan_to_num(gt, nan=0.0, posinf=0.0, neginf=0.0))
    return pred, pred_vis, gt, gt_vis


def _as_visibility(value, name: str, shape: tuple[int, int]) -> np.ndarray:
    array = as_array(value, name, dtype=None)
    if array.shape != shape:
        raise UserError(f"{name} must have shape {shape} (T, N), got {tuple(array.shape)}")
    if array.dtype != bool:
        if not np.isin(array, (0, 1)).all():
            raise UserError(f"{name} must be boolean (or 0/1); threshold visibility probabilities first")
        array = array.astype(bool)
    return array
