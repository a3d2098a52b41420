"""tools/compare_evals.py: the paired bootstrap re-pools as d4rt eval does and says what it cannot compare."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from d4rt.errors import UserError

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "compare_evals.py"
spec = importlib.util.spec_from_file_location("compare_evals", SCRIPT)
compare_evals = importlib.util.module_from_spec(spec)
spec.loader.exec_module(compare_evals)


def results(values: dict[str, float], pixels: dict[str, int] | None = None, metric: str = "abs_rel[scale&shift]"):
    rows = []
    for name, value in values.items():
        row = {"name": name, "metrics": {metric: value, "ate": value}, "notes": []}
        if pixels is not None:
            row["valid_pixels"] = pixels[name]
        rows.append(row)
    return {"methods": [{"name": "d4rt", "aggregate": {}, "sequences": rows}]}


def test_identical_results_differ_by_nothing_and_a_uniform_gain_is_certain():
    base = np.array([0.2, 0.5, 3.0, 0.3])
    same = compare_evals.paired_bootstrap(base, base, np.ones(4), samples=500)
    assert same["difference"] == same["low"] == same["high"] == 0.0 and same["share_new_better"] == 0.0
    better = compare_evals.paired_bootstrap(base, base - 0.1, np.ones(4), samples=500)
    assert better["difference"] == pytest.approx(-0.1)
    assert better["low"] == pytest.approx(-0.1) and better["high"] == pytest.approx(-0.1)
    assert better["share_new_better"] == 1.0 and better["new_better_on"] == 4
    # For a metric that is better higher, the same change is a loss.
    worse = compare_evals.paired_bootstrap(base, base - 0.1, np.ones(4), samples=500, lower_is_better=False)
    assert worse["share_new_better"] == 0.0 and worse["new_better_on"] == 0


def test_one_outlier_sequence_leaves_the_interval_wide():
    """A gain carried by one of many sequences is not certain: resamplings without it show none."""
    base = np.full(20, 0.3)
    base[0] = 3.0
    new = base.copy()
    new[0] = 2.0
    r = compare_evals.paired_bootstrap(base, new, np.ones(20), samples=2000)
    assert r["difference"] == pytest.approx(-0.05)
    assert r["high"] == 0.0 and r["low"] < -0.05 and 0.5 < r["share_new_better"] < 0.8


def test_depth_is_pooled_over_valid_pixels_like_d4rt_eval():
    names = ["a", "b"]
    pixels = {"a": 3000, "b": 1000}
    r = compare_evals.compare(results(dict(zip(names, [0.4, 1.0])), pixels),
                              results(dict(zip(names, [0.2, 1.0])), pixels), "abs_rel[scale&shift]", samples=200)
    assert r["weighting"] == "valid pixels" and r["difference"] == pytest.approx(-0.2 * 3000 / 4000)
    # Per-sequence means (ATE) weigh every sequence alike.
    r = compare_evals.compare(results(dict(zip(names, [0.4, 1.0])), pixels),
                              results(dict(zip(names, [0.2, 1.0])), pixels), "ate", samples=200)
    assert r["weighting"] == "equal" and r["difference"] == pytest.approx(-0.1)


def test_what_cannot_be_compared_is_refused_in_one_line():
    base, pixels = {"a": 0.4, "b": 1.0}, {"a": 10, "b": 10}
    with pytest.raises(UserError, match="different sequences"):
        compare_evals.compare(results(base, pixels), results({"a": 0.4, "c": 1.0}, {"a": 10, "c": 10}),
                              "abs_rel[scale&shift]")
    with pytest.raises(UserError, match="--unweighted"):
        compare_evals.compare(results(base), results(base), "abs_rel[scale&shift]")
    assert compare_evals.compare(results(base), results(base), "abs_rel[scale&shift]", samples=10,
                                 unweighted=True)["weighting"] == "equal"
    with pytest.raises(UserError, match="pools frames"):
        compare_evals.compare(results(base, pixels), results(base, pixels), "auc@30")
    with pytest.raises(UserError, match="no method 'pycolmap'"):
        compare_evals.compare(results(base, pixels), results(base, pixels), "ate", method="pycolmap")
    with pytest.raises(UserError, match="different valid pixels"):
        compare_evals.compare(results(base, pixels), results(base, {"a": 10, "b": 11}), "abs_rel[scale&shift]")


def test_two_checkpoints_of_one_depth_probe_compare_clip_by_clip():
    clips = [{"clip": "clip_00", "abs_rel[scale&shift]": 0.5, "valid_pixels": 300},
             {"clip": "clip_08", "abs_rel[scale&shift]": 1.5, "valid_pixels": 100}]
    better = [dict(row, **{"abs_rel[scale&shift]": row["abs_rel[scale&shift]"] - 0.1}) for row in clips]
    probe = {"held_out_seed": 9_000_000, "models": {"old": {"clips": clips}, "new": {"clips": better}}}
    r = compare_evals.compare(probe, probe, "abs_rel[scale&shift]", ("old", "new"), samples=200)
    assert r["difference"] == pytest.approx(-0.1) and r["new_better_on"] == 2 and r["method"] == "old vs new"
    with pytest.raises(UserError, match="no checkpoint 'other'"):
        compare_evals.compare(probe, probe, "abs_rel[scale&shift]", ("old", "other"))


def focal(errors: dict[str, float], clip_set: str = "synthetic-dynamic-v1") -> dict:
    """A ``tools/measure_focal.py`` JSON of one checkpoint."""
    clips = [{"name": name, "size": [64, 64], "focal_error": e} for name, e in errors.items()]
    return {"checkpoint": "ck", clip_set: {"clips": clips, "median_focal_error": float(np.median(list(errors.values())))},
            "tum-fr3-long-office-household": {"relative_error": 0.1}}


def test_focal_errors_compare_clip_by_clip_with_a_non_inferiority_margin():
    rng = np.random.default_rng(0)
    names = [f"clip_{i:02d}" for i in range(48)]
    base = dict(zip(names, rng.uniform(0.0, 0.5, 48)))
    slightly_worse = {name: e + 0.01 for name, e in base.items()}
    r = compare_evals.compare(focal(base), focal(slightly_worse), "focal_error", samples=500)
    assert r["weighting"] == "equal" and r["difference"] == pytest.approx(0.01) and r["new_better_on"] == 0
    # 1 point worse on every clip: inside a 5-point margin, outside a half-point one.
    assert compare_evals.not_worse(r, 0.05) and not compare_evals.not_worse(r, 0.005)
    # Noise of +-0.3 on a few clips widens the interval past the margin.
    noisy = {name: e + (0.3 if i % 4 == 0 else 0.0) for i, (name, e) in enumerate(base.items())}
    assert not compare_evals.not_worse(compare_evals.compare(focal(base), focal(noisy), "focal_error",
                                                             samples=500), 0.05)
    with pytest.raises(UserError, match="more than one clip set"):
        compare_evals.compare(dict(focal(base), **{"synthetic-held-out": {"clips": []}}), focal(base), "focal_error")
    with pytest.raises(UserError, match="different sequences"):
        compare_evals.compare(focal(base), focal(dict(list(base.items())[:47])), "focal_error")
