"""tools/focal_by_fov.py: clips fall into the band of their true horizontal FOV, and each band's figures are the
medians of its own clips."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "focal_by_fov.py"
spec = importlib.util.spec_from_file_location("focal_by_fov", SCRIPT)
focal_by_fov = importlib.util.module_from_spec(spec)
spec.loader.exec_module(focal_by_fov)


def clip(fov_degrees: float, ratio: float, width: int = 128, height: int = 96) -> dict:
    true_fx = width / (2 * math.tan(math.radians(fov_degrees / 2)))
    return {"size": [height, width], "true_fx_median": true_fx, "estimated_fx_median": ratio * true_fx}


def test_bands_by_true_fov_and_their_medians():
    clips = [clip(35, 0.5), clip(45, 0.7), clip(40, 0.6), clip(60, 1.0), clip(100, 1.25, width=64)]
    rows = focal_by_fov.focal_by_fov(clips)
    assert [r["band"] for r in rows] == ["< 50", "50-70", "70-90", ">= 90"]
    assert [r["clips"] for r in rows] == [3, 1, 0, 1]
    assert rows[0]["median_log_ratio"] == pytest.approx(math.log(0.6))
    assert rows[0]["median_focal_error"] == pytest.approx(0.4)
    assert rows[1]["median_focal_error"] == pytest.approx(0.0, abs=1e-12)
    assert rows[2]["median_log_ratio"] is None
    assert rows[3]["median_log_ratio"] == pytest.approx(math.log(1.25))
    assert focal_by_fov.horizontal_fov_degrees(128, 64) == pytest.approx(90.0)


def test_sizes_ordered_portrait_to_landscape_with_their_own_medians():
    clips = [clip(60, 0.5, 192, 96), clip(60, 0.8, 192, 96), clip(60, 1.1, 128, 128), clip(60, 1.5, 120, 160),
             clip(40, 2.0, 192, 96)]
    rows = focal_by_fov.focal_by_size(clips)
    assert [(r["size"], r["clips"]) for r in rows] == [("160x120", 1), ("128x128", 1), ("96x192", 3)]
    assert rows[0]["median_log_ratio"] == pytest.approx(math.log(1.5))
    assert rows[2]["median_log_ratio"] == pytest.approx(math.log(0.8))
    assert rows[2]["median_focal_error"] == pytest.approx(0.5)  # |0.5 - 1|, |0.8 - 1|, |2.0 - 1| -> 0.5


def test_regression_reads_the_share_of_the_focal_signal():
    fovs = [30, 45, 60, 80, 100]
    half = [clip(f, 1.0) for f in fovs]
    for c in half:  # an estimate that keeps half of the log focal, around fx / W = 1
        c["estimated_fx_median"] = c["size"][1] * (c["true_fx_median"] / c["size"][1]) ** 0.5
    fit = focal_by_fov.focal_regression(half)
    assert fit["slope"] == pytest.approx(0.5) and fit["intercept"] == pytest.approx(0.0, abs=1e-9)
    assert fit["correlation"] == pytest.approx(1.0) and fit["residual_sd"] == pytest.approx(0.0, abs=1e-9)
    assert fit["aspect_coefficient"] == pytest.approx(0.0, abs=1e-9)  # every clip 96x128: no elongation to fit
    # A model that reads the view from the shorter side (half its log focal, as above) whatever the aspect: one
    # law against S, while against the width the elongated frames seem to need an aspect term.
    shorter = []
    for height, width in ((128, 128), (96, 192), (120, 160), (192, 108), (108, 192)):
        for f in fovs:
            c = clip(f, 1.0, width, height)
            s = min(height, width)
            c["estimated_fx_median"] = s * (c["true_fx_median"] / s) ** 0.5
            shorter.append(c)
    on_s = focal_by_fov.focal_regression(shorter, "shorter")
    assert on_s["slope"] == pytest.approx(0.5) and on_s["residual_sd"] == pytest.approx(0.0, abs=1e-9)
    assert on_s["aspect_coefficient"] == pytest.approx(0.0, abs=1e-9)
    assert abs(focal_by_fov.focal_regression(shorter, "width")["aspect_coefficient"]) > 0.1
    with pytest.raises(focal_by_fov.UserError, match="side must be one of"):
        focal_by_fov.focal_regression(shorter, "diagonal")
    with pytest.raises(focal_by_fov.UserError, match="at least two clips"):
        focal_by_fov.focal_regression([clip(30, 1.0), clip(30, 2.0)])


def test_command_reads_every_synthetic_set_and_refuses_other_json(tmp_path, capsys):
    report = {"checkpoint": "ck", "synthetic-held-out": {"clips": [clip(35, 0.5)]},
              "tum-fr3-long-office-household": {"frames": 17, "estimated_fx": 500.0}}
    good = tmp_path / "focal.json"
    good.write_text(json.dumps(report))
    focal_by_fov.main([str(good)])
    out = capsys.readouterr().out
    assert "[synthetic-held-out]" in out and "1 clips" in out and "-0.69" in out and "tum" not in out
    assert "size  96x128:  1 clips, median log(est/true fx) -0.69" in out
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"rows": []}))
    with pytest.raises(SystemExit, match="has no synthetic clips"):
        focal_by_fov.main([str(other)])
    with pytest.raises(SystemExit, match="bands must be ascending"):
        focal_by_fov.main([str(good), "--bands", "70", "50"])
