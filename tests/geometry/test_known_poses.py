"""The Sim(3) that carries estimated cameras onto known ones (d4rt.geometry.known_poses)."""

import numpy as np
import pytest

from d4rt.errors import UserError
from d4rt.geometry.known_poses import similarity_to_known_poses
from d4rt.geometry.transforms import rigid, rotation_about_axis, similarity_times_pose


def path(centres: np.ndarray, seed: int = 0) -> np.ndarray:
    """Camera-to-world poses at the given centres (T, 3), each turned its own way."""
    rng = np.random.default_rng(seed)
    return np.stack([rigid(rotation_about_axis(rng.normal(size=3), rng.uniform(0, 0.5)), c) for c in centres])


def a_similarity(scale: float) -> np.ndarray:
    sim = np.eye(4)
    sim[:3, :3] = scale * rotation_about_axis(np.array([0.3, -1.0, 0.2]), 2.1)
    sim[:3, 3] = [4.0, -2.0, 7.5]
    return sim


@pytest.mark.parametrize("centres", [np.random.default_rng(1).normal(size=(9, 3)),           # anywhere
                                     np.linspace(0, 1, 9)[:, None] * np.array([[0.2, 0.0, 1.0]])],  # a straight line
                         ids=["scattered", "collinear"])
def test_the_similarity_is_recovered_exactly(centres):
    estimated = path(centres)
    sim = a_similarity(3.7)
    known = np.stack([similarity_times_pose(sim, p) for p in estimated])
    fitted, rms = similarity_to_known_poses(estimated, known)
    np.testing.assert_allclose(fitted, sim, atol=1e-9)
    assert rms < 1e-9


def test_noisy_estimates_give_the_least_squares_scale_and_their_residual():
    rng = np.random.default_rng(2)
    centres = rng.normal(size=(30, 3))
    known = path(centres)
    estimated = known.copy()
    estimated[:, :3, 3] = (centres + 0.01 * rng.normal(size=centres.shape)) / 2.0  # half the size, a little noise
    fitted, rms = similarity_to_known_poses(estimated, known)
    assert np.cbrt(np.linalg.det(fitted[:3, :3])) == pytest.approx(2.0, rel=0.01)
    assert 0.005 < rms < 0.03


@pytest.mark.parametrize("known, message", [
    (np.tile(np.eye(4), (5, 1, 1)), "does not move"),
    (np.zeros((4, 4, 4)), r"\(5, 4, 4\)"),
    (np.tile(np.diag([2.0, 1.0, 1.0, 1.0]), (5, 1, 1)), "not orthonormal"),
    (np.full((5, 4, 4), np.nan), "NaN")])
def test_poses_that_cannot_fix_a_scale_are_one_line_errors(known, message):
    estimated = path(np.random.default_rng(3).normal(size=(5, 3)))
    with pytest.raises(UserError, match=message) as error:
        similarity_to_known_poses(estimated, known)
    assert "\n" not in str(error.value)


def test_a_path_run_backwards_is_refused():
    centres = np.linspace(0, 1, 6)[:, None] * np.array([[1.0, 0.0, 0.0]])
    estimated, known = path(centres), path(-centres)  # same orientations, centres mirrored through the origin
    with pytest.raises(UserError, match="fitted scale <= 0"):
        similarity_to_known_poses(estimated, known)
