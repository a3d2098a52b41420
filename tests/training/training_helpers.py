"""Helpers of the training tests: a fast run config and running `d4rt` in child processes."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import yaml
from subprocess_budget import budget

REPO = Path(__file__).resolve().parents[2]


def fast_config(clip_dir: Path, **sections) -> dict:
    """A tiny-preset run on the small clips that takes well under a second per step on one core.
    ``sections`` update the config's sections (``run={"max_steps": 4}``)."""
    config = {
        "model": {"preset": "tiny", "overrides": {"max_frames": 4}},
        "data": {"batch_size": 1, "workers": 0,
                 "dataset": {"source": "files", "directory": str(clip_dir), "frames": 4, "size": [32, 32],
                             "sampler": {"num_queries": 64}}},
        "optim": {"lr": 1e-3, "warmup_steps": 2},
        # fp32: exact comparisons mean the same on every CPU (auto is bf16 on AMX-BF16 CPUs only)
        "run": {"max_steps": 6, "device": "cpu", "precision": "fp32", "log_every": 1, "checkpoint_every": 2,
                "tensorboard": False, "progress": False},
        "validation": {"every": 0},
    }
    config = copy.deepcopy(config)
    for section, values in sections.items():
        config.setdefault(section, {}).update(values)
    return config


def write_config(path: Path, config: dict) -> Path:
    path.write_text(yaml.safe_dump(config))
    return path


def subprocess_env() -> dict:
    """The environment for child processes: this checkout's sources first, one thread each."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), env.get("PYTHONPATH", "")])
    env["OMP_NUM_THREADS"] = "1"
    env.pop("PYTEST_XDIST_WORKER", None)
    return env


def run_d4rt(*args: str, timeout: float = budget(300)) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "d4rt", *args], capture_output=True, text=True,
                          env=subprocess_env(), timeout=timeout)
