"""Point-cloud metrics: L1 after mean shift (MegaSaM / D4RT convention) and accuracy / completeness.

- :func:`point_cloud_l1`: predicted and ground-truth clouds of the whole clip with one point per pixel (so
  they correspond), each shifted to zero mean; the prediction is first multiplied by the sequence's depth
  scale. Reported: the mean over points of the L1 norm |dx| + |dy| + |dz| of the difference.
- :func:`accuracy_completeness`: clouds without correspondence, already aligned. Accuracy is the mean
  distance from each predicted point to its nearest ground-truth point, completeness the mean distance
  from each ground-truth point to its nearest prediction (Euclidean; scipy's KD-tree).
- :func:`icp`: rigid point-to-point ICP with a maximum correspondence distance, the semantics of
  Open3D's ``registration_icp`` with ``TransformationEstimationPointToPoint`` (without scale).
- :func:`multiview_accuracy_completeness`: the CUT3R / pi3 multi-view protocol: Sim(3) Umeyama on
  corresponding points, then ICP (threshold 0.1), then accuracy / completeness.
"""

from __future__ import annotations

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.metrics._arrays import as_array, check_finite, check_same_shape, check_shape


def point_cloud_l1(pred_points, gt_points, scale: float = 1.0) -> float:
    """Mean L1 distance between corresponding points after mean shift.

    pred_points, gt_points: (N, 3) corresponding points (e.g. one per valid pixel of every frame, all in
    one camera's frame). scale: multiplies the prediction first (the sequence's depth alignment scale).
    """
    pred = as_array(pred_points, "pred_points")
    gt = as_array(gt_points, "gt_points")
    check_shape(pred, "pred_points", (None, 3))
    check_same_shape(pred, gt, "pred_points", "gt_points")
    if len(pred) == 0:
        raise UserError("point_cloud_l1 needs at least one point")
    check_finite(pred, "pred_points")
    check_finite(gt, "gt_points")
    pred = scale * pred
    return float(np.abs((pred - pred.mean(0)) - (gt - gt.mean(0))).sum(1).mean())


def accuracy_completeness(pred_points, gt_points) -> dict[str, float]:
    """Mean nearest-neighbour distances pred -> gt ("accuracy") and gt -> pred ("completeness").

    pred_points: (N, 3), gt_points: (M, 3), both in the same (aligned) frame.
    """
    from scipy.spatial import cKDTree

    pred = as_array(pred_points, "pred_points")
    gt = as_array(gt_points, "gt_points")
    check_shape(pred, "pred_points", (None, 3))
    check_shape(gt, "gt_points", (None, 3))
    if len(pred) == 0 or len(gt) == 0:
        raise UserError(f"both clouds need points, got {len(pred)} predicted and {len(gt)} ground-truth")
    check_finite(pred, "pred_points")
    check_finite(gt, "gt_points")
    accuracy = cKDTree(gt).query(pred, workers=-1)[0].mean()
    completeness = cKDTree(pred).query(gt, workers=-1)[0].mean()
    return {"accuracy": float(accuracy), "completeness": float(completeness)}


def icp(source_points, target_points, threshold: float = 0.1, init=None, max_iterations: int = 30,
        tolerance: float = 1e-6) -> tuple[np.ndarray, dict[str, float]]:
    """Rigid ICP: the 4x4 transform T moving ``source_points`` (N, 3) onto ``target_points`` (M, 3).

    Each iteration pairs every transformed source point with its nearest target point, keeps the pairs
    closer than ``threshold`` and refits T by Umeyama (rigid) on them, starting from ``init`` (4x4,
    default identity). It stops after ``max_iterations`` or when the fitness (share of source points
    with a pair) and the inlier RMSE both change by less than ``tolerance`` (relative), as Open3D does.
    Returns T and ``{"fitness", "inlier_rmse", "iterations"}`` of the final pairing.
    """
    import torch
    from scipy.spatial import cKDTree

    from d4rt.geometry.umeyama import umeyama

    src = as_array(source_points, "source_points").astype(np.float64)
    tgt = as_array(target_points, "target_points").astype(np.float64)
    check_shape(src, "source_points", (None, 3))
    check_shape(tgt, "target_points", (None, 3))
    if len(src) < 3 or len(tgt) < 3:
        raise UserError(f"icp needs at least 3 points in each cloud, got {len(src)} and {len(tgt)}")
    if not threshold > 0:
        raise UserError(f"icp threshold must be positive, got {threshold}")
    check_finite(src, "source_points")
    check_finite(tgt, "target_points")
    transform = np.eye(4) if init is None else as_array(init, "init").astype(np.float64)
    check_shape(transform, "init", (4, 4))
    tree = cKDTree(tgt)

    def pairs(t: np.ndarray):
        moved = src @ t[:3, :3].T + t[:3, 3]
        dist, index = tree.query(moved, distance_upper_bound=threshold, workers=-1)
        inlier = np.isfinite(dist)
        fitness = float(inlier.mean())
        rmse = float(np.sqrt(np.mean(dist[inlier] ** 2))) if inlier.any() else 0.0
        return inlier, index, fitness, rmse

    inlier, index, fitness, rmse = pairs(transform)
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        if inlier.sum() < 3:
            break
        fit = umeyama(torch.from_numpy(src[inlier]), torch.from_numpy(tgt[index[inlier]]))
        transform = fit.matrix().numpy()
        inlier, index, new_fitness, new_rmse = pairs(transform)
        converged = (abs(new_fitness - fitness) <= tolerance * max(fitness, 1e-12)
                     and abs(new_rmse - rmse) <= tolerance * max(rmse, 1e-12))
        fitness, rmse = new_fitness, new_rmse
        if converged:
            break
    return transform, {"fitness": fitness, "inlier_rmse": rmse, "iterations": float(iterations)}


def multiview_accuracy_completeness(pred_points, gt_points, threshold: float = 0.1) -> dict[str, float]:
    """The multi-view reconstruction protocol (CUT3R / pi3): align the predicted cloud to the ground truth
    by Sim(3) Umeyama on corresponding points, refine by rigid ICP (``threshold``), then
    :func:`accuracy_completeness`.

    pred_points, gt_points: (N, 3) corresponding points (one per valid pixel of every frame).
    Returns ``accuracy``, ``completeness`` and the ICP ``fitness``.
    """
    import torch

    from d4rt.geometry.umeyama import umeyama

    pred = as_array(pred_points, "pred_points").astype(np.float64)
    gt = as_array(gt_points, "gt_points").astype(np.float64)
    check_shape(pred, "pred_points", (None, 3))
    check_same_shape(pred, gt, "pred_points", "gt_points")
    check_finite(pred, "pred_points")
    check_finite(gt, "gt_points")
    sim = umeyama(torch.from_numpy(pred), torch.from_numpy(gt), with_scale=True)
    aligned = sim.apply(torch.from_numpy(pred)).numpy()
    transform, info = icp(aligned, gt, threshold)
    aligned = aligned @ transform[:3, :3].T + transform[:3, 3]
    return {**accuracy_completeness(aligned, gt), "fitness": info["fitness"]}
