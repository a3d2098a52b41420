"""Camera-pose metrics against the evo package (the field's reference) and on hand-built cases."""

import copy

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from d4rt.errors import UserError
from d4rt.evaluation.metrics import auc_from_errors, pose_auc, pose_metrics, relative_pose_errors
from d4rt.geometry.transforms import rigid

evo_metrics = pytest.importorskip("evo.core.metrics")
evo_trajectory = pytest.importorskip("evo.core.trajectory")


def random_trajectory(rng, frames):
    """A smooth-ish random camera-to-world trajectory."""
    rotations = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.15, (frames, 3)), 0)).as_matrix()
    centres = np.cumsum(rng.normal(0, 0.3, (frames, 3)), 0)
    return rigid(rotations, centres)


def noisy_similar_copy(rng, gt, scale):
    """gt seen through an unknown similarity transform, with pose noise."""
    noise_rot = Rotation.from_rotvec(rng.normal(0, 0.05, (len(gt), 3))).as_matrix()
    noisy = rigid(gt[:, :3, :3] @ noise_rot, gt[:, :3, 3] + rng.normal(0, 0.1, (len(gt), 3)))
    world = rigid(Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(0, 5, 3))
    out = world @ noisy
    out[:, :3, 3] = scale * out[:, :3, 3]
    return out


def evo_reference(pred, gt):
    ref = evo_trajectory.PosePath3D(poses_se3=list(gt))
    est = evo_trajectory.PosePath3D(poses_se3=list(pred))
    est.align(ref, correct_scale=True)
    results = {}
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    results["ate"] = ape.get_statistic(evo_metrics.StatisticsType.rmse)
    for key, relation in (("rpe_trans", evo_metrics.PoseRelation.translation_part),
                          ("rpe_rot", evo_metrics.PoseRelation.rotation_angle_deg)):
        rpe = evo_metrics.RPE(relation, delta=1, delta_unit=evo_metrics.Unit.frames, all_pairs=True)
        rpe.process_data((copy.deepcopy(ref), copy.deepcopy(est)))
        results[key] = rpe.get_statistic(evo_metrics.StatisticsType.rmse)
    return results


@pytest.mark.parametrize("seed", range(6))
def test_ate_rpe_match_evo(seed):
    rng = np.random.default_rng(seed)
    frames = int(rng.integers(3, 60))
    gt = random_trajectory(rng, frames)
    pred = noisy_similar_copy(rng, gt, scale=float(rng.uniform(0.05, 20)))
    ours = pose_metrics(pred, gt)
    reference = evo_reference(pred, gt)
    assert set(ours) == {"ate", "rpe_trans", "rpe_rot"}
    for key in ours:
        assert ours[key] == pytest.approx(reference[key], rel=1e-6, abs=1e-6), key


def test_torch_inputs_and_perfect_prediction_up_to_similarity():
    rng = np.random.default_rng(7)
    gt = random_trajectory(rng, 20)
    world = rigid(Rotation.random(random_state=3).as_matrix(), np.array([1.0, -2.0, 3.0]))
    pred = world @ gt
    pred[:, :3, 3] *= 0.37  # any global scale
    out = pose_metrics(torch.from_numpy(pred), torch.from_numpy(gt))
    assert out["ate"] < 1e-9 and out["rpe_trans"] < 1e-9 and out["rpe_rot"] < 1e-6
    assert pose_auc(pred, gt) == pytest.approx(1.0)


def test_straight_line_trajectories():
    """Collinear predicted centres (a dolly, a car driving straight) leave the alignment's rotation about
    the line free. evo refuses them ("degenerate covariance rank"); here the residual is still minimised,
    and the metrics are the limit of evo's on a trajectory nudged off the line by 1e-7."""
    rng = np.random.default_rng(11)
    frames = 12
    gt = random_trajectory(rng, frames)
    pred = noisy_similar_copy(rng, gt, scale=3.0)
    pred[:, :3, 3] = np.linspace(0, 1, frames)[:, None] * [[0.0, 0.0, 4.0]] + [1, 1, 1]
    nudged = pred.copy()
    nudged[:, :3, 3] += rng.normal(0, 1e-7, (frames, 3))
    ours, reference = pose_metrics(pred, gt), evo_reference(nudged, gt)
    for key in ours:
        assert ours[key] == pytest.approx(reference[key], rel=1e-5), key
    # Two poses can always be matched exactly by a similarity.
    assert pose_metrics(pred[:2], gt[:2])["ate"] == pytest.approx(0.0, abs=1e-12)


def test_pose_auc_known_rotation_error():
    """Every pair off by the same 10.5 degree rotation (and exact translation directions): the pair error
    falls in bin [10, 11), so the accuracy curve is 0 for thresholds 1..10 and 1 for 11..30: AUC = 20/30."""
    rng = np.random.default_rng(2)
    gt = random_trajectory(rng, 6)
    rot_err, trans_err = relative_pose_errors(gt, gt)
    assert np.allclose(rot_err, 0, atol=1e-6) and np.allclose(trans_err, 0, atol=1e-5)
    errors = np.full(15, 10.5)
    assert auc_from_errors(errors, np.zeros(15), 30) == pytest.approx(20 / 30)
    # On a trajectory: pure translation, with the odd cameras of the prediction turned by 10.5 degrees.
    gt = rigid(np.broadcast_to(np.eye(3), (6, 3, 3)), rng.normal(size=(6, 3)))
    spin = Rotation.from_rotvec([0, 0, np.radians(10.5)]).as_matrix()
    pred = gt.copy()
    pred[1::2, :3, :3] = spin  # pairs of one even and one odd frame are off by 10.5 degrees
    rot_err, _ = relative_pose_errors(pred, gt)
    pairs = [(i, j) for i in range(6) for j in range(i + 1, 6)]
    expected = np.array([10.5 if (i + j) % 2 else 0.0 for i, j in pairs])
    assert np.allclose(rot_err, expected, atol=1e-9)


def test_translation_direction_error_is_sign_agnostic():
    gt = rigid(np.broadcast_to(np.eye(3), (2, 3, 3)), np.array([[0, 0, 0], [1.0, 0, 0]]))
    flipped = rigid(np.broadcast_to(np.eye(3), (2, 3, 3)), np.array([[0, 0, 0], [-3.0, 0, 0]]))
    tilted = rigid(np.broadcast_to(np.eye(3), (2, 3, 3)), np.array([[0, 0, 0], [1.0, 1.0, 0]]))
    assert relative_pose_errors(flipped, gt)[1] == pytest.approx([0.0])
    assert relative_pose_errors(tilted, gt)[1] == pytest.approx([45.0])


def test_bad_inputs_raise_user_errors():
    gt = np.broadcast_to(np.eye(4), (5, 4, 4))
    with pytest.raises(UserError, match="same shape"):
        pose_metrics(gt[:4], gt)
    with pytest.raises(UserError, match=r"\(\*, 4, 4\)"):
        pose_metrics(np.zeros((5, 3, 4)), np.zeros((5, 3, 4)))
    bad = gt.copy()
    bad[2, 0, 3] = np.nan
    with pytest.raises(UserError, match="NaN"):
        pose_metrics(bad, gt)
    with pytest.raises(UserError, match="at least 2"):
        pose_metrics(gt[:1], gt[:1])
