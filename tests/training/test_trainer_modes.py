"""Trainer switches that the GPU configs use, exercised on CPU: activation checkpointing, bf16 autocast,
data-loader worker processes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.training import TrainConfig, train
from d4rt.training.validation import Validator
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


def test_bf16_without_native_support_is_obeyed_and_said(tmp_path, clip_dir, monkeypatch, capsys):
    import d4rt.training.trainer as trainer

    monkeypatch.setattr(trainer, "native_bf16", lambda device: False)  # an AVX2-only CPU
    steps = {"max_steps": 1, "checkpoint_every": 1}
    run(tmp_path, "auto", clip_dir, run=steps)  # auto picks fp32 there: nothing to say
    assert "emulated" not in capsys.readouterr().out
    run(tmp_path, "bf16", clip_dir, run={**steps, "precision": "bf16"})
    said = [line for line in capsys.readouterr().out.splitlines() if "emulated" in line]
    assert len(said) == 1 and "run.precision bf16 on cpu" in said[0]


def test_keep_best_publishes_the_best_validated_checkpoint_and_survives_a_resume(tmp_path, clip_dir):
    validation = {"every": 1, "directory": str(clip_dir), "num_clips": 1, "frames": 4, "track_points": 16,
                  "num_queries": 64, "keep_best": "loss/total", "tasks": []}  # the loss terms alone: fast
    steps = {"max_steps": 4, "checkpoint_every": 4, "keep_checkpoints": 10}
    config = TrainConfig.from_dict(fast_config(clip_dir, run=steps, validation=validation))
    out = tmp_path / "run"
    train(config, out)
    logged = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    values = {row["step"]: row["val/loss/total"] for row in logged if "val/loss/total" in row}
    best_step = min(values, key=values.get)
    record = json.loads((out / "best" / "best.json").read_text())
    assert record == {"metric": "loss/total", "mode": "min", "step": best_step, "value": values[best_step]}
    # Its weights are that step's checkpoint (written because it was a new best, off the checkpoint schedule).
    best = load_file(str(out / "best" / "model.safetensors"))
    saved = load_file(str(out / "checkpoints" / f"step-{best_step:08d}" / "model.safetensors"))
    assert all(best[k].equal(saved[k]) for k in best)
    # A resumed, longer run compares against the record it left, not from scratch.
    longer = TrainConfig.from_dict(fast_config(clip_dir, run={**steps, "max_steps": 5}, validation=validation))
    train(longer, out, resume=True)
    again = json.loads((out / "best" / "best.json").read_text())
    assert again["value"] <= record["value"] and (again == record or again["step"] == 5)
    with pytest.raises(UserError, match="not a validation metric"):
        bad = {**validation, "keep_best": "nonsense"}
        train(TrainConfig.from_dict(fast_config(clip_dir, run=steps, validation=bad)), tmp_path / "bad")
    with pytest.raises(UserError, match="keep_best_mode"):
        TrainConfig.from_dict(fast_config(clip_dir, validation={**validation, "keep_best_mode": "up"})).validate()


def test_a_model_that_cannot_be_reconstructed_is_validated_and_the_run_goes_on(tmp_path, clip_dir):
    # A collapsed model: every point it answers lies on the plane 1 unit behind the camera, so no focal length
    # can be fitted (the failure a diverged run met at its last validation).
    validation = {"every": 1, "directory": str(clip_dir), "num_clips": 1, "frames": 4, "track_points": 16,
                  "num_queries": 64, "keep_best": "abs_rel_scale_shift"}
    still = {"optim": {"lr": 1e-12, "min_lr": 1e-12, "warmup_steps": 0}, "run": {"max_steps": 2, "checkpoint_every": 2},
             "validation": validation}  # a rate too small to move the weights
    config = TrainConfig.from_dict(fast_config(clip_dir, **still))
    collapsed = D4RT(config.model.build())
    points = collapsed.decoder.heads.heads["points"]
    with torch.no_grad():
        points.weight[2].zero_()
        points.bias[2] = -1.0
    validator = Validator(config.validation, config.loss, config.data.dataset.sampler)
    scalars = validator.run(collapsed, torch.autocast("cpu", enabled=False))
    assert scalars["val/reconstruction_failures"] == 1.0 and np.isfinite(scalars["val/loss/3d"])
    assert "val/abs_rel_scale_shift" not in scalars and "val/ate" not in scalars  # scored on no clip
    assert len(validator.failures) == 1 and validator.failures[0].startswith("clip_0: too few valid points")

    # Trained on from it without moving, the run validates every step, keeps no best (its metric was never
    # computed) and still writes its last checkpoint.
    collapsed.save_pretrained(tmp_path / "collapsed")
    model = {"preset": "tiny", "overrides": {"max_frames": 4}, "init_from": str(tmp_path / "collapsed")}
    config = TrainConfig.from_dict(fast_config(clip_dir, model=model, **still))
    result = train(config, tmp_path / "run")
    assert result.step == 2 and (tmp_path / "run" / "checkpoints" / "step-00000002").is_dir()
    logged = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [row["val/reconstruction_failures"] for row in logged if "val/loss/3d" in row] == [1.0, 1.0]
    assert not (tmp_path / "run" / "best").exists()


def test_a_frozen_encoder_keeps_the_weights_it_started_from_while_the_rest_trains(tmp_path, clip_dir):
    import torch

    from d4rt.config import D4RTConfig
    from d4rt.model import D4RT

    torch.manual_seed(3)
    D4RT(D4RTConfig.preset("tiny").replace(max_frames=4)).save_pretrained(tmp_path / "start")
    start = load_file(str(tmp_path / "start" / "model.safetensors"))
    model = {"preset": "tiny", "overrides": {"max_frames": 4}, "init_from": str(tmp_path / "start")}
    weights, metrics = run(tmp_path, "frozen", clip_dir, model=model, run={"max_steps": 2, "checkpoint_every": 2},
                           optim={"lr": 1e-3, "warmup_steps": 2, "freeze": ["encoder.*"]})
    assert np.isfinite(metrics["loss/total"])
    encoder = [k for k in start if k.startswith("encoder.")]
    assert encoder and all(weights[k].equal(start[k]) for k in encoder)
    assert all(not weights[k].equal(start[k]) for k in start if k.startswith("decoder.blocks.0."))
    # the optimiser holds state for the trained parameters alone
    state = load_file(str(tmp_path / "frozen" / "checkpoints" / "step-00000002" / "optimizer.safetensors"))
    trained = sum(p.numel() for n, p in D4RT.from_pretrained(tmp_path / "start").named_parameters()
                  if not n.startswith("encoder."))
    assert sum(v.numel() for k, v in state.items() if "exp_avg_sq" in k) == trained


def test_muon_steps_the_matched_matrices_and_a_resumed_run_is_bitwise_the_uninterrupted_one(tmp_path, clip_dir):
    optim = {**fast_config(clip_dir)["optim"], "decay_steps": 4, "muon": ["encoder.blocks.*", "decoder.blocks.*"]}
    steps = {"checkpoint_every": 1, "keep_checkpoints": 10}
    whole, metrics = run(tmp_path, "whole", clip_dir, optim=optim, run={**steps, "max_steps": 4})
    assert np.isfinite(metrics["loss/total"])
    # Muon keeps a momentum buffer for the block matrices, AdamW its moments for everything else.
    state = load_file(str(tmp_path / "whole" / "checkpoints" / "step-00000004" / "optimizer.safetensors"))
    momentum = {k.rsplit("/", 1)[0] for k in state if k.endswith("/momentum_buffer")}
    moments = {k.rsplit("/", 1)[0] for k in state if k.endswith("/exp_avg")}
    assert "encoder.blocks.0.attn.qkv.weight" in momentum and "decoder.blocks.3.mlp.fc2.weight" in momentum
    assert all(".blocks." in name and name.endswith(".weight") for name in momentum)
    assert not momentum & moments and "encoder.blocks.0.norm1.weight" in moments
    assert "encoder.patch_embed.proj.weight" in moments and "decoder.heads.heads.points.weight" in moments
    adamw, _ = run(tmp_path, "adamw", clip_dir, optim={**optim, "muon": []}, run={**steps, "max_steps": 4})
    assert any(not whole[k].equal(adamw[k]) for k in whole)
    # Stopped after 2 steps and resumed to 4: the same weights, bit for bit (both optimisers' state restored).
    run(tmp_path, "resumed", clip_dir, optim=optim, run={**steps, "max_steps": 2})
    config = TrainConfig.from_dict(fast_config(clip_dir, optim=optim, run={**steps, "max_steps": 4}))
    train(config, tmp_path / "resumed", resume=True)
    resumed = load_file(str(tmp_path / "resumed" / "model.safetensors"))
    assert all(whole[k].equal(resumed[k]) for k in whole)
