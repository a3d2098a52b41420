"""Point-cloud metrics on hand-built clouds."""

import numpy as np
import pytest

from d4rt.errors import UserError
from d4rt.evaluation.metrics import accuracy_completeness, point_cloud_l1


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
