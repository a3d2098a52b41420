"""Point-cloud metrics on hand-built clouds."""

import numpy as np
import pytest
import torch

from d4rt.errors import UserError
from d4rt.evaluation.metrics import accuracy_completeness, icp, multiview_accuracy_completeness, point_cloud_l1
from d4rt.geometry.transforms import quaternion_to_rotation
from d4rt.geometry.umeyama import umeyama


def test_l1_after_mean_shift():
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(100, 3))
    assert point_cloud_l1(gt + [5.0, -2.0, 1.0], gt) == pytest.approx(0.0, abs=1e-12)  # any shift
    assert point_cloud_l1(gt * 0.5, gt, scale=2.0) == pytest.approx(0.0, abs=1e-12)  # the depth scale
    noisy = gt.copy()
    noisy[::2, 0] += 0.2
    noisy[1::2, 0] -= 0.2  # zero-mean noise: mean shift leaves it, L1 = 0.2 per point
    assert point_cloud_l1(noisy, gt) == pytest.approx(0.2)
    with pytest.raises(UserError, match="same shape"):
        point_cloud_l1(gt[:5], gt)


def test_accuracy_and_completeness():
    gt = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    pred = np.array([[0.0, 0.1, 0], [1, 0.1, 0]])  # covers half of the ground truth, 0.1 off
    out = accuracy_completeness(pred, gt)
    assert out["accuracy"] == pytest.approx(0.1)
    assert out["completeness"] == pytest.approx((0.1 + 0.1 + np.hypot(1, 0.1) + np.hypot(2, 0.1)) / 4)
    with pytest.raises(UserError, match="need points"):
        accuracy_completeness(np.zeros((0, 3)), gt)


def rigid(angle_deg: float, axis, translation) -> np.ndarray:
    """4x4 rotation about ``axis`` by ``angle_deg``, then ``translation``."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    half = np.radians(angle_deg) / 2
    t = np.eye(4)
    t[:3, :3] = quaternion_to_rotation(np.array([*(np.sin(half) * axis), np.cos(half)]))  # (x, y, z, w)
    t[:3, 3] = translation
    return t


def surface(n: int = 40) -> np.ndarray:
    """(n*n, 3) samples of a curved, non-symmetric surface patch about 1 m across."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 0.8, n))
    z = 2 + 0.3 * np.sin(3 * x) * np.cos(2 * y) + 0.2 * x * y
    return np.stack([x, y, z], -1).reshape(-1, 3)


def test_icp_recovers_a_small_rigid_motion_exactly_and_ignores_far_points():
    target = surface()
    true = rigid(0.1, [1, 2, 0.5], [0.003, -0.002, 0.001])  # a small residual (points sit 2 m out)
    source = (target - true[:3, 3]) @ true[:3, :3]  # true^-1 applied to the target
    far = np.random.default_rng(0).uniform(10, 11, size=(300, 3))  # clutter only the target has
    transform, info = icp(source, np.concatenate([target, far]), threshold=0.1, max_iterations=200)
    assert np.allclose(transform, true, atol=1e-7), transform - true
    assert info["fitness"] == 1.0 and info["inlier_rmse"] < 1e-7
    # Source points with no target within the threshold are left out of the fit (fitness drops).
    transform, info = icp(np.concatenate([source, far + 5]), target, threshold=0.1, max_iterations=200)
    assert np.allclose(transform, true, atol=1e-7)
    assert info["fitness"] == pytest.approx(len(source) / (len(source) + 300))
    with pytest.raises(UserError, match="threshold"):
        icp(source, target, threshold=0.0)


def test_multiview_protocol_icp_discounts_what_umeyama_cannot():
    gt = surface()
    sim = rigid(20.0, [0, 1, 0], [0.5, 0.1, -0.3])
    pred = 0.7 * gt @ sim[:3, :3].T + sim[:3, 3]  # the same points, scaled and moved
    # Exact correspondences: exact alignment, nothing left to measure.
    exact = multiview_accuracy_completeness(pred, gt)
    assert exact["accuracy"] < 1e-9 and exact["completeness"] < 1e-9 and exact["fitness"] == 1.0
    # A tenth of the predictions far off (0.5 in depth): least squares (Umeyama) is pulled towards them;
    # ICP (threshold 0.1) leaves them out of its fit and moves the rest towards the ground truth (only
    # towards: it is rigid, as Open3D's, so the scale Umeyama took from the outliers stays).
    pred = gt.copy()
    pred[::10, 2] += 0.5
    pred = 0.7 * pred @ sim[:3, :3].T + sim[:3, 3]
    out = multiview_accuracy_completeness(pred, gt, threshold=0.1)
    fit = umeyama(torch.from_numpy(pred), torch.from_numpy(gt), with_scale=True)
    before = accuracy_completeness(fit.apply(torch.from_numpy(pred)).numpy(), gt)
    assert out["fitness"] == pytest.approx(0.9, abs=0.01)
    assert out["completeness"] < before["completeness"] / 2 and out["accuracy"] < before["accuracy"], (out, before)
