"""benchmarks/equal_time_ab.py: each arm calibrated on its own speed, trained for its budget's step count with the
cosine ending there, its overrides applied; a finished arm is kept when the driver runs again."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import yaml
from subprocess_budget import budget
from training_helpers import REPO, fast_config, subprocess_env, write_config


def run_driver(config, out, *arms: list[str]) -> subprocess.CompletedProcess:
    command = [sys.executable, str(REPO / "benchmarks" / "equal_time_ab.py"), "--config", str(config), "--out",
               str(out), "--minutes", "0.05", "--calibration-steps", "30"]
    for arm in arms:
        command += ["--arm", *arm]
    return subprocess.run(command, capture_output=True, text=True, env=subprocess_env(), timeout=budget(600))


@pytest.mark.slow(seconds=60)
def test_two_arms_at_equal_time(clip_dir, tmp_path):
    config = write_config(tmp_path / "config.yaml", fast_config(clip_dir, run={"grad_accum": 2, "max_steps": 5}))
    out = tmp_path / "runs"
    arms = (["q16", "data.dataset.sampler.num_queries=16"], ["q48", "data.dataset.sampler.num_queries=48"])
    done = run_driver(config, out, *arms)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads((out / "arms.json").read_text())
    assert [arm["name"] for arm in result["arms"]] == ["q16", "q48"]
    for arm, queries in zip(result["arms"], (16, 48)):
        steps = arm["steps"]
        assert steps == max(1, int(arm["calibrated_steps_per_s"] * 0.05 * 60)) and arm["clips"] == 2 * steps
        assert (out / arm["name"] / "checkpoints" / f"step-{steps:08d}").is_dir()
        trained = yaml.safe_load((out / arm["name"] / "train_config.yaml").read_text())
        assert trained["data"]["dataset"]["sampler"]["num_queries"] == queries
        assert trained["optim"]["decay_steps"] == steps  # the cosine ends with the budget
        assert arm["train_seconds"] > 0
    logs = {name: (out / f"{name}.log").stat().st_size for name, _ in arms}
    again = run_driver(config, out, *arms)  # finished arms are kept, not trained again
    assert again.returncode == 0, again.stderr[-2000:]
    assert {name: (out / f"{name}.log").stat().st_size for name, _ in arms} == logs


def test_one_arm_or_a_bad_override_is_refused(clip_dir, tmp_path):
    config = write_config(tmp_path / "config.yaml", fast_config(clip_dir))
    one = run_driver(config, tmp_path / "runs", ["a", "run.seed=1"])
    assert one.returncode == 2 and "at least two arms" in one.stderr
    bad = run_driver(config, tmp_path / "runs", ["a", "run.seed=1"], ["b", "run.seed"])
    assert bad.returncode == 2 and "KEY=VALUE" in bad.stderr
    failing = run_driver(config, tmp_path / "runs", ["a", "run.no_such_field=1"], ["b", "run.seed=1"])
    assert failing.returncode == 1 and "Traceback" not in failing.stderr
    assert "exited with" in failing.stderr and "a-calibration.log" in failing.stderr


def test_an_arms_threads_set_its_torch_threads_and_are_not_a_config_key(monkeypatch, tmp_path):
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import equal_time_ab
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    calls = []
    monkeypatch.setattr(equal_time_ab, "d4rt_train", lambda arguments, log, append, threads: calls.append(
        (arguments, threads)))
    equal_time_ab.train(tmp_path / "c.yaml", tmp_path / "runs" / "e2", 5, ["data.dataset.echo=2", "threads=2"])
    equal_time_ab.train(tmp_path / "c.yaml", tmp_path / "runs" / "e1", 5, ["data.dataset.echo=1"])
    (first, threads), (second, default) = calls
    assert threads == 2 and default == 1
    assert "--set" in first and "data.dataset.echo=2" in first and "threads=2" not in first
    assert "data.dataset.echo=1" in second
