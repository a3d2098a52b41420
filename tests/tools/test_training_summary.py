"""tools/training_summary.py: which machine a run is said to have trained on."""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path

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
