"""Is one ``d4rt eval`` result better than another beyond what the choice of sequences explains? A paired bootstrap.

    python tools/compare_evals.py BASE.json NEW.json [--metric "abs_rel[scale&shift]"] [--method d4rt]
                                  [--samples 10000] [--unweighted]

Why (issue 14): synthetic-dynamic-v1's pooled depth AbsRel is decided by two or three outdoor clips (clip 2 alone
is about a fifth of it), so two models can differ by 0.01 for reasons that would not hold on other scenes. This
resamples the sequences with replacement, the same draw for both results (paired), re-aggregates the metric the way
``d4rt eval`` does (depth AbsRel and delta<1.25: pooled over valid pixels, each sequence weighted by its
``valid_pixels``; the other per-sequence metrics: the mean over sequences), and prints NEW - BASE, its 95%
interval over the draws, the share of draws in which NEW is better, and on how many sequences NEW is better. It
says how much the benchmark's own sequences could move a difference, not how the models would compare on other
scenes (that needs held-out clips). Pose AUC and the registered fraction pool frames, not sequences, and are refused.

It also reads ``tools/depth_probe.py`` JSON (held-out clips; ``--methods`` names a checkpoint of each) and
``tools/measure_focal.py`` JSON (one checkpoint's ``focal_error`` per synthetic clip, compared as a plain mean over
clips; ``--metric focal_error``). ``--margin M`` adds a non-inferiority verdict: NEW is not worse when the upper end
of the 95% interval of NEW - BASE is below M (for a lower-is-better metric; above -M for a higher-is-better one). JSON
written before ``valid_pixels`` was recorded per sequence (or per probe clip) has no depth weights:
``--unweighted`` then averages the sequences equally (said in the output), which is not the benchmark's pooling.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from d4rt.errors import UserError

# Metrics where a lower value is better; every other per-sequence metric is better higher.
LOWER_IS_BETTER = ("abs_rel", "focal_error", "ate", "rpe_trans", "rpe_rot", "pc_l1", "world_l1")
# Aggregates that are not a mean or a pixel-weighted mean of the per-sequence values.
NOT_PER_SEQUENCE = ("auc@", "registered")


def paired_bootstrap(base: np.ndarray, new: np.ndarray, weights: np.ndarray, samples: int = 10000,
                     seed: int = 0, lower_is_better: bool = True) -> dict:
    """Weighted-mean difference ``new - base`` over sequences and its bootstrap distribution.

    base, new, weights: ``(S,)`` per-sequence values of two results on the same sequences, and each sequence's
    weight in the aggregate (1 for a plain mean). Returns the difference, its 2.5% and 97.5% quantiles over
    ``samples`` paired resamplings of the sequences, the share of resamplings in which ``new`` is better, and
    the number of sequences on which it is better.
    """
    base, new, weights = (np.asarray(a, dtype=np.float64) for a in (base, new, weights))
    if not base.shape == new.shape == weights.shape or base.ndim != 1 or base.size == 0:
        raise UserError(f"need equal, non-empty (S,) arrays, got {base.shape}, {new.shape}, {weights.shape}")
    if samples < 1 or np.any(weights < 0) or weights.sum() <= 0:
        raise UserError("samples must be >= 1 and the weights non-negative with a positive sum")
    sign = 1.0 if lower_is_better else -1.0
    draws = np.random.default_rng(seed).integers(0, base.size, size=(samples, base.size))
    w = weights[draws]
    total = w.sum(axis=1)
    kept = total > 0  # a draw of only zero-weight sequences has no aggregate
    diffs = ((new[draws] - base[draws]) * w).sum(axis=1)[kept] / total[kept]
    low, high = np.quantile(diffs, [0.025, 0.975])
    return {
        "difference": float(np.average(new, weights=weights) - np.average(base, weights=weights)),
        "low": float(low),
        "high": float(high),
        "share_new_better": float(np.mean(sign * diffs < 0)),
        "new_better_on": int(np.sum(sign * (new - base) < 0)),
        "sequences": int(base.size),
    }


def not_worse(result: dict, margin: float, lower_is_better: bool = True) -> bool:
    """Non-inferiority: the 95% interval of NEW - BASE (from ``paired_bootstrap``) lies below ``margin`` (above
    ``-margin`` when higher is better), so NEW is at most ``margin`` worse with 97.5% confidence."""
    if margin < 0:
        raise UserError(f"the margin must be >= 0, got {margin}")
    return result["high"] < margin if lower_is_better else result["low"] > -margin


def method_rows(results: dict, method: str, path: str) -> dict[str, dict]:
    """Sequence name -> row (``metrics``, ``valid_pixels``) of one method of a ``d4rt eval`` JSON, of one
    checkpoint of a ``tools/depth_probe.py`` JSON (its ``models``, named by checkpoint path), or of the synthetic
    clip set of a ``tools/measure_focal.py`` JSON (one checkpoint; ``method`` is not used)."""
    clip_sets = [key for key, value in results.items() if isinstance(value, dict) and "clips" in value]
    if "checkpoint" in results and clip_sets:  # a focal measurement: one clip set per file
        if len(clip_sets) != 1:
            raise UserError(f"{path}: more than one clip set ({clip_sets}); compare one at a time")
        return {row["name"]: {"metrics": row} for row in results[clip_sets[0]]["clips"]}
    if "models" in results:  # a depth probe: one row per held-out clip, its metrics inline
        if method not in results["models"]:
            raise UserError(f"{path}: no checkpoint {method!r} (it has {list(results['models'])})")
        return {row["clip"]: {"metrics": row, **{k: row[k] for k in ("valid_pixels",) if k in row}}
                for row in results["models"][method]["clips"]}
    for entry in results.get("methods", []):
        if entry["name"] == method:
            return {row["name"]: row for row in entry["sequences"]}
    names = [entry["name"] for entry in results.get("methods", [])]
    raise UserError(f"{path}: no method {method!r} (it has {names})")


def compare(base: dict, new: dict, metric: str, method: str | tuple[str, str] = "d4rt", samples: int = 10000,
            unweighted: bool = False, names: tuple[str, str] = ("BASE", "NEW")) -> dict:
    """Paired bootstrap of ``metric`` between two results (see the module docstring); ``method`` names the
    method (or depth-probe checkpoint) of both, or a (base, new) pair."""
    if metric.startswith(NOT_PER_SEQUENCE):
        raise UserError(f"{metric} pools frames, not sequences: it cannot be resampled by sequence")
    methods = (method, method) if isinstance(method, str) else tuple(method)
    rows_a, rows_b = method_rows(base, methods[0], names[0]), method_rows(new, methods[1], names[1])
    if rows_a.keys() != rows_b.keys():
        raise UserError(f"{names[0]} and {names[1]} score different sequences: "
                        f"{sorted(rows_a.keys() ^ rows_b.keys())[:5]}")
    scored = [name for name in rows_a
              if rows_a[name]["metrics"].get(metric) is not None and rows_b[name]["metrics"].get(metric) is not None]
    if not scored:
        raise UserError(f"no sequence has {metric!r} in both results")
    pooled = metric.startswith(("abs_rel", "delta<")) and not unweighted
    if pooled:
        missing = [name for name in scored if "valid_pixels" not in rows_a[name] or "valid_pixels" not in rows_b[name]]
        if missing:
            raise UserError(f"{missing[0]} has no valid_pixels (JSON from an older d4rt eval): pass --unweighted")
        if any(rows_a[name]["valid_pixels"] != rows_b[name]["valid_pixels"] for name in scored):
            raise UserError("the two results count different valid pixels: they are not on the same ground truth")
    weights = [rows_a[name]["valid_pixels"] if pooled else 1.0 for name in scored]
    values = [[rows[name]["metrics"][metric] for name in scored] for rows in (rows_a, rows_b)]
    out = paired_bootstrap(*values, weights, samples, lower_is_better=metric.startswith(LOWER_IS_BETTER))
    out.update(metric=metric, method=" vs ".join(dict.fromkeys(methods)),
               weighting="valid pixels" if pooled else "equal", left_out=len(rows_a) - len(scored))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", type=Path, help="d4rt eval (or depth-probe) JSON of the reference")
    parser.add_argument("new", type=Path, help="d4rt eval (or depth-probe) JSON of the candidate")
    parser.add_argument("--metric", default="abs_rel[scale&shift]")
    parser.add_argument("--method", default="d4rt", help="method of both results (a checkpoint for a depth probe)")
    parser.add_argument("--methods", nargs=2, metavar=("BASE_METHOD", "NEW_METHOD"),
                        help="a method each, e.g. two checkpoints of one depth-probe JSON given twice")
    parser.add_argument("--samples", type=int, default=10000)
    parser.add_argument("--unweighted", action="store_true", help="average sequences equally (older JSON)")
    parser.add_argument("--margin", type=float, help="non-inferiority margin: exit 1 unless NEW is not worse by it")
    args = parser.parse_args()
    try:
        if args.margin is not None and args.margin < 0:
            raise UserError(f"--margin must be >= 0, got {args.margin}")
        loaded = []
        for path in (args.base, args.new):
            try:
                loaded.append(json.loads(path.read_text()))
            except (OSError, ValueError) as error:
                raise UserError(f"cannot read {path}: {error}") from None
        r = compare(*loaded, args.metric, tuple(args.methods or (args.method,) * 2), args.samples, args.unweighted,
                    (str(args.base), str(args.new)))
    except UserError as error:
        parser.error(str(error))
    print(f"{r['metric']} ({r['method']}, {r['sequences']} sequences, weighted by {r['weighting']}"
          + (f", {r['left_out']} without it left out" if r["left_out"] else "") + "): "
          f"NEW - BASE = {r['difference']:+.4f}, 95% interval [{r['low']:+.4f}, {r['high']:+.4f}]; "
          f"NEW better in {r['share_new_better']:.1%} of {args.samples:,} paired resamplings and on "
          f"{r['new_better_on']} of {r['sequences']} sequences")
    if args.margin is not None:
        ok = not_worse(r, args.margin, r["metric"].startswith(LOWER_IS_BETTER))
        print(f"non-inferiority at margin {args.margin:g}: {'PASS' if ok else 'FAIL'}")
        raise SystemExit(0 if ok else 1)


if __name__ == "__main__":
    main()
