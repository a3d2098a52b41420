"""Point-cloud metrics: L1 after mean shift (MegaSaM / D4RT convention) and accuracy / completeness.

- :func:`point_cloud_l1`: predicted and ground-truth clouds of the whole clip with one point per pixel (so
  they correspond), each shifted to zero mean; the prediction is first multiplied by the sequence's depth
  scale. Reported: the mean over points of the L1 norm |dx| + |dy| + |dz| of the difference.
- :func:`accuracy_completeness`: clouds without correspondence, already aligned. Accuracy is the mean
  distance from each predicted point to its nearest ground-truth point, completeness the mean distance
  from each ground-truth point to its nearest prediction (Euclidean; scipy's KD-tree). The CUT3R / pi3
  multi-view protocol first aligns with Umeyama and ICP (Open3D, threshold 0.1); that ICP step is not
  part of this function.
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
