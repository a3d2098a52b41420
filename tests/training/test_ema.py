"""The exponential moving average of the weights (optim.ema_decay): its update rule, its place in checkpoints,
validation and best/, and an exact resume."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file
from torch import nn

from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.training import TrainConfig, train
from d4rt.training.ema import WeightAverage
from training_helpers import fast_config


def test_the_average_follows_its_formula_and_swapping_restores_the_weights_exactly():
    layer = nn.Linear(3, 2)
    frozen = nn.Parameter(torch.ones(2), requires_grad=False)
    layer.register_parameter("frozen", frozen)
    start = layer.weight.detach().clone()
    average = WeightAverage(layer, decay=0.7)
    expected = start.clone()
    for n in range(30):
        with torch.no_grad():
            layer.weight.add_(torch.randn_like(layer.weight))
        d = min(0.7, (1 + n) / (10 + n))  # warm-up first, 0.7 from n = 20
        expected = d * expected + (1 - d) * layer.weight.detach()
        average.update()
    assert average.updates == 30 and average.current_decay() == 0.7
    own = layer.weight.detach().clone()
    with average.swapped_in():
        torch.testing.assert_close(layer.weight.detach(), expected, rtol=1e-6, atol=1e-6)
    assert layer.weight.detach().equal(own)  # bitwise its own values again
    with pytest.raises(ValueError, match="decay"):
        WeightAverage(layer, decay=1.0)


def run_config(clip_dir, steps: int, **sections) -> TrainConfig:
    optim = {**fast_config(clip_dir)["optim"], "ema_decay": 0.8, "decay_steps": 6}
    run = {"max_steps": steps, "checkpoint_every": 1, "keep_checkpoints": 10}
    return TrainConfig.from_dict(fast_config(clip_dir, optim=optim, run=run, **sections))


def test_checkpoints_hold_the_average_of_every_step_and_a_resume_is_bitwise_exact(tmp_path, clip_dir):
    config = run_config(clip_dir, 6)
    out = tmp_path / "run"
    train(config, out)
    # The average recomputed from the initial weights (seeded) and every step's checkpointed weights.
    torch.manual_seed(config.run.seed)
    initial = D4RT(config.validate()).state_dict()
    names = [n for n, p in D4RT(config.validate()).named_parameters() if p.requires_grad]
    expected = {n: initial[n].clone() for n in names}
    for step in range(1, 7):
        weights = load_file(str(out / f"checkpoints/step-{step:08d}/model.safetensors"))
        d = min(0.8, step / (9 + step))
        for n in names:
            expected[n].lerp_(weights[n], 1 - d)
    saved = D4RT.from_pretrained(out / "checkpoints/step-00000006/ema")  # a model directory, loaded strictly
    state = saved.state_dict()
    assert all(state[n].equal(expected[n]) for n in names)
    published = load_file(str(out / "ema/model.safetensors"))
    assert all(published[n].equal(state[n]) for n in names)
    assert any(not published[n].equal(weights[n]) for n in names)  # the average is not the last weights

    # Stopped after 4 steps and resumed to 6: the same weights and the same average, bit for bit.
    resumed = tmp_path / "resumed"
    train(run_config(clip_dir, 4), resumed)
    train(config, resumed, resume=True)
    for name in ("model.safetensors", "ema/model.safetensors"):
        a, b = load_file(str(out / name)), load_file(str(resumed / name))
        assert all(a[k].equal(b[k]) for k in a)


def test_validation_scores_the_average_and_best_holds_it(tmp_path, clip_dir):
    validation = {"every": 2, "directory": str(clip_dir), "num_clips": 1, "frames": 4, "track_points": 16,
                  "num_queries": 64, "keep_best": "loss/total", "tasks": []}
    out = tmp_path / "run"
    train(run_config(clip_dir, 4, validation=validation), out)
    record = json.loads((out / "best" / "best.json").read_text())
    best = load_file(str(out / "best" / "model.safetensors"))
    averaged = load_file(str(out / "checkpoints" / f"step-{record['step']:08d}" / "ema" / "model.safetensors"))
    assert all(best[k].equal(averaged[k]) for k in best)


def test_a_decay_outside_0_1_is_a_one_line_error(clip_dir):
    bad = fast_config(clip_dir, optim={"ema_decay": 1.5})
    with pytest.raises(UserError, match="ema_decay must lie in"):
        TrainConfig.from_dict(bad).validate()
