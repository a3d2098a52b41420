"""Video-depth metrics: alignment modes recover known transforms, caps, clipping and weighting."""

import numpy as np
import pytest
import torch
from scipy.optimize import linprog

from d4rt.errors import UserError
from d4rt.evaluation.metrics import aggregate_depth, depth_metrics, evaluate_depth


@pytest.fixture
def gt():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 60.0, (4, 12, 16))
    depth[0, :3] = 0.0  # no ground truth here
    depth[1, 5, 5] = np.nan
    return depth


@pytest.mark.parametrize("align, pred_of", [
    ("median", lambda g: 0.25 * g),
    ("scale", lambda g: 3.7 * g),
    ("scale&shift", lambda g: 0.4 * g - 1.3),
    ("metric", lambda g: g),
])
def test_alignment_recovers_a_known_transform_exactly(gt, align, pred_of):
    pred = np.nan_to_num(pred_of(gt), nan=5.0)
    result = evaluate_depth(pred, gt, align=align)
    assert result.abs_rel < 1e-10 and result.delta_1_25 == 1.0
    valid = np.isfinite(gt) & (gt > 0)
    assert result.valid_pixels == valid.sum()
    # The fitted transform is the inverse of the one applied.
    p, g = pred[valid], gt[valid]
    assert np.allclose(result.scale * p + result.shift, g, rtol=1e-10, atol=1e-9)


def test_scale_and_shift_is_the_l1_optimum():
    """With outliers, the fit equals the linear-programming solution of min sum |s p + t - g|."""
    rng = np.random.default_rng(3)
    g = rng.uniform(1, 10, (1, 20, 20))
    p = 0.5 * g + 2.0 + rng.standard_cauchy(g.shape) * 0.3
    p = np.abs(p) + 0.1
    result = evaluate_depth(p, g, align="scale&shift")
    pv, gv = p.ravel(), g.ravel()
    n = len(pv)
    lp = linprog(np.r_[0, 0, np.ones(n)],
                 A_ub=np.block([[pv[:, None], np.ones((n, 1)), -np.eye(n)],
                                [-pv[:, None], -np.ones((n, 1)), -np.eye(n)]]),
                 b_ub=np.r_[gv, -gv], bounds=[(None, None)] * 2 + [(0, None)] * n)
    ours = np.abs(result.scale * pv + result.shift - gv).sum()
    assert ours == pytest.approx(lp.fun, rel=1e-9)
    # "scale": the weighted-median solution beats every scale on a fine grid.
    s = evaluate_depth(p, g, align="scale").scale
    grid = np.linspace(0.5 * s, 1.5 * s, 2001)
    costs = np.abs(grid[:, None] * pv - gv).sum(1)
    assert np.abs(s * pv - gv).sum() <= costs.min() + 1e-9


def test_metric_values_by_hand():
    gt = np.array([[[1.0, 2.0, 4.0, 8.0]]])
    pred = np.array([[[1.1, 2.0, 2.0, 16.0]]])  # ratios 1.1, 1, 0.5, 2
    out = depth_metrics(pred, gt, align="metric")
    assert out == pytest.approx({"abs_rel": (0.1 + 0 + 0.5 + 1.0) / 4, "delta_1_25": 0.5})
    # Non-positive aligned predictions are never within the threshold.
    out = depth_metrics(np.array([[[-1.0, 2.0]]]), np.array([[[1.0, 2.0]]]), align="metric")
    assert out["delta_1_25"] == 0.5 and out["abs_rel"] == pytest.approx(1.0)


def test_max_depth_cap_and_post_alignment_clipping():
    gt = np.array([[[10.0, 50.0, 69.0, 75.0, 500.0]]])
    pred = gt * 2.0
    capped = evaluate_depth(pred, gt, align="median", max_depth=70)
    assert capped.valid_pixels == 3  # 75 and 500 are beyond the cap
    assert capped.abs_rel < 1e-12
    # Clipping after alignment: a prediction far beyond 70 is clipped to 70 before the metric.
    gt = np.array([[[10.0, 60.0]]])
    pred = np.array([[[10.0, 600.0]]])
    clipped = depth_metrics(pred, gt, align="metric", max_depth=70, clip_max=70)
    assert clipped["abs_rel"] == pytest.approx((10.0 / 60.0) / 2)
    unclipped = depth_metrics(pred, gt, align="metric", max_depth=70)
    assert unclipped["abs_rel"] == pytest.approx((540.0 / 60.0) / 2)


def test_one_alignment_per_sequence_and_pixel_weighted_aggregation():
    """Frames share one scale: a per-frame scale drift is an error, not aligned away."""
    gt = np.ones((3, 4, 4))
    pred = np.stack([np.ones((4, 4)), np.ones((4, 4)), 2 * np.ones((4, 4))])
    out = evaluate_depth(pred, gt, align="median")
    # The median ratio over all frames fits the first two; the third stays off by a factor 2.
    assert out.scale == 1.0 and out.delta_1_25 == pytest.approx(2 / 3)
    small = evaluate_depth(np.full((1, 2, 2), 2.0), np.ones((1, 2, 2)), align="metric")  # abs_rel 1, 4 px
    large = evaluate_depth(np.ones((1, 6, 6)), np.ones((1, 6, 6)), align="metric")  # abs_rel 0, 36 px
    agg = aggregate_depth([small, large])
    assert agg["abs_rel"] == pytest.approx(4 / 40) and agg["valid_pixels"] == 40
    assert agg["delta_1_25"] == pytest.approx(36 / 40)


def test_torch_inputs_and_errors():
    gt = torch.rand(2, 5, 5) + 1
    out = depth_metrics(gt * 3, gt)  # default scale&shift
    assert out["abs_rel"] < 1e-6
    with pytest.raises(UserError, match="same shape"):
        depth_metrics(gt[:1], gt)
    with pytest.raises(UserError, match="align must be one of"):
        depth_metrics(gt, gt, align="affine")
    with pytest.raises(UserError, match="no valid ground-truth"):
        depth_metrics(gt, torch.zeros_like(gt))
    bad = gt.clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(UserError, match="NaN"):
        depth_metrics(bad, gt)
