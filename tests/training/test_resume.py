"""Kill and resume: a run stopped with SIGKILL (or SIGTERM, which checkpoints the current step, also when
sent to the whole process group with loader workers) and resumed ends bitwise equal to an uninterrupted
run; a checkpoint half-written at the kill is never picked up."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from safetensors.torch import load_file

from d4rt.training import latest_checkpoint
from training_helpers import fast_config, run_d4rt, subprocess_env, write_config
from subprocess_budget import budget


def same_tensors(a: Path, b: Path) -> bool:
    x, y = load_file(str(a)), load_file(str(b))
    return x.keys() == y.keys() and all(x[k].dtype == y[k].dtype and x[k].equal(y[k]) for k in x)


def start_run_and_wait_for_steps(config: Path, out: Path, steps: int, new_session: bool = False) -> subprocess.Popen:
    """``d4rt train`` in a subprocess (its own process group with ``new_session``), returned once it has
    logged ``steps`` steps (or exited, or 240 s passed)."""
    process = subprocess.Popen([sys.executable, "-m", "d4rt", "train", "--config", str(config), "--out", str(out)],
                               env=subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=new_session)
    metrics = out / "metrics.jsonl"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and process.poll() is None:
        if metrics.is_file() and len(metrics.read_text().splitlines()) >= steps:
            break
        time.sleep(0.01)
    return process


@pytest.mark.slow(seconds=28)
def test_sigkill_mid_run_then_resume_is_bitwise_equal_to_an_uninterrupted_run(tmp_path, clip_dir):
    config = write_config(tmp_path / "run.yaml", fast_config(clip_dir, run={"max_steps": 12, "checkpoint_every": 2,
                                                                           "log_every": 1}))
    reference = tmp_path / "reference"
    done = run_d4rt("train", "--config", str(config), "--out", str(reference))
    assert done.returncode == 0, done.stderr

    killed = tmp_path / "killed"
    process = subprocess.Popen([sys.executable, "-m", "d4rt", "train", "--config", str(config), "--out", str(killed)],
                               env=subprocess_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # Kill at the first sign of the writer working on the checkpoint after step 4 (its temporary
    # directory), or failing that as soon as step 6 is on disk: either way mid-run.
    root = killed / "checkpoints"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and process.poll() is None:
        names = [p.name for p in root.iterdir()] if root.is_dir() else []
        if "step-00000004" in names and any(n.startswith(".step-") or n == "step-00000006" for n in names):
            break
        time.sleep(0.002)
    process.send_signal(signal.SIGKILL)
    assert process.wait(timeout=30) == -signal.SIGKILL, "the run finished before it could be killed"
    survivor = latest_checkpoint(root)
    assert survivor is not None and survivor.name in ("step-00000004", "step-00000006")
    assert not (killed / "checkpoints" / "step-00000012").exists()

    resumed = run_d4rt("train", "--config", str(config), "--out", str(killed), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert f"resumed from {survivor}" in resumed.stdout + resumed.stderr
    assert not any(p.name.startswith(".step-") for p in root.iterdir())  # leftovers removed
    assert same_tensors(reference / "model.safetensors", killed / "model.safetensors")
    for name in ("model.safetensors", "optimizer.safetensors"):
        assert same_tensors(reference / "checkpoints/step-00000012" / name, killed / "checkpoints/step-00000012" / name)
    # The log holds every step exactly once, and the same numbers as the uninterrupted run.
    logged = [json.loads(line) for line in (killed / "metrics.jsonl").read_text().splitlines()]
    expected = [json.loads(line) for line in (reference / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in logged] == list(range(1, 13))
    assert [r["loss/total"] for r in logged] == [r["loss/total"] for r in expected]


def test_sigterm_writes_a_checkpoint_of_the_current_step_and_resume_loses_nothing(tmp_path, clip_dir):
    """Preemption: SIGTERM mid-run finishes the step, checkpoints it (off the checkpoint schedule), exits
    with 128 + SIGTERM; --resume then ends bitwise equal to an uninterrupted run."""
    run = {"max_steps": 10, "checkpoint_every": 100, "log_every": 1}
    config = write_config(tmp_path / "run.yaml", fast_config(clip_dir, run=run))
    reference = tmp_path / "reference"
    assert run_d4rt("train", "--config", str(config), "--out", str(reference)).returncode == 0

    stopped = tmp_path / "stopped"
    process = start_run_and_wait_for_steps(config, stopped, 3)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=budget(120))
    assert process.returncode == 128 + signal.SIGTERM, err
    step = int(re.search(r"stopped at step (\d+) by SIGTERM", out).group(1))
    assert 3 <= step < 10 and "checkpoint written, continue with --resume" in out + err
    assert latest_checkpoint(stopped / "checkpoints").name == f"step-{step:08d}"  # not on the schedule

    resumed = run_d4rt("train", "--config", str(config), "--out", str(stopped), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert f"at step {step}" in resumed.stdout + resumed.stderr
    assert same_tensors(reference / "model.safetensors", stopped / "model.safetensors")
    for name in ("model.safetensors", "optimizer.safetensors"):
        assert same_tensors(reference / "checkpoints/step-00000010" / name, stopped / "checkpoints/step-00000010" / name)


@pytest.fixture(scope="module")
def workers_reference(tmp_path_factory, clip_dir) -> tuple[Path, Path]:
    """An 8-step config with two loader workers and two micro-batches per step (the stopping step still
    needs a batch after the signal), and its uninterrupted run: (config, run directory)."""
    tmp = tmp_path_factory.mktemp("workers")
    run = {"max_steps": 8, "grad_accum": 2, "checkpoint_every": 100, "log_every": 1}
    config = write_config(tmp / "run.yaml", fast_config(clip_dir, data={"workers": 2}, run=run))
    done = run_d4rt("train", "--config", str(config), "--out", str(tmp / "reference"))
    assert done.returncode == 0, done.stderr
    return config, tmp / "reference"


@pytest.mark.parametrize("name", ["SIGTERM", "SIGINT"])
def test_a_signal_to_the_process_group_with_loader_workers_stops_cleanly_and_resume_loses_nothing(
        tmp_path, workers_reference, name):
    """`timeout`, a scheduler's preemption or Ctrl-C signal the whole process group, loader workers too:
    they must not die under the run (which then failed with "DataLoader worker ... killed by signal"),
    the run checkpoints the current step, exits 128 + the signal and leaves no worker behind."""
    config, reference = workers_reference
    sig = signal.Signals[name]
    stopped = tmp_path / "stopped"
    process = start_run_and_wait_for_steps(config, stopped, 3, new_session=True)
    os.killpg(process.pid, sig)  # the group: the run and its workers
    out, err = process.communicate(timeout=budget(120))
    assert "killed by signal" not in err and "exited unexpectedly" not in err, err
    assert process.returncode == 128 + sig, err
    step = int(re.search(rf"stopped at step (\d+) by {name}", out).group(1))
    assert 3 <= step < 8
    assert latest_checkpoint(stopped / "checkpoints").name == f"step-{step:08d}"
    with pytest.raises(ProcessLookupError):  # the workers were shut down before the run exited
        os.killpg(process.pid, 0)

    resumed = run_d4rt("train", "--config", str(config), "--out", str(stopped), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert f"at step {step}" in resumed.stdout + resumed.stderr
    assert same_tensors(reference / "model.safetensors", stopped / "model.safetensors")
    for file in ("model.safetensors", "optimizer.safetensors"):
        assert same_tensors(reference / "checkpoints/step-00000008" / file, stopped / "checkpoints/step-00000008" / file)


_KILL_MID_WRITE = """
import os, signal, sys
import safetensors.torch
from d4rt.config import D4RTConfig
from d4rt.model import D4RT
from d4rt.training import checkpoint

model = D4RT(D4RTConfig.preset("tiny", max_frames=4))
state = {"state": {}, "param_groups": [{"lr": 0.1, "params": list(model.state_dict())}]}
checkpoint.write_checkpoint(sys.argv[1], 2, model.state_dict(), model.config, state, {"note": "complete"})
real_save = safetensors.torch.save_file

def save_half_then_die(tensors, path, metadata=None):
    real_save(tensors, path, metadata=metadata)
    with open(path, "r+b") as fh:
        fh.truncate(os.path.getsize(path) // 2)
    os.kill(os.getpid(), signal.SIGKILL)

checkpoint.save_file = save_half_then_die  # the optimizer file of step 4 is cut short, then SIGKILL
checkpoint.write_checkpoint(sys.argv[1], 4, model.state_dict(), model.config, state, {"note": "never"})
"""


def test_a_checkpoint_half_written_at_a_kill_is_never_picked_up(tmp_path):
    root = tmp_path / "checkpoints"
    killed = subprocess.run([sys.executable, "-c", _KILL_MID_WRITE, str(root)], env=subprocess_env(),
                            capture_output=True, text=True, timeout=budget(120))
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    leftovers = [p.name for p in root.iterdir()]
    assert "step-00000002" in leftovers and "step-00000004" not in leftovers
    assert any(name.startswith(".step-00000004.tmp-") for name in leftovers)
    assert latest_checkpoint(root).name == "step-00000002"


def test_a_checkpoint_with_a_truncated_file_is_skipped(tmp_path):
    import torch

    from d4rt.config import D4RTConfig
    from d4rt.model import D4RT
    from d4rt.training.checkpoint import is_complete, write_checkpoint

    model = D4RT(D4RTConfig.preset("tiny", max_frames=4))
    state = {"state": {"x": {"step": torch.tensor(1.0)}}, "param_groups": []}
    for step in (2, 4):
        write_checkpoint(tmp_path, step, model.state_dict(), model.config, state, {})
    weights = tmp_path / "step-00000004" / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[:-10])  # e.g. a disk that lost the tail after a crash
    assert not is_complete(tmp_path / "step-00000004")
    assert latest_checkpoint(tmp_path).name == "step-00000002"
