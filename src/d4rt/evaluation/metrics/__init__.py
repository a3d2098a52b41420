"""Evaluation metrics as pure typed functions (numpy or torch inputs, float results).

Each module documents the protocol it reproduces and where it comes from:
- ``depth``: video depth AbsRel / delta<1.25 with per-sequence alignment (MonST3R / CUT3R / pi3).
- ``pose``: ATE / RPE after Sim(3) alignment (evo) and pose AUC (VGGT).
- ``tracks``: TAPVid-3D APD3D / 3D-AJ / OA (tapnet) and world-frame APD3D / L1.
- ``point_cloud``: L1 after mean shift; accuracy / completeness; ICP and the multi-view protocol.
"""

from d4rt.evaluation.metrics.depth import (
    ALIGNMENTS,
    DepthEvaluation,
    aggregate_depth,
    align_depth,
    depth_metrics,
    evaluate_depth,
)
from d4rt.evaluation.metrics.point_cloud import (
    accuracy_completeness,
    icp,
    multiview_accuracy_completeness,
    point_cloud_l1,
)
from d4rt.evaluation.metrics.pose import (
    auc_from_errors,
    pose_auc,
    pose_metrics,
    relative_pose_errors,
    sim3_alignment,
)
from d4rt.evaluation.metrics.tracks import (
    SCALINGS,
    THRESHOLDS_PX,
    metric_focal_length,
    tapvid3d_metrics,
    tapvid3d_threshold_metrics,
    world_track_metrics,
)

__all__ = [
    "ALIGNMENTS",
    "DepthEvaluation",
    "SCALINGS",
    "THRESHOLDS_PX",
    "accuracy_completeness",
    "icp",
    "multiview_accuracy_completeness",
    "aggregate_depth",
    "align_depth",
    "auc_from_errors",
    "depth_metrics",
    "evaluate_depth",
    "metric_focal_length",
    "point_cloud_l1",
    "pose_auc",
    "pose_metrics",
    "relative_pose_errors",
    "sim3_alignment",
    "tapvid3d_metrics",
    "tapvid3d_threshold_metrics",
    "world_track_metrics",
]
