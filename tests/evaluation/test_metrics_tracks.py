"""TAPVid-3D metrics on hand-built cases with known answers."""

import numpy as np
import pytest
import torch

from d4rt.errors import UserError
from d4rt.evaluation.metrics import (
    metric_focal_length,
    tapvid3d_metrics,
    tapvid3d_threshold_metrics,
    world_track_metrics,
)

# A 128 x 200 video with fx = fy = 50: rescaled to a 256 short side, sqrt(fx fy) = 100 px. At depth 10 the
# thresholds px * z / f are then 0.1, 0.2, 0.4, 0.8 and 1.6 for px = 1, 2, 4, 8, 16.
IMAGE_SIZE = (128, 200)
INTRINSICS = (50.0, 50.0, 99.5, 63.5)
# Offsets of five equal groups of tracks and how many thresholds each passes: 5, 4, 3, 1, 0.
OFFSETS = (0.05, 0.15, 0.3, 1.0, 5.0)
EXPECTED_WITHIN = np.array([1, 2, 3, 3, 4]) / 5  # fraction within px = 1, 2, 4, 8, 16


def flat_tracks(frames=6, per_group=4):
    """Tracks at depth 10 spread in x and y, moving sideways over time: (T, N, 3)."""
    rng = np.random.default_rng(0)
    n = per_group * len(OFFSETS)
    xy = rng.uniform(-3, 3, (1, n, 2)) + np.linspace(0, 1, frames)[:, None, None]
    return np.concatenate([xy, np.full((frames, n, 1), 10.0)], -1)


def offset_prediction(gt, per_group=4):
    """Each group displaced by its offset along y (all at the same depth, so thresholds are the same)."""
    pred = gt.copy()
    pred[..., 1] += np.repeat(OFFSETS, per_group)[None]
    return pred


def test_perfect_prediction_scores_one():
    gt = flat_tracks()
    visible = np.ones(gt.shape[:2], bool)
    visible[2, :5] = False
    out = tapvid3d_metrics(gt, visible, gt, visible, INTRINSICS, IMAGE_SIZE)
    assert out == {"apd3d": 1.0, "aj": 1.0, "oa": 1.0}
    assert metric_focal_length(INTRINSICS, IMAGE_SIZE) == pytest.approx(100.0)


def test_known_offsets_give_the_expected_threshold_fractions():
    gt = flat_tracks()
    pred = offset_prediction(gt)
    visible = np.ones(gt.shape[:2], bool)
    out = tapvid3d_threshold_metrics(pred, visible, gt, visible, INTRINSICS, IMAGE_SIZE, scaling="none")
    within = np.array([out[f"pts_within_{px}"] for px in (1, 2, 4, 8, 16)])
    assert np.allclose(within, EXPECTED_WITHIN)
    # Everything predicted visible and visible: FP are the points outside the threshold, so
    # Jaccard = a / (1 + (1 - a)) for a fraction a within.
    jaccard = np.array([out[f"jaccard_{px}"] for px in (1, 2, 4, 8, 16)])
    assert np.allclose(jaccard, EXPECTED_WITHIN / (2 - EXPECTED_WITHIN))
    assert out["apd3d"] == pytest.approx(EXPECTED_WITHIN.mean())
    assert out["aj"] == pytest.approx(np.mean(EXPECTED_WITHIN / (2 - EXPECTED_WITHIN)))
    assert out["oa"] == 1.0


def test_occlusion_terms():
    """Occluded ground truth predicted visible: a false positive for AJ and an OA miss; APD ignores it.
    Visible ground truth predicted occluded: counts for APD, not as a true positive for AJ."""
    gt = flat_tracks(frames=5, per_group=2)  # 10 tracks, 50 (t, n) entries
    gt_vis = np.ones(gt.shape[:2], bool)
    gt_vis[0, :5] = False  # 5 occluded entries, predicted visible
    pred_vis = np.ones_like(gt_vis)
    pred_vis[1, :5] = False  # 5 visible entries predicted occluded
    out = tapvid3d_metrics(gt, pred_vis, gt, gt_vis, INTRINSICS, IMAGE_SIZE, scaling="none")
    assert out["apd3d"] == 1.0
    assert out["oa"] == pytest.approx(40 / 50)
    assert out["aj"] == pytest.approx(40 / (45 + 5))  # TP 40; ground-truth visible 45; FP 5


def test_median_scaling_is_scale_invariant():
    gt = flat_tracks()
    pred = offset_prediction(gt)
    visible = np.ones(gt.shape[:2], bool)
    visible[::2, ::3] = False
    reference = tapvid3d_metrics(pred, visible, gt, visible, INTRINSICS, IMAGE_SIZE)
    for factor in (0.01, 0.5, 7.0, 1e3):
        scaled = tapvid3d_metrics(pred * factor, visible, gt, visible, INTRINSICS, IMAGE_SIZE)
        assert scaled == pytest.approx(reference)
    # Perfect up to scale is perfect.
    assert tapvid3d_metrics(gt * 0.2, visible, gt, visible, INTRINSICS, IMAGE_SIZE) == pytest.approx(
        {"apd3d": 1.0, "aj": 1.0, "oa": 1.0})
    # Without scaling it is not.
    assert tapvid3d_metrics(gt * 0.2, visible, gt, visible, INTRINSICS, IMAGE_SIZE, scaling="none")["apd3d"] == 0


def test_other_scalings():
    gt = flat_tracks(frames=4, per_group=2)
    visible = np.ones(gt.shape[:2], bool)
    per_track = np.linspace(0.5, 3.0, gt.shape[1])[None, :, None]
    query_frames = np.zeros(gt.shape[1], int)
    # Each track off by its own factor: only per-trajectory scaling recovers it.
    out = tapvid3d_metrics(gt * per_track, visible, gt, visible, INTRINSICS, IMAGE_SIZE,
                           scaling="per_trajectory", query_frames=query_frames)
    assert out["apd3d"] == pytest.approx(1.0)
    assert tapvid3d_metrics(gt * per_track, visible, gt, visible, INTRINSICS, IMAGE_SIZE)["apd3d"] < 1.0
    # reproduce_2d moves every point along its ray to the true depth: only the 2D error remains.
    along_rays = gt * np.random.default_rng(1).uniform(0.5, 2.0, gt.shape[:2])[..., None]
    out = tapvid3d_metrics(along_rays, visible, gt, visible, INTRINSICS, IMAGE_SIZE, scaling="reproduce_2d")
    assert out["apd3d"] == pytest.approx(1.0)
    for scaling in ("mean", "median_on_queries"):
        out = tapvid3d_metrics(gt * 4.0, visible, gt, visible, INTRINSICS, IMAGE_SIZE, scaling=scaling,
                               query_frames=query_frames)
        assert out["apd3d"] == pytest.approx(1.0)
    with pytest.raises(UserError, match="query_frames"):
        tapvid3d_metrics(gt, visible, gt, visible, INTRINSICS, IMAGE_SIZE, scaling="per_trajectory")


def test_world_frame_metrics():
    gt = flat_tracks()
    visible = np.ones(gt.shape[:2], bool)
    depth = gt[..., 2]  # here the shared frame is the camera itself
    out = world_track_metrics(offset_prediction(gt) * 3.0, gt, visible, depth, INTRINSICS, IMAGE_SIZE,
                              scaling="none")
    assert out["apd3d"] < 0.1
    out = world_track_metrics(gt * 3.0, gt, visible, depth, INTRINSICS, IMAGE_SIZE)
    assert out == pytest.approx({"apd3d": 1.0, "l1": 0.0})
    pred = gt.copy()
    pred[..., 0] += 0.3
    pred[..., 2] -= 0.1
    out = world_track_metrics(pred, gt, visible, depth, INTRINSICS, IMAGE_SIZE, scaling="none")
    assert out["l1"] == pytest.approx(0.4)
    assert out["apd3d"] == pytest.approx(3 / 5)  # |err| = 0.316: within 0.4, 0.8, 1.6


def test_inputs_torch_probabilities_and_shapes():
    gt = torch.from_numpy(flat_tracks())
    visible = torch.ones(gt.shape[:2], dtype=torch.bool)
    assert tapvid3d_metrics(gt, visible, gt, visible.float(), INTRINSICS, IMAGE_SIZE)["apd3d"] == 1.0
    with pytest.raises(UserError, match="threshold visibility"):
        tapvid3d_metrics(gt, visible.float() * 0.7, gt, visible, INTRINSICS, IMAGE_SIZE)
    with pytest.raises(UserError, match="same shape"):
        tapvid3d_metrics(gt[:, :3], visible[:, :3], gt, visible, INTRINSICS, IMAGE_SIZE)
    with pytest.raises(UserError, match=r"\(fx, fy, cx, cy\)"):
        tapvid3d_metrics(gt, visible, gt, visible, (50.0, 50.0), IMAGE_SIZE)
    # Occluded ground truth may be missing (NaN): it is never compared.
    missing = gt.clone()
    hidden = visible.clone()
    missing[0, 0] = float("nan")
    hidden[0, 0] = False
    assert tapvid3d_metrics(gt, hidden, missing, hidden, INTRINSICS, IMAGE_SIZE)["apd3d"] == 1.0


def test_per_frame_intrinsics_of_a_zooming_camera():
    """With (T, 4) intrinsics each frame's threshold uses its own focal length: a 2.5x longer focal length
    in the second half of the video divides the thresholds there by 2.5."""
    gt = flat_tracks()
    pred = offset_prediction(gt)
    visible = np.ones(gt.shape[:2], bool)
    per_frame = np.tile(INTRINSICS, (gt.shape[0], 1))
    constant = tapvid3d_threshold_metrics(pred, visible, gt, visible, per_frame, IMAGE_SIZE, scaling="none")
    assert constant["apd3d"] == pytest.approx(EXPECTED_WITHIN.mean())
    per_frame[3:, :2] *= 2.5  # thresholds 0.04, 0.08, 0.16, 0.32, 0.64 in frames 3..5
    zoomed = tapvid3d_threshold_metrics(pred, visible, gt, visible, per_frame, IMAGE_SIZE, scaling="none")
    zoomed_within = np.array([0, 1, 2, 3, 3]) / 5  # offsets 0.05, 0.15, 0.3, 1.0, 5.0 against those
    assert zoomed["apd3d"] == pytest.approx((EXPECTED_WITHIN.mean() + zoomed_within.mean()) / 2)
