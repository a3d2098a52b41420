"""tools/training_summary.py: the training time is read from the logged throughput whatever the clips per step."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "training_summary.py"
spec = importlib.util.spec_from_file_location("training_summary", SCRIPT)
training_summary = importlib.util.module_from_spec(spec)
spec.loader.exec_module(training_summary)


@pytest.mark.parametrize("clips_per_step", [1, 4])
def test_training_seconds_counts_clips_not_steps(clips_per_step):
    # Two logged windows of 20 and 30 optimiser steps at 2 and 3 clips/s; validation records carry no throughput.
    records = [{"step": 20, "throughput/clips_per_s": 2.0}, {"step": 20, "val/loss/3d": 0.3},
               {"step": 50, "throughput/clips_per_s": 3.0}]
    expected = (20 * clips_per_step / 2.0) + (30 * clips_per_step / 3.0)
    assert training_summary.training_seconds(records, clips_per_step) == pytest.approx(expected)
