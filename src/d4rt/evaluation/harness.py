"""The evaluation harness: every method on every sequence of a benchmark, per-sequence rows and the
benchmark-level aggregate, each number computed by ``d4rt.evaluation.metrics``.

Columns (None where a method does not predict it or the benchmark has no ground truth for it):
- ``abs_rel[<align>]``, ``delta<1.25[<align>]`` for each of the benchmark's depth alignments;
  aggregated over sequences weighted by valid pixels.
- ``ate``, ``rpe_trans``, ``rpe_rot`` (degrees): mean over sequences; ``auc@30``: pose AUC (in [0, 1])
  over the pooled frame pairs of all sequences; ``registered``: fraction of frames with a pose. Pose
  metrics use the registered frames only and need at least 3 of them (a similarity fits 2 exactly).
- ``apd3d``, ``aj``, ``oa``: TAPVid-3D metrics in each frame's camera, median scaling, thresholds from
  the ground-truth intrinsics (per frame when the camera zooms); ``world_apd3d``, ``world_l1``: tracks
  in the camera of frame 0. Plain mean over sequences (over subsets of means for TAPVid-3D).
- ``pc_l1``: point-cloud L1 after mean shift, with the prediction scaled by its L1-optimal depth scale,
  over pixels with ground truth (below the depth cap) and a prediction. Mean over sequences.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from d4rt.progress import progress_bar

from d4rt.errors import UserError
from d4rt.evaluation.benchmarks import Benchmark
from d4rt.evaluation.metrics import (
    aggregate_depth,
    align_depth,
    auc_from_errors,
    evaluate_depth,
    point_cloud_l1,
    pose_metrics,
    relative_pose_errors,
    tapvid3d_metrics,
    world_track_metrics,
)
from d4rt.evaluation.metrics.depth import DepthEvaluation
from d4rt.evaluation.predictions import Prediction, Predictor
from d4rt.evaluation.sequence import EvalSequence

MIN_REGISTERED_FRAMES = 3
POSE_AUC_THRESHOLD = 30


@dataclass
class SequenceResult:
    """One row: the metrics of one method on one sequence, plus what the aggregate needs."""

    name: str
    metrics: dict[str, float | None]
    notes: list[str] = field(default_factory=list)
    depth: dict[str, DepthEvaluation] = field(default_factory=dict)
    pose_errors: tuple[np.ndarray, np.ndarray] | None = None
    frames: int = 0
    registered: int = 0
    # (K, 2) [confidence, relative depth error] of up to CONFIDENCE_SAMPLES valid pixels, the first depth
    # alignment applied: whether the method's confidence tells its good pixels from its bad ones.
    confidence_errors: np.ndarray | None = None

    @property
    def valid_pixels(self) -> int | None:
        """Pixels with a true depth: the sequence's weight in the pooled depth figures (None without depth)."""
        return next(iter(self.depth.values())).valid_pixels if self.depth else None


@dataclass
class MethodResults:
    method: str
    rows: list[SequenceResult]
    aggregate: dict[str, float | None]


def metric_columns(benchmark: Benchmark) -> list[str]:
    """The columns of a benchmark's tables, in order."""
    columns = []
    if "depth" in benchmark.tasks:
        for align in benchmark.depth_alignments:
            columns += [f"abs_rel[{align}]", f"delta<1.25[{align}]"]
    if "pose" in benchmark.tasks:
        columns += ["ate", "rpe_trans", "rpe_rot", f"auc@{POSE_AUC_THRESHOLD}", "registered"]
    if "tracks" in benchmark.tasks:
        columns += ["apd3d", "aj", "oa"]
    if "world_tracks" in benchmark.tasks:
        columns += ["world_apd3d", "world_l1"]
    if "point_cloud" in benchmark.tasks:
        columns += ["pc_l1"]
    return columns


def evaluate_sequence(benchmark: Benchmark, sequence: EvalSequence, prediction: Prediction) -> SequenceResult:
    """Score one prediction against one sequence's ground truth."""
    result = SequenceResult(sequence.name, dict.fromkeys(metric_columns(benchmark)), list(prediction.notes),
                            frames=sequence.num_frames)
    m = result.metrics
    tasks = set(benchmark.tasks)
    if "depth" in tasks and sequence.depth is not None and prediction.depth is not None:
        for align in benchmark.depth_alignments:
            ev = evaluate_depth(prediction.depth, sequence.depth, align, benchmark.max_depth,
                                clip_max=benchmark.clip_max)
            result.depth[align] = ev
            m[f"abs_rel[{align}]"], m[f"delta<1.25[{align}]"] = ev.abs_rel, ev.delta_1_25
        if prediction.depth_confidence is not None:
            result.confidence_errors = confidence_error_samples(prediction.depth, prediction.depth_confidence,
                                                                sequence.depth, result.depth[benchmark.depth_alignments[0]],
                                                                benchmark.max_depth)
    if "pose" in tasks and sequence.cam_to_world is not None and prediction.cam_to_world is not None:
        _score_poses(result, sequence, prediction)
    tracks = sequence.tracks
    if tracks is not None and "tracks" in tasks and prediction.tracks is not None:
        m.update(tapvid3d_metrics(prediction.tracks, prediction.track_visible, tracks.points, tracks.visible,
                                  track_intrinsics(sequence), sequence.image_size, benchmark.track_scaling))
    gt_world = sequence.world_tracks() if "world_tracks" in tasks else None
    if gt_world is not None and prediction.world_tracks is not None:
        world = world_track_metrics(prediction.world_tracks, gt_world, tracks.visible, tracks.points[..., 2],
                                    track_intrinsics(sequence), sequence.image_size, benchmark.track_scaling)
        m["world_apd3d"], m["world_l1"] = world["apd3d"], world["l1"]
    gt_map = sequence.point_map() if "point_cloud" in tasks else None
    if gt_map is not None and prediction.point_map is not None:
        m["pc_l1"] = _point_cloud_l1(benchmark, sequence, prediction, gt_map)
    return result


CONFIDENCE_SAMPLES = 4096


def confidence_error_samples(depth: np.ndarray, confidence: np.ndarray, gt: np.ndarray, fit: DepthEvaluation,
                             max_depth: float | None = None, count: int = CONFIDENCE_SAMPLES) -> np.ndarray:
    """(K, 2) [confidence, |aligned depth - gt| / gt] at up to ``count`` valid pixels drawn with a fixed seed,
    the depth aligned by ``fit``'s scale and shift (the sequence's own alignment)."""
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(gt) & (gt > 0) & np.isfinite(depth) & np.isfinite(confidence)
        if max_depth is not None:
            valid &= gt < max_depth
    index = np.flatnonzero(valid)
    if len(index) > count:
        index = np.sort(np.random.default_rng(0).choice(index, count, replace=False))
    g = gt.reshape(-1)[index]
    error = np.abs(fit.scale * depth.reshape(-1)[index] + fit.shift - g) / g
    return np.stack([confidence.reshape(-1)[index], error], 1)


def _score_poses(result: SequenceResult, sequence: EvalSequence, prediction: Prediction) -> None:
    registered = np.ones(sequence.num_frames, bool) if prediction.registered is None else prediction.registered
    result.registered = int(registered.sum())
    result.metrics["registered"] = result.registered / sequence.num_frames
    if result.registered < MIN_REGISTERED_FRAMES:
        result.notes.append(f"pose metrics not computed: {result.registered} registered frame(s), "
                            f"need {MIN_REGISTERED_FRAMES}")
        return
    pred, gt = prediction.cam_to_world[registered], sequence.cam_to_world[registered]
    result.metrics.update(pose_metrics(pred, gt))
    result.pose_errors = relative_pose_errors(pred, gt)
    result.metrics[f"auc@{POSE_AUC_THRESHOLD}"] = auc_from_errors(*result.pose_errors, POSE_AUC_THRESHOLD)


def track_intrinsics(sequence: EvalSequence) -> np.ndarray:
    """(fx, fy, cx, cy), per frame (T, 4) if the camera zooms."""
    if sequence.intrinsics is None:
        raise UserError(f"{sequence.name}: 3D-track metrics need the ground-truth intrinsics")
    k = sequence.intrinsics
    per_frame = np.stack([k[:, 0, 0], k[:, 1, 1], k[:, 0, 2], k[:, 1, 2]], 1)
    return per_frame[0] if np.allclose(per_frame, per_frame[0]) else per_frame


def _point_cloud_l1(benchmark: Benchmark, sequence: EvalSequence, prediction: Prediction,
                    gt_map: np.ndarray) -> float:
    valid = np.isfinite(gt_map).all(-1) & np.isfinite(prediction.point_map).all(-1)
    if benchmark.max_depth is not None:
        valid &= sequence.depth < benchmark.max_depth
    if not valid.any():
        raise UserError(f"{sequence.name}: no pixel has both a ground-truth and a predicted 3D point")
    scale = 1.0
    if prediction.depth is not None:
        scale, _ = align_depth(prediction.depth[valid].astype(np.float64), sequence.depth[valid].astype(np.float64),
                               "scale")
    return point_cloud_l1(prediction.point_map[valid], gt_map[valid], scale)


def aggregate(benchmark: Benchmark, rows: list[SequenceResult]) -> dict[str, float | None]:
    """Benchmark-level numbers from per-sequence rows (rules in the module docstring)."""
    out: dict[str, float | None] = dict.fromkeys(metric_columns(benchmark))
    for align in benchmark.depth_alignments:
        evaluations = [r.depth[align] for r in rows if align in r.depth]
        if evaluations:
            agg = aggregate_depth(evaluations)
            out[f"abs_rel[{align}]"], out[f"delta<1.25[{align}]"] = agg["abs_rel"], agg["delta_1_25"]
    for key in ("ate", "rpe_trans", "rpe_rot", "pc_l1"):
        if key in out:
            out[key] = _mean([r.metrics[key] for r in rows])
    with_errors = [r.pose_errors for r in rows if r.pose_errors is not None]
    if with_errors:
        out[f"auc@{POSE_AUC_THRESHOLD}"] = auc_from_errors(np.concatenate([e[0] for e in with_errors]),
                                                           np.concatenate([e[1] for e in with_errors]),
                                                           POSE_AUC_THRESHOLD)
    scored = [r for r in rows if r.metrics.get("registered") is not None]
    if scored:
        out["registered"] = sum(r.registered for r in scored) / sum(r.frames for r in scored)
    for key in ("apd3d", "aj", "oa", "world_apd3d", "world_l1"):
        if key in out:
            out[key] = _group_mean(rows, key) if benchmark.group_by_subset else _mean([r.metrics[key] for r in rows])
    return out


def _mean(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def _group_mean(rows: list[SequenceResult], key: str) -> float | None:
    """Mean over subsets (name prefix before '/') of the mean over each subset's sequences."""
    groups: dict[str, list[float | None]] = {}
    for r in rows:
        groups.setdefault(r.name.split("/")[0] if "/" in r.name else "", []).append(r.metrics[key])
    return _mean([_mean(values) for values in groups.values()])


def run_benchmark(benchmark: Benchmark, predictors: list[Predictor], data: Path | None = None,
                  limit: int | None = None, progress: bool = True, store=None) -> list[MethodResults]:
    """Evaluate every predictor on the benchmark's sequences (each sequence is read once).

    store: a :class:`~d4rt.evaluation.partial_results.PartialResults` (or None): rows it already holds are reused
    (a sequence all of whose rows it holds is not even read) and each new row is put into it when scored.
    """
    if not predictors:
        raise UserError("nothing to evaluate: give a checkpoint and/or baselines")
    if len({p.name for p in predictors}) != len(predictors):
        raise UserError(f"methods must have distinct names, got {[p.name for p in predictors]}")
    names = benchmark.sequence_names(data)
    if limit is not None:
        if limit < 1:
            raise UserError(f"--limit must be at least 1, got {limit}")
        names = names[:limit]
    rows: dict[str, list[SequenceResult]] = {p.name: [] for p in predictors}
    tasks = set(benchmark.tasks)
    bar = progress_bar(total=len(names) * len(predictors), desc=f"eval {benchmark.name}", unit="run", disable=not progress)
    for name in names:
        stored = {p.name: store.get(p.name, name) if store is not None else None for p in predictors}
        sequence = None if all(r is not None for r in stored.values()) else benchmark.load(data, name)
        for predictor in predictors:
            bar.set_postfix_str(f"{name} / {predictor.name}")
            result = stored[predictor.name]
            if result is None:
                result = evaluate_sequence(benchmark, sequence, predictor.predict(sequence, tasks))
                result.notes = sequence.notes + result.notes
                if store is not None:
                    store.put(predictor.name, name, result)
            rows[predictor.name].append(result)
            bar.update()
    bar.close()
    return [MethodResults(p.name, rows[p.name], aggregate(benchmark, rows[p.name])) for p in predictors]
