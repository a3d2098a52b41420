"""Where a model's focal error lies by field of view and by frame size, from ``tools/measure_focal.py`` JSON.

    python tools/focal_by_fov.py FOCAL.json [FOCAL.json ...] [--bands 50 70 90]

Per clip, the true horizontal field of view is ``2 atan(W / (2 fx_true))`` (W the clip's width in pixels, fx the
median true focal over its frames); clips are grouped into bands by it, and each band reports its clip count, the
median of ``log(fx_estimated / fx_true)`` (below 0: focal too short, the view read too wide) and the median relative
focal error. Why (stage 50, docs/training.md): a median over 48 clips hides that every field of view is pulled
toward about 60 degrees; this shows which band decides the median. It also fits, over all clips of a set,
``log(fx_est / W) = a + b log(fx_true / W)``: the slope b is the share of the true log-focal signal the model reads (1:
every field of view told apart; 0: one focal for all), and the residual spread is the error left at slope 1; the
same fit against the frame's shorter side S, each with the coefficient that ``|log(W / H)|`` takes when it joins
(over 16 draws of 48 clips the shipped weights read -0.05 +- 0.19 against W, +0.29 +- 0.20 against S: the view is
read across the width, and one draw's term is mostly its spread). Then the same two medians per frame size (H x W,
portrait to landscape): whether non-square frames are read as wider or narrower than square ones (measured
2026-12-05, docs/training.md "Focal error by frame size"). Every
synthetic set in each file is reported (``synthetic-dynamic-v1``, ``synthetic-held-out``); the real TUM frames are
one camera and are left out.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from d4rt.errors import UserError

DEFAULT_BANDS = (50.0, 70.0, 90.0)
SIDES = ("width", "shorter", "longer")


def horizontal_fov_degrees(width: float, fx: float) -> float:
    """Horizontal field of view in degrees of a pinhole camera ``width`` pixels wide with focal ``fx`` pixels."""
    return math.degrees(2.0 * math.atan(width / (2.0 * fx)))


def focal_by_fov(clips: list[dict], bands: tuple[float, ...] = DEFAULT_BANDS) -> list[dict]:
    """Clips of one measure_focal set grouped by true horizontal FOV.

    clips: each with ``size`` [H, W], ``true_fx_median`` and ``estimated_fx_median`` (pixels); bands: ascending
    FOV edges in degrees. Returns one dict per band (len(bands) + 1, empty ones included): ``band`` (its label),
    ``clips`` (count), ``median_log_ratio`` and ``median_focal_error`` (None when empty).
    """
    edges = [-math.inf, *bands, math.inf]
    if any(high <= low for low, high in zip(edges[:-1], edges[1:])):
        raise UserError(f"FOV bands must be ascending, got {list(bands)}")
    rows = []
    for low, high in zip(edges[:-1], edges[1:]):
        picked = [c for c in clips if low <= horizontal_fov_degrees(c["size"][1], c["true_fx_median"]) < high]
        ratios = np.log([c["estimated_fx_median"] / c["true_fx_median"] for c in picked])
        label = f"< {high:g}" if low == -math.inf else f">= {low:g}" if high == math.inf else f"{low:g}-{high:g}"
        rows.append({
            "band": label, "clips": len(picked),
            "median_log_ratio": float(np.median(ratios)) if picked else None,
            "median_focal_error": float(np.median(np.abs(np.exp(ratios) - 1))) if picked else None,
        })
    return rows


def focal_by_size(clips: list[dict]) -> list[dict]:
    """Clips of one measure_focal set grouped by frame size, ordered by aspect ratio W / H (portrait first).

    Returns one dict per size present: ``size`` ("HxW"), ``clips`` (count), ``median_log_ratio`` and
    ``median_focal_error`` (as :func:`focal_by_fov`'s).
    """
    sizes = sorted({tuple(c["size"]) for c in clips}, key=lambda hw: (hw[1] / hw[0], hw[0]))
    rows = []
    for height, width in sizes:
        ratios = np.log([c["estimated_fx_median"] / c["true_fx_median"] for c in clips
                         if tuple(c["size"]) == (height, width)])
        rows.append({"size": f"{height}x{width}", "clips": len(ratios), "median_log_ratio": float(np.median(ratios)),
                     "median_focal_error": float(np.median(np.abs(np.exp(ratios) - 1)))})
    return rows


def focal_regression(clips: list[dict], side: str = "width") -> dict:
    """Least-squares fit of ``log(fx_est / S)`` on ``log(fx_true / S)`` over ``clips`` (at least two, with two
    different true focals), S the frame's ``side`` in pixels ("width", "shorter" or "longer"): ``slope``,
    ``intercept``, ``correlation`` and ``residual_sd`` (of the fit, in log units), and ``aspect_coefficient``: the
    coefficient of ``|log(W / H)|`` when it joins the fit (0: the frame's elongation adds nothing to the law)."""
    if side not in SIDES:
        raise UserError(f"side must be one of {', '.join(SIDES)}, got {side!r}")
    height = np.array([c["size"][0] for c in clips], dtype=float)
    width = np.array([c["size"][1] for c in clips], dtype=float)
    s = {"width": width, "shorter": np.minimum(height, width), "longer": np.maximum(height, width)}[side]
    true = np.log(np.array([c["true_fx_median"] for c in clips]) / s)
    estimated = np.log(np.array([c["estimated_fx_median"] for c in clips]) / s)
    if len(clips) < 2 or np.ptp(true) == 0:
        raise UserError("a focal regression needs at least two clips with different true focal lengths")
    slope, intercept = np.polyfit(true, estimated, 1)
    residual = estimated - (intercept + slope * true)
    design = np.stack([np.ones_like(true), true, np.abs(np.log(width / height))], 1)
    with_aspect = np.linalg.lstsq(design, estimated, rcond=None)[0] if np.ptp(design[:, 2]) > 0 else [0, 0, 0.0]
    return {"slope": float(slope), "intercept": float(intercept),
            "correlation": float(np.corrcoef(true, estimated)[0, 1]), "residual_sd": float(residual.std()),
            "aspect_coefficient": float(with_aspect[2])}


def synthetic_sets(report: dict) -> dict[str, list[dict]]:
    """The per-clip lists of every synthetic set in one measure_focal JSON, by set name."""
    return {name: value["clips"] for name, value in report.items() if isinstance(value, dict) and "clips" in value}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("reports", nargs="+", type=Path, help="tools/measure_focal.py JSON files")
    parser.add_argument("--bands", nargs="+", type=float, default=list(DEFAULT_BANDS),
                        help="ascending FOV edges in degrees (default: 50 70 90)")
    args = parser.parse_args(argv)
    for path in args.reports:
        try:
            report = json.loads(path.read_text())
        except (OSError, ValueError) as error:
            raise SystemExit(f"error: cannot read focal JSON {path}: {error}") from None
        sets = synthetic_sets(report)
        if not sets:
            raise SystemExit(f"error: {path} has no synthetic clips (is it tools/measure_focal.py output?)")
        for name, clips in sets.items():
            try:
                rows = focal_by_fov(clips, tuple(args.bands))
            except UserError as error:
                raise SystemExit(f"error: {error}") from None
            print(f"{path} [{name}] {report.get('checkpoint', '')}")
            for row in rows:
                if row["clips"]:
                    print(f"  FOV {row['band']:>7} deg: {row['clips']:2d} clips, median log(est/true fx) "
                          f"{row['median_log_ratio']:+.2f}, median focal error {100 * row['median_focal_error']:.1f}%")
                else:
                    print(f"  FOV {row['band']:>7} deg:  0 clips")
            if len(clips) >= 2:
                for side, s in (("width", "W"), ("shorter", "S")):
                    fit = focal_regression(clips, side)
                    print(f"  log(est fx / {s}) = {fit['intercept']:+.2f} + {fit['slope']:.2f} log(true fx / {s}): "
                          f"correlation {fit['correlation']:.2f}, residual sd {fit['residual_sd']:.2f}; with "
                          f"|log(W / H)| {fit['aspect_coefficient']:+.2f}" + (" (S: the shorter side)" if s == "S" else ""))
            for row in focal_by_size(clips):
                print(f"  size {row['size']:>7}: {row['clips']:2d} clips, median log(est/true fx) "
                      f"{row['median_log_ratio']:+.2f}, median focal error {100 * row['median_focal_error']:.1f}%")


if __name__ == "__main__":
    main()
