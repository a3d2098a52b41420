"""Camera-pose metrics: ATE and RPE after Sim(3) alignment (evo conventions) and pose AUC (VGGT convention).

All poses are camera-to-world (T, 4, 4) in OpenCV axes, numpy or torch; computed in float64.

- ATE: the predicted camera centres are Sim(3)-aligned to the ground truth (Umeyama with scale, evo
  ``align=True, correct_scale=True``); ATE is the RMSE of the centre errors (evo APE, translation part).
- RPE: on the same aligned trajectory, for consecutive frames (i, i+1) the error pose is
  E_i = (Q_i^-1 Q_i+1)^-1 (P_i^-1 P_i+1), Q ground truth, P prediction; RPE-trans is the RMSE of |t(E_i)|
  and RPE-rot the RMSE of the rotation angle of E_i in degrees (evo RPE, delta = 1 frame).
- Pose AUC@30: for every frame pair i < j, the angle between the relative rotations and the angle between
  the relative translation directions (sign-agnostic), in degrees; the pair's error is the larger; AUC is
  the mean of the cumulative histogram of pair errors over 1-degree bins up to the threshold (in [0, 1];
  papers print it times 100).
"""

from __future__ import annotations

import numpy as np
import torch

from d4rt.errors import UserError
from d4rt.evaluation.metrics._arrays import as_array, check_finite, check_same_shape, check_shape
from d4rt.geometry.transforms import invert_rigid
from d4rt.geometry.umeyama import Similarity, umeyama


def pose_metrics(pred_cam_to_world, gt_cam_to_world) -> dict[str, float]:
    """ATE, RPE-trans (both in ground-truth units) and RPE-rot (degrees) after Sim(3) alignment.

    pred_cam_to_world, gt_cam_to_world: (T, 4, 4) camera-to-world, T >= 2.
    Returns ``{"ate", "rpe_trans", "rpe_rot"}``.
    """
    pred, gt = _check_trajectories(pred_cam_to_world, gt_cam_to_world)
    aligned = align_trajectory(sim3_alignment(pred, gt), pred)
    ate = _rmse(np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1))
    error = invert_rigid(_consecutive(gt)) @ _consecutive(aligned)
    return {
        "ate": ate,
        "rpe_trans": _rmse(np.linalg.norm(error[:, :3, 3], axis=1)),
        "rpe_rot": _rmse(np.degrees(rotation_angle(error[:, :3, :3]))),
    }


def sim3_alignment(pred_cam_to_world, gt_cam_to_world) -> Similarity:
    """The similarity that best maps the predicted camera centres onto the ground-truth ones (Umeyama,
    as evo: straight-line and two-pose trajectories are fine, the residual is still minimal)."""
    pred, gt = _check_trajectories(pred_cam_to_world, gt_cam_to_world)
    return umeyama(torch.from_numpy(pred[:, :3, 3]), torch.from_numpy(gt[:, :3, 3]), with_scale=True,
                   allow_degenerate=True)


def align_trajectory(similarity: Similarity, cam_to_world: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (T, 4, 4) mapped through a similarity as evo's ``align(correct_scale=True)``
    does: translations scaled, then the rigid part applied on the left (rotations turn, centres move)."""
    rotation = similarity.rotation.double().numpy()
    out = np.array(cam_to_world, dtype=np.float64, copy=True)
    out[:, :3, :3] = rotation @ out[:, :3, :3]
    out[:, :3, 3] = similarity.apply(torch.from_numpy(out[:, :3, 3])).numpy()
    return out


def relative_pose_errors(pred_cam_to_world, gt_cam_to_world) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation-direction errors (degrees) of the relative pose of every pair i < j.

    The relative pose of a pair is P_i^-1 P_j (camera j in camera i's frame). Returns two (T(T-1)/2,)
    arrays in ``itertools.combinations`` order. The translation error ignores the sign of the direction,
    and a zero-length translation has no direction: it counts as 90 degrees (as in VGGT's evaluation).
    """
    pred, gt = _check_trajectories(pred_cam_to_world, gt_cam_to_world)
    i, j = np.triu_indices(len(pred), k=1)
    rel_pred = invert_rigid(pred[i]) @ pred[j]
    rel_gt = invert_rigid(gt[i]) @ gt[j]
    rot_err = np.degrees(rotation_angle(np.swapaxes(rel_gt[:, :3, :3], 1, 2) @ rel_pred[:, :3, :3]))
    t_pred, t_gt = rel_pred[:, :3, 3], rel_gt[:, :3, 3]
    norms = np.linalg.norm(t_pred, axis=1) * np.linalg.norm(t_gt, axis=1)
    cos = np.abs((t_pred * t_gt).sum(1)) / np.where(norms > 0, norms, 1.0)
    trans_err = np.where(norms > 0, np.degrees(np.arccos(np.clip(cos, 0.0, 1.0))), 90.0)
    return rot_err, trans_err


def pose_auc(pred_cam_to_world, gt_cam_to_world, max_threshold: int = 30) -> float:
    """Pose AUC@max_threshold over all frame pairs of one trajectory, in [0, 1]."""
    return auc_from_errors(*relative_pose_errors(pred_cam_to_world, gt_cam_to_world), max_threshold)


def auc_from_errors(rot_errors, trans_errors, max_threshold: int = 30) -> float:
    """AUC of the accuracy curve of max(rotation, translation) error over integer-degree thresholds
    1..max_threshold: the mean of the cumulative histogram with bins [0, 1), ..., [max - 1, max].
    Pool the errors of several trajectories here to get a benchmark-level AUC."""
    rot = as_array(rot_errors, "rot_errors").reshape(-1)
    trans = as_array(trans_errors, "trans_errors").reshape(-1)
    if rot.shape != trans.shape or rot.size == 0:
        raise UserError(f"need equally many (> 0) rotation and translation errors, got {rot.size} and {trans.size}")
    if int(max_threshold) != max_threshold or max_threshold < 1:
        raise UserError(f"max_threshold must be a positive integer number of degrees, got {max_threshold}")
    histogram, _ = np.histogram(np.maximum(rot, trans), bins=np.arange(int(max_threshold) + 1))
    return float(np.mean(np.cumsum(histogram) / rot.size))


def rotation_angle(rotations: np.ndarray) -> np.ndarray:
    """Angle (radians, in [0, pi]) of rotation matrices (..., 3, 3); accurate near 0 (atan2 form)."""
    r = np.asarray(rotations, dtype=np.float64)
    axis = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    trace = r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]
    return np.arctan2(0.5 * np.linalg.norm(axis, axis=-1), 0.5 * (trace - 1.0))


def _consecutive(poses: np.ndarray) -> np.ndarray:
    """Relative poses P_i^-1 P_(i+1) of consecutive frames: (T - 1, 4, 4)."""
    return invert_rigid(poses[:-1]) @ poses[1:]


def _rmse(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors ** 2)))


def _check_trajectories(pred, gt) -> tuple[np.ndarray, np.ndarray]:
    pred = as_array(pred, "pred_cam_to_world")
    gt = as_array(gt, "gt_cam_to_world")
    check_shape(pred, "pred_cam_to_world", (None, 4, 4))
    check_shape(gt, "gt_cam_to_world", (None, 4, 4))
    check_same_shape(pred, gt, "pred_cam_to_world", "gt_cam_to_world")
    if len(pred) < 2:
        raise UserError(f"pose metrics need at least 2 poses, got {len(pred)}")
    check_finite(pred, "pred_cam_to_world")
    check_finite(gt, "gt_cam_to_world")
    return pred, gt
