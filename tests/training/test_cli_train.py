"""`d4rt train` through the real console entry point, with the shipped tiny CPU config (fixed interface)."""

from __future__ import annotations

import json

import pytest

from d4rt.model import D4RT
from training_helpers import REPO, fast_config, run_d4rt, write_config

TINY = str(REPO / "configs" / "tiny-cpu.yaml")


@pytest.mark.slow(seconds=58)
def test_tiny_cpu_config_trains_writes_safetensors_logs_and_resumes(tmp_path):
    out = tmp_path / "run"
    done = run_d4rt("train", "--config", TINY, "--out", str(out), "--max-steps", "2")
    assert done.returncode == 0, done.stderr
    assert (out / "model.safetensors").is_file() and (out / "config.json").is_file()
    model = D4RT.from_pretrained(out)  # strict load of the published weights
    assert model.config.name == "tiny"
    assert (out / "checkpoints" / "step-00000002" / "optimizer.safetensors").is_file()
    assert not list(out.rglob("*.pt")) and not list(out.rglob("*.pkl"))  # no pickles anywhere
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))
    assert "train" in done.stderr  # the progress bar

    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    logged = {key for record in records for key in record}
    for key in ("loss/total", "loss/3d", "loss/3d_confident", "loss/confidence", "loss/2d", "loss/visibility",
                "loss/motion", "loss/normal", "lr", "grad_norm", "throughput/clips_per_s",
                "throughput/queries_per_s", "val/loss/3d", "val/abs_rel_scale_shift", "val/ate", "val/rpe_rot",
                "val/apd3d", "val/aj", "val/oa"):
        assert key in logged, key

    resumed = run_d4rt("train", "--config", TINY, "--out", str(out), "--max-steps", "3", "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert "resumed from" in resumed.stdout + resumed.stderr
    assert (out / "checkpoints" / "step-00000003").is_dir()


def test_existing_run_without_resume_is_refused_in_one_line(tmp_path, clip_dir):
    config = write_config(tmp_path / "run.yaml", fast_config(clip_dir, run={"max_steps": 1, "checkpoint_every": 1}))
    assert run_d4rt("train", "--config", str(config), "--out", str(tmp_path / "run")).returncode == 0
    again = run_d4rt("train", "--config", str(config), "--out", str(tmp_path / "run"))
    assert again.returncode == 2
    assert again.stderr.strip().count("\n") == 0 and "--resume" in again.stderr


def test_resume_with_a_changed_recipe_is_refused(tmp_path, clip_dir):
    config = write_config(tmp_path / "run.yaml", fast_config(clip_dir, run={"max_steps": 1, "checkpoint_every": 1}))
    assert run_d4rt("train", "--config", str(config), "--out", str(tmp_path / "run")).returncode == 0
    changed = run_d4rt("train", "--config", str(config), "--out", str(tmp_path / "run"), "--resume",
                       "--max-steps", "2", "--set", "optim.lr=0.5")
    assert changed.returncode == 2 and "optim.lr" in changed.stderr


@pytest.mark.slow(seconds=29)
def test_bad_configs_and_arguments_fail_in_one_line(tmp_path, clip_dir):
    cases = [
        (fast_config(clip_dir, optim={"lr": 1e-3, "lrr": 1.0}), "lrr"),
        (fast_config(clip_dir, run={"max_steps": "many"}), "run.max_steps"),
        (fast_config(clip_dir, data={"batch_size": 0}), "data.batch_size"),
        (fast_config(clip_dir, model={"preset": "enormous"}), "enormous"),
    ]
    for index, (config, message) in enumerate(cases):
        path = write_config(tmp_path / f"bad{index}.yaml", config)
        done = run_d4rt("train", "--config", str(path), "--out", str(tmp_path / f"run{index}"))
        assert done.returncode == 2, (message, done.stderr)
        assert message in done.stderr and done.stderr.strip().count("\n") == 0, done.stderr
    missing = run_d4rt("train", "--config", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "x"))
    assert missing.returncode == 2 and "not found" in missing.stderr
    bad_steps = run_d4rt("train", "--config", TINY, "--out", str(tmp_path / "y"), "--max-steps", "0")
    assert bad_steps.returncode == 2 and "--max-steps" in bad_steps.stderr
