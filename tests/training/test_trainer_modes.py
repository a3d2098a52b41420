"""Trainer switches that the GPU configs use, exercised on CPU: activation checkpointing, bf16 autocast,
data-loader worker processes."""

from __future__ import annotations

import numpy as np
from safetensors.torch import load_file

from d4rt.training import TrainConfig, train
from training_helpers import fast_config


def run(tmp_path, name: str, clip_dir, **sections) -> tuple[dict, dict]:
    config = fast_config(clip_dir, **sections)
    result = train(TrainConfig.from_dict(config), tmp_path / name)
    return load_file(str(tmp_path / name / "model.safetensors")), result.metrics


def test_activation_checkpointing_and_loader_workers_do_not_change_the_result(tmp_path, clip_dir):
    steps = {"max_steps": 2, "checkpoint_every": 2}
    plain, _ = run(tmp_path, "plain", clip_dir, run=steps)
    recomputed, _ = run(tmp_path, "checkpointing", clip_dir, run=steps,
                        model={"preset": "tiny", "overrides": {"max_frames": 4, "gradient_checkpointing": True}})
    assert all(plain[k].equal(recomputed[k]) for k in plain)
    data = fast_config(clip_dir)["data"]
    workers, _ = run(tmp_path, "workers", clip_dir, run=steps, data={**data, "workers": 2})
    assert all(plain[k].equal(workers[k]) for k in plain)  # samples depend on (seed, epoch, index) only


def test_bf16_autocast_trains(tmp_path, clip_dir):
    weights, metrics = run(tmp_path, "bf16", clip_dir, run={"max_steps": 2, "checkpoint_every": 2,
                                                           "precision": "bf16"})
    assert all(np.isfinite(metrics[k]) for k in ("loss/total", "loss/3d", "grad_norm"))
    fp32, _ = run(tmp_path, "fp32", clip_dir, run={"max_steps": 2, "checkpoint_every": 2})
    assert all(w.dtype == fp32[k].dtype for k, w in weights.items())  # parameters stay float32
    assert any(not weights[k].equal(fp32[k]) for k in weights)  # the matmuls did run in bf16
