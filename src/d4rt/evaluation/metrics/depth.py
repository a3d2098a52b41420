"""Video-depth metrics as in the MonST3R -> CUT3R -> pi3 evaluations (AbsRel, delta < 1.25).

Protocol (one sequence):
1. Predictions are at the ground truth's resolution; all frames are stacked, so there is ONE alignment
   per sequence.
2. Valid pixels: finite ground truth with 0 < gt < max_depth (no upper cap when max_depth is None).
3. Alignment over the valid pixels, ``align``:
   - ``"median"``: s = median(gt) / median(pred);
   - ``"scale"``: the L1-optimal scale, argmin_s sum |s p - g|;
   - ``"scale&shift"``: the L1-optimal scale and shift, argmin_{s,t} sum |s p + t - g|;
   - ``"metric"``: none.
   The L1 problems are solved to convergence: "scale" exactly (a weighted median), "scale&shift" by a
   golden-section search over s with the optimal t = median(g - s p) for each s (the objective is convex
   in s). The public reference scripts approximate the same objectives with 10 IRLS steps ("scale") and
   1,000 Adam steps from the median ratio ("scale&shift"), so their alignment can be slightly worse.
4. Optional post-alignment clipping of the prediction to ``clip_max`` (Sintel: 70).
5. AbsRel = mean |p - g| / g; delta<1.25 = mean(max(p/g, g/p) < 1.25), where a non-positive aligned
   prediction counts as outside the threshold.
Across sequences, metrics are averaged with weights equal to each sequence's number of valid pixels
(:func:`aggregate_depth`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.metrics._arrays import as_array, check_finite, check_same_shape

ALIGNMENTS = ("median", "scale", "scale&shift", "metric")
DELTA_THRESHOLD = 1.25


@dataclass(frozen=True)
class DepthEvaluation:
    """Metrics of one sequence plus what is needed to aggregate and audit them."""

    abs_rel: float
    delta_1_25: float
    valid_pixels: int
    scale: float
    shift: float

    def as_dict(self) -> dict:
        return asdict(self)


def depth_metrics(pred, gt, align: str = "scale&shift", max_depth: float | None = None, *,
                  clip_max: float | None = None) -> dict[str, float]:
    """AbsRel and delta<1.25 of one sequence, aligned once over all its frames.

    pred, gt: (T, H, W) (or (H, W)) depths of equal shape, numpy or torch; gt <= 0 or non-finite marks
    pixels without ground truth. align: one of ``ALIGNMENTS``. max_depth: ground-truth cap (valid pixels
    have gt < max_depth). clip_max: clip the aligned prediction to at most this value.
    Returns ``{"abs_rel", "delta_1_25"}``; see :func:`evaluate_depth` for the pixel count and alignment.
    """
    result = evaluate_depth(pred, gt, align, max_depth, clip_max=clip_max)
    return {"abs_rel": result.abs_rel, "delta_1_25": result.delta_1_25}


def evaluate_depth(pred, gt, align: str = "scale&shift", max_depth: float | None = None, *,
                   clip_max: float | None = None) -> DepthEvaluation:
    """Like :func:`depth_metrics`, returning also the valid-pixel count and the fitted scale and shift."""
    if align not in ALIGNMENTS:
        raise UserError(f"align must be one of {ALIGNMENTS}, got {align!r}")
    pred = as_array(pred, "pred depth")
    gt = as_array(gt, "gt depth")
    check_same_shape(pred, gt, "pred depth", "gt depth")
    if pred.ndim not in (2, 3):
        raise UserError(f"depth maps must have shape (T, H, W) or (H, W), got {pred.shape}")
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(gt) & (gt > 0)
        if max_depth is not None:
            valid &= gt < max_depth
    count = int(valid.sum())
    if count == 0:
        raise UserError("no valid ground-truth depth pixels (0 < gt < max_depth) in this sequence")
    check_finite(pred, "pred depth", valid)
    p, g = pred[valid], gt[valid]
    scale, shift = align_depth(p, g, align)
    p = scale * p + shift
    if clip_max is not None:
        p = np.minimum(p, clip_max)
    abs_rel = float(np.mean(np.abs(p - g) / g))
    with np.errstate(divide="ignore"):
        ratio = np.where(p > 0, np.maximum(p / g, g / np.where(p > 0, p, 1.0)), np.inf)
    return DepthEvaluation(abs_rel, float(np.mean(ratio < DELTA_THRESHOLD)), count, scale, shift)


def align_depth(pred: np.ndarray, gt: np.ndarray, align: str) -> tuple[float, float]:
    """(scale, shift) aligning valid predictions (n,) to ground truth (n,) under ``align`` (module doc)."""
    if align == "metric":
        return 1.0, 0.0
    if align == "median":
        return float(np.median(gt) / np.median(pred)), 0.0
    if align == "scale":
        return l1_scale(pred, gt), 0.0
    if align == "scale&shift":
        return l1_scale_and_shift(pred, gt)
    raise UserError(f"align must be one of {ALIGNMENTS}, got {align!r}")


def l1_scale(pred: np.ndarray, gt: np.ndarray) -> float:
    """argmin_s sum |s p - g|, exactly: sum |p| |s - g / p| is minimised by the |p|-weighted median of g / p."""
    keep = pred != 0
    if not keep.any():
        raise UserError("cannot fit a depth scale: every prediction is zero")
    ratios, weights = gt[keep] / pred[keep], np.abs(pred[keep])
    order = np.argsort(ratios, kind="stable")
    cumulative = np.cumsum(weights[order])
    return float(ratios[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def l1_scale_and_shift(pred: np.ndarray, gt: np.ndarray, rel_tol: float = 1e-12) -> tuple[float, float]:
    """argmin_{s,t} sum |s p + t - g|.

    For fixed s the best t is median(g - s p), and F(s) = min_t sum |s p + t - g| is convex (partial
    minimum of a jointly convex function), so a bracketed golden-section search over s converges to the
    optimum; the search starts from the median ratio as the reference scripts do.
    """
    def objective(s: float) -> float:
        residual = gt - s * pred
        return float(np.abs(residual - np.median(residual)).sum())

    if np.ptp(pred) == 0:  # constant prediction: any s works with the shift; keep s from the median ratio
        s = float(np.median(gt) / pred[0]) if pred[0] != 0 else 0.0
        return s, float(np.median(gt - s * pred))
    s0 = float(np.median(gt) / np.median(pred)) if np.median(pred) != 0 else 0.0
    step = max(abs(s0), float(np.ptp(gt) / np.ptp(pred)), 1e-12)
    lo, hi = _bracket(objective, s0, step)
    golden = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - golden * (hi - lo), lo + golden * (hi - lo)
    fa, fb = objective(a), objective(b)
    while hi - lo > rel_tol * max(abs(lo), abs(hi), 1e-300):
        if fa <= fb:
            hi, b, fb = b, a, fa
            a = hi - golden * (hi - lo)
            fa = objective(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + golden * (hi - lo)
            fb = objective(b)
        if b <= a:  # the interval is at float resolution
            break
    s = float(0.5 * (lo + hi))
    return s, float(np.median(gt - s * pred))


def _bracket(objective, start: float, step: float, max_doublings: int = 200) -> tuple[float, float]:
    """An interval [lo, hi] that contains a minimiser of the convex ``objective``, grown from ``start``."""
    f0 = objective(start)
    left, right = objective(start - step), objective(start + step)
    if left >= f0 and right >= f0:
        return start - step, start + step
    direction = 1.0 if right < f0 else -1.0
    previous, current, f_current = start, start + direction * step, min(left, right)
    for _ in range(max_doublings):
        step *= 2.0
        nxt = current + direction * step
        f_next = objective(nxt)
        if f_next >= f_current:
            return (previous, nxt) if direction > 0 else (nxt, previous)
        previous, current, f_current = current, nxt, f_next
    raise UserError("scale-and-shift depth alignment diverged (the L1 objective keeps decreasing)")


def aggregate_depth(results: list[DepthEvaluation]) -> dict[str, float]:
    """Benchmark-level AbsRel and delta<1.25: per-sequence values weighted by their valid-pixel counts."""
    if not results:
        raise UserError("no sequences to aggregate")
    weights = np.array([r.valid_pixels for r in results], dtype=np.float64)
    return {
        "abs_rel": float(np.average([r.abs_rel for r in results], weights=weights)),
        "delta_1_25": float(np.average([r.delta_1_25 for r in results], weights=weights)),
        "valid_pixels": int(weights.sum()),
    }
