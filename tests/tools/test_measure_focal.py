"""tools/measure_focal.py: the held-out clips are new scenes of the benchmark's clip definitions, and the focal
recipe is exact on them when the oracle answers."""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from d4rt.evaluation.synthetic_benchmark import FRAMES, clip_specs
from d4rt.synthetic import render_clip

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "measure_focal.py"
spec = importlib.util.spec_from_file_location("measure_focal", SCRIPT)
measure_focal = importlib.util.module_from_spec(spec)
spec.loader.exec_module(measure_focal)


def test_held_out_focal_is_exact_on_the_oracle_and_drawn_from_unused_seeds():
    held_out = [replace(s, seed=measure_focal.HELD_OUT_SEED + s.index) for s in clip_specs()[:2]]
    clips = [render_clip(s.seed, FRAMES, s.height, s.width, **vars(s.options)) for s in held_out]
    # A stand-in model whose reconstruction of a held-out clip's frames is that clip's exact oracle.
    def reconstruct(rgb):
        return next(c for c in clips if np.array_equal(c.rgb, rgb)).reconstruction()

    oracle = SimpleNamespace(reconstruct=reconstruct)
    report = measure_focal.synthetic_focal_errors(oracle, limit=2, held_out=True)
    assert [c["name"] for c in report["clips"]] == [s.name for s in held_out]
    assert report["median_focal_error"] < 1e-5
    # The other recipes are exact too on clips that do not zoom (one camera, square pixels, as the engine's).
    assert not any(s.options.zoom for s in held_out)
    other = measure_focal.synthetic_focal_errors(oracle, limit=2, held_out=True,
                                                 recipe={"camera": "single", "square_pixels": True})
    assert other["median_focal_error"] < 1e-5
    # Rendered at about the training's pixel count: the same definition, its aspect ratio kept.
    small = measure_focal.at_pixels(held_out[1], 6400)
    assert abs(small.height * small.width - 6400) < small.height + small.width
    assert abs(small.width / small.height - held_out[1].width / held_out[1].height) < 0.03
    assert measure_focal.at_pixels(held_out[1], None) is held_out[1]
    benchmark_first = clip_specs()[0].render()
    assert not np.array_equal(benchmark_first.rgb, clips[0].rgb)  # another scene of the same definition
    assert report["clips"][0]["size"] == [held_out[0].height, held_out[0].width]


def test_a_gate_seed_measures_the_gate_set_and_refuses_a_second_clip_set(monkeypatch, capsys):
    gate = measure_focal.gate_specs(11_097_000)[:1]
    clip = render_clip(gate[0].seed, FRAMES, gate[0].height, gate[0].width, **vars(gate[0].options))
    oracle = SimpleNamespace(reconstruct=lambda rgb: clip.reconstruction())
    report = measure_focal.synthetic_focal_errors(oracle, limit=1, seed_base=11_097_000)
    assert report["clips"][0]["name"] == gate[0].name and report["median_focal_error"] < 1e-5
    assert measure_focal.gate_key(11_097_000) == "synthetic-gate-11097000"
    for argv, message in ((["--held-out", "--gate-seed", "11097000"], "two different clip sets"),
                          (["--gate-seed", "9000000"], "--gate-seed must lie in 11,000,000-11,999,952")):
        monkeypatch.setattr("sys.argv", ["measure_focal.py", "--out", "unused.json", *argv])
        with pytest.raises(SystemExit):
            measure_focal.main()
        assert message in capsys.readouterr().err
