import numpy as np
import pytest
import torch

from d4rt.errors import UserError
from d4rt.geometry.umeyama import umeyama


def _random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@pytest.mark.parametrize("with_scale", [False, True])
def test_recovers_random_transforms_exactly(with_scale):
    rng = np.random.default_rng(0)
    for _ in range(20):
        rot, trans = _random_rotation(rng), rng.normal(size=3) * 5
        scale = rng.uniform(0.1, 10) if with_scale else 1.0
        src = rng.normal(size=(50, 3)) * rng.uniform(0.1, 10)
        dst = scale * src @ rot.T + trans
        fit = umeyama(torch.from_numpy(src), torch.from_numpy(dst), with_scale=with_scale)
        assert np.allclose(fit.rotation.numpy(), rot, atol=1e-10)
        assert np.allclose(fit.translation.numpy(), trans, atol=1e-9)
        assert np.isclose(float(fit.scale), scale, rtol=1e-10)
        assert np.allclose(fit.apply(torch.from_numpy(src)).numpy(), dst, atol=1e-9)


def test_planar_points_still_give_the_exact_proper_rotation():
    rng = np.random.default_rng(1)
    rot, trans = _random_rotation(rng), rng.normal(size=3)
    src = np.concatenate([rng.normal(size=(30, 2)), np.zeros((30, 1))], 1)  # all in the plane z = 0
    fit = umeyama(torch.from_numpy(src), torch.from_numpy(src @ rot.T + trans), with_scale=True)
    assert np.allclose(fit.rotation.numpy(), rot, atol=1e-10) and np.isclose(float(fit.scale), 1.0)
    assert np.isclose(np.linalg.det(fit.rotation.numpy()), 1.0)


def test_a_mirror_image_gives_a_proper_rotation_not_a_reflection():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(40, 3))
    dst = src * np.array([1.0, 1.0, -1.0])  # a reflection: no rotation maps src onto dst
    fit = umeyama(torch.from_numpy(src), torch.from_numpy(dst))
    assert np.isclose(np.linalg.det(fit.rotation.numpy()), 1.0)


def test_weights_select_the_inliers():
    rng = np.random.default_rng(3)
    rot, trans = _random_rotation(rng), rng.normal(size=3)
    src = rng.normal(size=(60, 3))
    dst = src @ rot.T + trans
    dst[:20] += rng.normal(size=(20, 3)) * 5  # outliers
    w = np.r_[np.zeros(20), np.ones(40)]
    fit = umeyama(torch.from_numpy(src), torch.from_numpy(dst), torch.from_numpy(w))
    assert np.allclose(fit.rotation.numpy(), rot, atol=1e-10)


def test_degenerate_inputs_fail_clearly():
    line = torch.tensor([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], dtype=torch.float64)
    with pytest.raises(UserError, match="collinear"):
        umeyama(line, line + 1)
    with pytest.raises(UserError, match="at least 3"):
        umeyama(line[:2], line[:2])
    with pytest.raises(UserError, match=r"\(N, 3\)"):
        umeyama(torch.zeros(5, 2), torch.zeros(5, 2))


def test_degenerate_inputs_allowed_for_trajectory_evaluation():
    """allow_degenerate: collinear points are aligned (rotation about the line is free, residual minimal),
    coincident source points map onto the target centroid."""
    line = torch.tensor([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], dtype=torch.float64)
    target = line @ torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64).T * 2 + 5
    fit = umeyama(line, target, with_scale=True, allow_degenerate=True)
    assert torch.allclose(fit.apply(line), target) and np.isclose(float(fit.scale), 2.0)
    assert np.isclose(np.linalg.det(fit.rotation.numpy()), 1.0)
    point = torch.ones(3, 3, dtype=torch.float64)
    fit = umeyama(point, line[:3], with_scale=True, allow_degenerate=True)
    assert float(fit.scale) == 0.0 and torch.allclose(fit.apply(point), line[:3].mean(0).expand(3, 3))


def test_rotation_quaternion_round_trip():
    from d4rt.geometry.transforms import quaternion_to_rotation, rotation_to_quaternion

    rng = np.random.default_rng(4)
    rots = np.stack([_random_rotation(rng) for _ in range(200)] + [np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]),
                                                                   np.diag([-1.0, -1, 1]), np.eye(3)])
    q = rotation_to_quaternion(rots)
    assert np.allclose(np.linalg.norm(q, axis=1), 1) and (q[:, 3] >= 0).all()
    assert np.allclose(quaternion_to_rotation(q), rots, atol=1e-12)
