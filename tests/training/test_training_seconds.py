"""d4rt.training.logger.training_seconds: the training time is read from the logged throughput whatever the clips
per step (tools/training_summary.py and the equal-time benchmarks use it)."""

from __future__ import annotations

import json

import pytest

from d4rt.training.logger import read_metrics, training_seconds


@pytest.mark.parametrize("clips_per_step", [1, 4])
def test_training_seconds_counts_clips_not_steps(clips_per_step, tmp_path):
    # Two logged windows of 20 and 30 optimiser steps at 2 and 3 clips/s; validation records carry no throughput.
    records = [{"step": 20, "throughput/clips_per_s": 2.0}, {"step": 20, "val/loss/3d": 0.3},
               {"step": 50, "throughput/clips_per_s": 3.0}]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records) + "\n")
    assert read_metrics(tmp_path) == records  # blank lines skipped
    expected = (20 * clips_per_step / 2.0) + (30 * clips_per_step / 3.0)
    assert training_seconds(records, clips_per_step) == pytest.approx(expected)
