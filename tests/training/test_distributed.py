"""The same training code under torchrun (gloo on CPU): DDP and FSDP (fully_shard) train a few steps,
every rank ends with identical parameters, equal to one process that accumulates the same samples; a
run stopped at a checkpoint and resumed under the same strategy ends bitwise equal (weights, optimiser state and
the average of the weights); a frozen encoder (optim.freeze) stays the start's under both strategies."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from d4rt.training import TrainConfig, train
from training_helpers import fast_config, subprocess_env, write_config
from subprocess_budget import budget

WORKER = Path(__file__).with_name("distributed_worker.py")


def torchrun(config: Path, out: Path, report: Path, *flags: str) -> list[dict]:
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
               str(WORKER), str(config), str(out), str(report), *flags]
    # A session of its own: if anything hangs, the launcher and its workers are killed together.
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               env=subprocess_env(), start_new_session=True)
    try:
        output, _ = process.communicate(timeout=budget(400))
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        output, _ = process.communicate()
    assert process.returncode == 0, output[-6000:]
    return json.loads(report.read_text())


@pytest.fixture(scope="module")
def single_process_reference(tmp_path_factory, clip_dir) -> dict:
    """One process, 2 micro-batches per step: the samples and the averaged gradient of 2 ranks x 1 clip."""
    out = tmp_path_factory.mktemp("single")
    config = fast_config(clip_dir, run={"max_steps": 3, "grad_accum": 2, "checkpoint_every": 3})
    train(TrainConfig.from_dict(config), out)
    return load_file(str(out / "model.safetensors"))


@pytest.mark.parametrize("strategy", ["ddp", "fsdp"])
def test_two_processes_train_to_identical_parameters(strategy, tmp_path, clip_dir, single_process_reference):
    config = write_config(tmp_path / "run.yaml", fast_config(
        clip_dir, run={"max_steps": 3, "grad_accum": 1, "checkpoint_every": 3, "strategy": strategy}))
    ranks = torchrun(config, tmp_path / "out", tmp_path / "report.json")
    assert [r["strategy"] for r in ranks] == [strategy, strategy]
    assert ranks[0]["digests"] == ranks[1]["digests"], "parameters differ between ranks"

    trained = load_file(str(tmp_path / "out" / "model.safetensors"))  # full weights written by rank 0
    assert trained.keys() == single_process_reference.keys()
    moved = 0
    for name, reference in single_process_reference.items():
        # Same samples, same mean gradient: only the order of float reductions differs.
        torch.testing.assert_close(trained[name], reference, rtol=1e-4, atol=1e-5, msg=name)
        moved += int(not torch.equal(trained[name], reference))
    assert moved > 0 or strategy == "ddp"  # sanity: the comparison looks at trained, non-trivial weights


@pytest.mark.slow(seconds=66)
@pytest.mark.parametrize("strategy", ["ddp", "fsdp"])
def test_resume_under_torchrun_restores_sharded_state_exactly(strategy, tmp_path, clip_dir):
    def config(steps: int) -> Path:
        optim = {**fast_config(clip_dir)["optim"], "ema_decay": 0.5}  # the average is sharded and restored too
        return write_config(tmp_path / f"run{steps}.yaml", fast_config(
            clip_dir, optim=optim, run={"max_steps": steps, "checkpoint_every": 2, "strategy": strategy}))

    torchrun(config(3), tmp_path / "straight", tmp_path / "a.json")
    torchrun(config(2), tmp_path / "stopped", tmp_path / "b.json")  # checkpoint at step 2, then exit
    ranks = torchrun(config(3), tmp_path / "stopped", tmp_path / "c.json", "--resume")
    assert ranks[0]["digests"] == ranks[1]["digests"]
    straight = load_file(str(tmp_path / "straight" / "checkpoints" / "step-00000003" / "optimizer.safetensors"))
    resumed = load_file(str(tmp_path / "stopped" / "checkpoints" / "step-00000003" / "optimizer.safetensors"))
    assert straight.keys() == resumed.keys() and all(straight[k].equal(resumed[k]) for k in straight)
    for name in ("model.safetensors", "ema/model.safetensors"):
        a, b = (load_file(str(tmp_path / d / name)) for d in ("straight", "stopped"))
        assert all(a[k].equal(b[k]) for k in a)
    weights, averaged = (load_file(str(tmp_path / "stopped" / name))
                         for name in ("model.safetensors", "ema/model.safetensors"))
    assert any(not weights[k].equal(averaged[k]) for k in weights)  # the average was gathered, not the weights


@pytest.mark.slow(seconds=25)
@pytest.mark.parametrize("strategy", ["ddp", "fsdp"])
def test_a_frozen_encoder_stays_frozen_under_torchrun_and_the_rest_trains_as_in_one_process(strategy, tmp_path,
                                                                                              clip_dir):
    frozen = {"lr": 1e-3, "warmup_steps": 2, "freeze": ["encoder.*"]}
    single = fast_config(clip_dir, optim=frozen, run={"max_steps": 2, "grad_accum": 2, "checkpoint_every": 2})
    train(TrainConfig.from_dict(single), tmp_path / "single")
    reference = load_file(str(tmp_path / "single" / "model.safetensors"))
    config = write_config(tmp_path / "run.yaml", fast_config(
        clip_dir, optim=frozen, run={"max_steps": 2, "grad_accum": 1, "checkpoint_every": 2, "strategy": strategy}))
    ranks = torchrun(config, tmp_path / "out", tmp_path / "report.json")
    assert [r["strategy"] for r in ranks] == [strategy, strategy]
    assert ranks[0]["digests"] == ranks[1]["digests"], "parameters differ between ranks"
    trained = load_file(str(tmp_path / "out" / "model.safetensors"))
    for name, expected in reference.items():
        if name.startswith("encoder."):  # both started from the same seeded weights and neither moved them
            assert torch.equal(trained[name], expected), name
        else:
            torch.testing.assert_close(trained[name], expected, rtol=1e-4, atol=1e-5, msg=name)
