"""Overfitting one synthetic clip: the tiny preset must cut the 3D loss at least 10x within a CI budget."""

from __future__ import annotations

import time

import torch

from d4rt.data import ClipQueryDataset
from d4rt.model import D4RT
from d4rt.synthetic import render_clip
from d4rt.training import TrainConfig, d4rt_loss, train
from training_helpers import fast_config


def l3d(model: D4RT, batch: dict) -> float:
    with torch.no_grad():
        out = model.train(False)(batch["video"], batch["queries"], batch["aspect_ratio"])
    return d4rt_loss(out, batch)[1]["3d"].item()


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
        run={"max_steps": 250, "log_every": 25, "checkpoint_every": 250}))
    # Held-out queries of the same clip: an epoch the run never reaches draws other (u, v, t) triples.
    dataset = ClipQueryDataset(config.data.dataset)
    dataset.set_epoch(10_000)
    batch = {k: v[None] for k, v in dataset[0].items()}
    torch.manual_seed(config.run.seed)
    before = l3d(D4RT(config.model.build()), batch)  # the trainer's initial weights (same seed)

    start = time.perf_counter()
    train(config, tmp_path / "run")
    seconds = time.perf_counter() - start
    after = l3d(D4RT.from_pretrained(tmp_path / "run"), batch)
    assert after < before / 10, f"L3D {before:.4f} -> {after:.4f} in {seconds:.0f} s"
