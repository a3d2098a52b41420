"""Overfitting one synthetic clip: the tiny preset must cut the 3D loss at least 10x within a CI budget,
and the validation metrics (through the reconstruction recipes) must see the difference."""

from __future__ import annotations

import time

import pytest
import torch

from d4rt.data import ClipQueryDataset
from d4rt.model import D4RT
from d4rt.synthetic import render_clip
from d4rt.training import TrainConfig, d4rt_loss, train
from d4rt.training.validation import Validator
from training_helpers import fast_config


def l3d(model: D4RT, batch: dict) -> float:
    with torch.no_grad():
        out = model.train(False)(batch["video"], batch["queries"], batch["aspect_ratio"])
    return d4rt_loss(out, batch)[1]["3d"].item()


@pytest.mark.slow(seconds=83)
def test_tiny_preset_overfits_one_clip(tmp_path):
    clip_dir = tmp_path / "clip"
    render_clip(7, 4, 32, 32, camera_motion="orbit", num_objects=2).save(clip_dir / "clip.npz")
    config = TrainConfig.from_dict(fast_config(
        clip_dir,
        model={"preset": "tiny", "overrides": {}},
        data={"batch_size": 1, "workers": 0,
              "dataset": {"source": "files", "directory": str(clip_dir), "frames": 4, "size": [32, 32],
                          "augment": {"enabled": False}, "sampler": {"num_queries": 256}}},
        optim={"lr": 1e-3, "warmup_steps": 10},
        run={"max_steps": 250, "log_every": 25, "checkpoint_every": 250},
        validation={"every": 250, "directory": str(clip_dir), "num_clips": 1, "frames": 4, "track_points": 32}))
    # Held-out queries of the same clip: an epoch the run never reaches draws other (u, v, t) triples.
    dataset = ClipQueryDataset(config.data.dataset)
    dataset.set_epoch(10_000)
    batch = {k: v[None] for k, v in dataset[0].items()}
    torch.manual_seed(config.run.seed)
    initial = D4RT(config.model.build())  # the trainer's initial weights (same seed)
    before = l3d(initial, batch)
    validator = Validator(config.validation, config.loss, config.data.dataset.sampler)
    validated_before = validator.run(initial, torch.autocast("cpu", enabled=False))

    start = time.perf_counter()
    result = train(config, tmp_path / "run")
    seconds = time.perf_counter() - start
    after = l3d(D4RT.from_pretrained(tmp_path / "run"), batch)
    assert after < before / 10, f"L3D {before:.4f} -> {after:.4f} in {seconds:.0f} s"

    # Validation on this clip (reconstructed by queries, scored by the evaluation harness) improves too.
    validated = result.metrics
    assert validated["val/loss/3d"] < validated_before["val/loss/3d"] / 5
    assert validated["val/abs_rel_scale_shift"] < validated_before["val/abs_rel_scale_shift"] / 2
    assert validated["val/rpe_rot"] < validated_before["val/rpe_rot"]
    assert validated["val/oa"] > validated_before["val/oa"]  # occlusion accuracy of the 3D tracks
