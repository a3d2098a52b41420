"""tools/model_card.py: how the shipped weights' recipe is written out."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "model_card.py"
spec = importlib.util.spec_from_file_location("model_card", SCRIPT)
model_card = importlib.util.module_from_spec(spec)
spec.loader.exec_module(model_card)


def test_an_average_of_averages_is_written_with_brackets_and_kept_steps():
    assert model_card.average_text({"stages": [2, 4], "weights": [0.5, 0.5]}) == "0.5 x stage 2 + 0.5 x stage 4"
    inner = {"stages": [{"stages": [2, 4], "weights": [0.5, 0.5]}, 21], "weights": [0.5, 0.5], "steps": {"21": 4000}}
    nested = {"stages": [inner, 25], "weights": [0.5, 0.5], "steps": {"25": 3500}}
    assert model_card.average_text(nested) == ("0.5 x (0.5 x (0.5 x stage 2 + 0.5 x stage 4) + 0.5 x stage 21 "
                                               "(its step 4,000)) + 0.5 x stage 25 (its step 3,500)")


def test_a_stage_trained_on_a_lent_gpu_names_the_gpu_and_the_echoed_clips():
    """A GPU lease's run (benchmarks/gpu_session.sh brings its hardware.json back) is described by its GPU, and
    data echoing by the clips rendered as well as the samples drawn from them."""
    config = {"data": {"dataset": {"source": "render", "frames": 24, "echo": 2, "augment": {"crop_policy": "none"}}},
              "optim": {"lr": 5e-5}, "run": {"precision": "auto"}}
    training = {"hardware": {"gpu": "NVIDIA H200", "logical_cpus": 16, "torch": "2.9.0", "device": "auto"},
                "config": config, "frames_per_clip": 24, "resumed": True, "clips_seen": 21952, "input_size": [64, 64],
                "queries_per_clip": 1024, "steps": 1372, "clips_per_step": 16, "training_seconds": 460.0,
                "starts_from": "the weights shipped before it"}
    row = model_card.stage_summary(training, previous=118)
    assert row.startswith("from the weights shipped before it; 21,952 samples of 10,976 synthetic clips rendered on "
                          "the fly (each sampled 2 times), 24 frames at 64x64, whole frames (no crop)")
    assert row.endswith("one NVIDIA H200 with 16 CPU cores rendering clips, torch 2.9.0, bf16")
    cpu = {**training, "hardware": {"cpu": "AMD EPYC", "logical_cpus": 2, "torch": "2.13.0+cpu", "torch_threads": 1},
           "config": {**config, "run": {"precision": "fp32"}}}
    assert model_card.stage_summary(cpu, previous=118).endswith(
        "CPU only: AMD EPYC, 2 logical cores (shared), 1 torch thread(s), torch 2.13.0+cpu, fp32")


def test_sibling_legs_of_a_stage_are_read_in_training_order(tmp_path):
    """Two legs trained side by side by one config (training-stage141a.json, -141b.json) sort after the stages
    before them and by their letter; a file name that is neither a number nor a number and a letter is named."""
    for stem in ("135", "141b", "141a", "9"):
        (tmp_path / f"training-stage{stem}.json").write_text(f'{{"stage": "{stem}"}}')
    summaries = model_card.training_summaries(tmp_path)
    assert list(summaries) == [9, 135, "141a", "141b"] and summaries["141a"] == {"stage": "141a"}
    soup = {"stages": [{"stages": [118, 135], "weights": [0.75, 0.25]}, "141a", "141b"], "weights": [0.5, 0.25, 0.25]}
    assert model_card.average_text(soup) == ("0.5 x (0.75 x stage 118 + 0.25 x stage 135) + 0.25 x stage 141a + "
                                             "0.25 x stage 141b")
    with pytest.raises(ValueError, match="training-stage141-b.json"):
        model_card.stage_order("141-b")
