"""The trainer's parts: learning-rate schedule, weight-decay groups, sample stream, checkpoint files,
random-generator states."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.training import OptimConfig, build_optimizer, learning_rate, read_checkpoint, write_checkpoint
from d4rt.training.data import SampleStream
from d4rt.training.optimization import freeze_parameters, set_learning_rate
from d4rt.training.randomness import capture_rng_state, restore_rng_state, seed_rank


def test_paper_schedule_warm_up_then_cosine():
    paper = OptimConfig()  # 2,500 steps to 1e-4, cosine to 1e-6
    total = 500_000
    assert learning_rate(0, paper, total) == pytest.approx(1e-4 / 2500)
    assert learning_rate(1249, paper, total) == pytest.approx(0.5e-4)
    assert learning_rate(2499, paper, total) == pytest.approx(1e-4)
    assert learning_rate(2500, paper, total) == pytest.approx(1e-4)
    middle = 2500 + (total - 2500) // 2
    assert learning_rate(middle, paper, total) == pytest.approx((1e-4 + 1e-6) / 2, rel=1e-4)
    assert learning_rate(total, paper, total) == pytest.approx(1e-6)
    assert learning_rate(total + 10, paper, total) == pytest.approx(1e-6)
    after = [learning_rate(s, paper, total) for s in range(2500, total, 997)]
    assert all(a >= b for a, b in zip(after, after[1:]))
    short = OptimConfig(warmup_steps=0, decay_steps=100)
    assert learning_rate(0, short, 10) == pytest.approx(1e-4)
    assert learning_rate(50, short, 10) == pytest.approx(1e-6 + 0.5 * (1e-4 - 1e-6) * (1 + math.cos(math.pi / 2)))


def test_weight_decay_skips_biases_norms_and_position_tables():
    model = D4RT(D4RTConfig.preset("tiny"))
    optimizer = build_optimizer(model, OptimConfig())
    names = {id(p): n for n, p in model.named_parameters()}
    decayed = {names[id(p)] for p in optimizer.param_groups[0]["params"]}
    kept = {names[id(p)] for p in optimizer.param_groups[1]["params"]}
    assert optimizer.param_groups[0]["weight_decay"] == 0.03 and optimizer.param_groups[1]["weight_decay"] == 0.0
    assert decayed | kept == set(names.values()) and not decayed & kept
    assert "encoder.blocks.0.attn.proj.weight" in decayed and "query_embedding.time_src.weight" in decayed
    for name in ("encoder.blocks.0.attn.proj.bias", "encoder.norm.weight", "encoder.pos_embed.time",
                 "encoder.pos_embed.space", "encoder.blocks.0.attn.q_bias"):
        assert name in kept, name


def test_lr_scale_puts_matching_parameters_in_groups_whose_rate_is_scaled():
    from d4rt.training.optimization import set_learning_rate

    model = D4RT(D4RTConfig.preset("tiny"))
    config = OptimConfig(lr_scale={"encoder.blocks.[23].*": 10.0, "decoder.*": 0.5})
    optimizer = build_optimizer(model, config)
    names = {id(p): n for n, p in model.named_parameters()}
    set_learning_rate(optimizer, 2e-5)
    by_name = {names[id(p)]: g for g in optimizer.param_groups for p in g["params"]}
    assert len(by_name) == len(names)  # every parameter in exactly one group
    for name, group in by_name.items():
        scale = 10.0 if name.startswith(("encoder.blocks.2.", "encoder.blocks.3.")) else \
            0.5 if name.startswith("decoder.") else 1.0
        assert group["lr"] == pytest.approx(2e-5 * scale), name
    assert by_name["encoder.blocks.2.attn.proj.weight"]["weight_decay"] == 0.03
    assert by_name["encoder.blocks.2.attn.proj.bias"]["weight_decay"] == 0.0
    # Without patterns: the two groups every earlier checkpoint holds, in the same order.
    plain = build_optimizer(model, OptimConfig())
    assert [g["weight_decay"] for g in plain.param_groups] == [0.03, 0.0]
    assert all("lr_scale" not in g for g in plain.param_groups)


def test_lr_scale_moves_the_matching_parameters_that_many_times_further():
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(4, 4), torch.nn.Linear(4, 1))
    before = [p.detach().clone() for p in model.parameters()]
    optimizer = build_optimizer(model, OptimConfig(lr=1e-3, weight_decay=0.0, lr_scale={"1.*": 10}))
    from d4rt.training.optimization import set_learning_rate

    set_learning_rate(optimizer, 1e-3)
    model(torch.randn(8, 4)).square().mean().backward()
    optimizer.step()  # Adam's first step moves every parameter with a gradient by about its rate
    moved = [(p.detach() - b).abs().max().item() for p, b in zip(model.parameters(), before)]
    assert moved[0] == pytest.approx(1e-3, rel=1e-2) and moved[2] == pytest.approx(1e-2, rel=1e-2)


def test_lr_scale_refuses_a_pattern_that_matches_nothing_and_a_factor_that_is_not_positive():
    from d4rt.training import TrainConfig

    with pytest.raises(UserError, match=r"'encoder\.block\.\*' match no parameter"):
        build_optimizer(D4RT(D4RTConfig.preset("tiny")), OptimConfig(lr_scale={"encoder.block.*": 2.0}))
    for scale in (0, -1.0, "ten", True):
        with pytest.raises(UserError, match="optim.lr_scale maps parameter-name patterns to positive factors"):
            TrainConfig.from_dict({"optim": {"lr_scale": {"decoder.*": scale}}}).validate()


def test_sample_stream_splits_one_global_order_across_ranks_and_resumes_anywhere():
    length, batch, accum, world = 7, 2, 3, 2

    def keys(rank, start=0, steps=4, world_size=world, grad_accum=accum):
        stream = iter(SampleStream(length, 5, start, batch, grad_accum, rank, world_size))
        return [next(stream) for _ in range(steps * grad_accum)]

    single = keys(0, world_size=1, grad_accum=accum * world)  # one process accumulating all of it
    per_rank = [keys(r) for r in range(world)]
    for step in range(4):
        for micro in range(accum):
            for rank in range(world):  # rank r's micro-batch m is the single process's (m * world + r)
                assert per_rank[rank][step * accum + micro] == single[step * accum * world + micro * world + rank]
    flat = [k for group in single for k in group]
    for epoch in range(2):  # every epoch visits every clip once, in a fresh order
        assert sorted(i for e, i in flat[epoch * length:(epoch + 1) * length]) == list(range(length))
        assert all(e == epoch for e, _ in flat[epoch * length:(epoch + 1) * length])
    assert [i for _, i in flat[:length]] != [i for _, i in flat[length:2 * length]]
    # Resuming at step 2 yields exactly what the uninterrupted stream yields from step 2 on.
    samples_per_step = batch * accum * world
    assert keys(1, start=2 * samples_per_step, steps=2) == per_rank[1][2 * accum:]


def test_an_echoing_stream_repeats_each_clip_of_the_plain_stream_and_resumes_anywhere():
    def flat(echo, start=0, samples=24):
        stream = iter(SampleStream(7, 5, start, 2, 3, 0, 1, echo=echo))
        return [k for _ in range(samples // 2) for k in next(stream)]

    plain, echoed = flat(1), flat(3)
    assert echoed == [(*plain[g // 3], g % 3) for g in range(24)]  # each plain key three times, repeats 0, 1, 2
    assert flat(3, start=6, samples=18) == echoed[6:]  # resumed after one step of 6 samples


def test_echo_is_refused_for_track_clips():
    from d4rt.training import TrainConfig

    config = TrainConfig.from_dict({"data": {"dataset": {"echo": 2}, "tracks": {"directory": "unused"}}})
    with pytest.raises(UserError, match="echo 2 applies to data.dataset"):
        config.validate()


def test_checkpoint_round_trip_is_exact_and_loads_as_a_model(tmp_path):
    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny", max_frames=4))
    optimizer = build_optimizer(model, OptimConfig(lr=1e-3))
    video, queries = torch.rand(1, 4, 32, 32, 3), torch.cat([torch.rand(1, 8, 2), torch.zeros(1, 8, 3)], -1)
    for _ in range(2):
        out = model(video, queries, torch.ones(1))
        (out["points"].square().mean() + out["uv"].abs().mean()).backward()
        optimizer.step()
        optimizer.zero_grad()
    from d4rt.training.distributed import optimizer_state

    state = optimizer_state(model, optimizer)
    path = write_checkpoint(tmp_path, 2, model.state_dict(), model.config, state, {"next_sample": 2, "note": [1, 2]})
    weights, optim, trainer = read_checkpoint(path)
    assert trainer["step"] == 2 and trainer["next_sample"] == 2 and trainer["note"] == [1, 2]
    assert all(torch.equal(weights[k], v) for k, v in model.state_dict().items())
    assert optim["state"].keys() == state["state"].keys()
    for name, entries in state["state"].items():
        for key, value in entries.items():
            assert torch.equal(optim["state"][name][key], value), (name, key)
    assert optim["param_groups"] == state["param_groups"]  # betas come back as a tuple
    restored = D4RT.from_pretrained(path)  # a checkpoint directory is also a model directory
    assert all(torch.equal(restored.state_dict()[k], v) for k, v in model.state_dict().items())


def test_scaled_groups_survive_a_checkpoint_into_a_fresh_optimizer(tmp_path):
    from d4rt.training.distributed import DistributedContext, load_optimizer_state, optimizer_state

    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny", max_frames=4))
    config = OptimConfig(lr=1e-3, lr_scale={"decoder.blocks.1.*": 4.0})
    optimizer = build_optimizer(model, config)
    video, queries = torch.rand(1, 4, 32, 32, 3), torch.cat([torch.rand(1, 8, 2), torch.zeros(1, 8, 3)], -1)
    out = model(video, queries, torch.ones(1))
    sum(v.square().mean() for v in out.values() if torch.is_tensor(v) and v.requires_grad).backward()
    optimizer.step()
    path = write_checkpoint(tmp_path, 1, model.state_dict(), model.config, optimizer_state(model, optimizer), {})
    _, optim, _ = read_checkpoint(path)
    model.zero_grad(set_to_none=True)  # as a resumed run's fresh model has none
    fresh = build_optimizer(model, config)
    load_optimizer_state(model, fresh, optim, DistributedContext())
    assert [g.get("lr_scale") for g in fresh.param_groups] == [None, None, 4.0, 4.0]
    assert [len(g["params"]) for g in fresh.param_groups] == [len(g["params"]) for g in optimizer.param_groups]
    for old, new in zip(optimizer.state_dict()["state"].values(), fresh.state_dict()["state"].values()):
        assert torch.equal(old["exp_avg"], new["exp_avg"])


def test_rng_states_round_trip_through_json():
    import json

    seed_rank(3, 1)
    state = json.loads(json.dumps(capture_rng_state(torch.device("cpu"))))
    expected = (random.random(), np.random.rand(), torch.rand(3))
    seed_rank(99, 0)
    restore_rng_state(state, torch.device("cpu"))
    again = (random.random(), np.random.rand(), torch.rand(3))
    assert expected[:2] == again[:2] and torch.equal(expected[2], again[2])
    seed_rank(3, 0)
    other_rank = torch.rand(3)
    assert not torch.equal(other_rank, expected[2])  # ranks draw different streams


def test_freeze_turns_off_matching_gradients_and_refuses_a_pattern_that_matches_nothing_or_everything():


    model = D4RT(D4RTConfig.preset("tiny"))
    frozen = freeze_parameters(model, ["encoder.*", "query_embedding.time_*"])
    assert frozen == sum(p.numel() for n, p in model.named_parameters()
                         if n.startswith(("encoder.", "query_embedding.time_")))
    optimizer = build_optimizer(model, OptimConfig())
    kept = {id(p) for g in optimizer.param_groups for p in g["params"]}
    for name, param in model.named_parameters():
        frozen_here = name.startswith(("encoder.", "query_embedding.time_"))
        assert param.requires_grad is not frozen_here and (id(param) in kept) is not frozen_here, name
    with pytest.raises(UserError, match=r"'encoders\.\*' match no parameter"):
        freeze_parameters(D4RT(D4RTConfig.preset("tiny")), ["encoders.*"])
    with pytest.raises(UserError, match="freezes every parameter"):
        freeze_parameters(D4RT(D4RTConfig.preset("tiny")), ["encoder.*", "decoder.*", "query_embedding.*"])


def test_muon_takes_the_matched_trained_matrices_and_adamw_the_rest_and_refuses_what_it_cannot_take():
    from d4rt.training.optimization import OptimizerChain

    model = D4RT(D4RTConfig.preset("tiny"))
    chain = build_optimizer(model, OptimConfig(muon=("decoder.blocks.*",), lr_scale={"decoder.blocks.0.*": 2.0}))
    assert isinstance(chain, OptimizerChain)
    adamw, muon = chain.optimizers
    assert isinstance(adamw, torch.optim.AdamW) and isinstance(muon, torch.optim.Muon)
    names = {id(p): n for n, p in model.named_parameters()}
    stepped = {names[id(p)]: opt for opt in chain.optimizers for g in opt.param_groups for p in g["params"]}
    assert sorted(stepped) == sorted(names.values())  # every parameter, once
    expected = {n for n, p in model.named_parameters() if n.startswith("decoder.blocks.") and p.ndim == 2}
    assert {n for n, opt in stepped.items() if opt is muon} == expected
    # the rate's schedule and lr_scale reach Muon's groups too
    set_learning_rate(chain, 1e-3)
    rates = {names[id(p)]: g["lr"] for g in muon.param_groups for p in g["params"]}
    assert rates["decoder.blocks.0.mlp.fc1.weight"] == 2e-3 and rates["decoder.blocks.1.mlp.fc1.weight"] == 1e-3
    assert all(g["weight_decay"] == OptimConfig().weight_decay for g in muon.param_groups)
    assert isinstance(build_optimizer(model, OptimConfig()), torch.optim.AdamW)  # no patterns: AdamW alone
    with pytest.raises(UserError, match=r"optim.muon pattern\(s\) '\*.bias' match no trained 2-D weight"):
        build_optimizer(model, OptimConfig(muon=("decoder.*", "*.bias")))
    freeze_parameters(model, ["decoder.*"])
    with pytest.raises(UserError, match="match no trained 2-D weight"):
        build_optimizer(model, OptimConfig(muon=("decoder.blocks.*",)))


def test_a_run_written_before_an_option_existed_resumes_under_its_default(tmp_path):
    from d4rt.training import TrainConfig
    from d4rt.training.trainer import _check_resumable

    current = TrainConfig().to_dict()
    older = TrainConfig().to_dict()
    del older["optim"]["freeze"]  # as every checkpoint written before optim.freeze
    _check_resumable(older, current, tmp_path)
    frozen = TrainConfig.from_dict({"optim": {"freeze": ["encoder.*"]}}).to_dict()
    with pytest.raises(UserError, match="optim.freeze"):
        _check_resumable(older, frozen, tmp_path)
