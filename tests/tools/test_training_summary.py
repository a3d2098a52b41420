"""tools/training_summary.py: which machine a run is said to have trained on, and a run without checkpoints."""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path

import pytest
import yaml

from d4rt.config import D4RTConfig
from d4rt.model import D4RT

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "training_summary.py"
spec = importlib.util.spec_from_file_location("training_summary", SCRIPT)
training_summary = importlib.util.module_from_spec(spec)
spec.loader.exec_module(training_summary)

CONFIG = {"run": {"device": "auto"}}


def test_a_run_brought_back_from_a_gpu_lease_keeps_the_gpu_machine(tmp_path):
    written = {"gpu": "NVIDIA H200", "logical_cpus": 16, "torch": "2.9.0", "cuda": "12.8"}
    (tmp_path / "hardware.json").write_text(json.dumps(written))
    assert training_summary.hardware(tmp_path, CONFIG) == {**written, "device": "auto"}


def test_a_run_without_hardware_json_is_described_by_this_machine(tmp_path):
    described = training_summary.hardware(tmp_path, CONFIG)
    assert described["logical_cpus"] == os.cpu_count() and "gpu" not in described and described["cpu"]


def test_a_run_without_checkpoints_is_summarised_from_its_weights_config_and_log(tmp_path):
    """The sixth lease brought back final weights, train_config.yaml and metrics.jsonl but no checkpoint: the
    samples follow from the last logged step and the batch, and a log that counts skipped steps is refused."""
    D4RT(D4RTConfig(name="tiny")).save_pretrained(tmp_path)
    config = {"model": {"preset": "tiny"}, "run": {"device": "auto", "grad_accum": 1},
              "data": {"batch_size": 16, "dataset": {"frames": 24, "size": [64, 64], "sampler": {"num_queries": 1024}}}}
    (tmp_path / "train_config.yaml").write_text(yaml.safe_dump(config))
    rows = [{"step": s, "loss/3d": 0.4, "throughput/clips_per_s": 40.0, "skipped_steps": 0.0} for s in (20, 40)]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    summary = training_summary.summarise(tmp_path)
    assert (summary["steps"], summary["clips_seen"], summary["clips_per_step"]) == (40, 640, 16)
    rows[-1]["skipped_steps"] = 1.0
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(SystemExit, match="skipped steps"):
        training_summary.summarise(tmp_path)
