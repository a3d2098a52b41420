"""benchmarks/judge_beside_training.sh launch: it waits for every leg, applies the stop rule to each, and runs the
judge only when every leg passes (a soup's legs are judged together)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "judge_beside_training.sh"


def _leg(tmp_path: Path, name: str, confidence: float) -> tuple[Path, Path]:
    run = tmp_path / name
    run.mkdir()
    rows = [{"step": step, "loss/confidence_mean": confidence} for step in range(20, 601, 20)]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    log = tmp_path / f"{name}.log"
    log.write_text(f"trained to step 600; weights in {run}\n")
    return log, run


def _launch(tmp_path: Path, legs: list[tuple[Path, Path]], expect: int = 0, **env_changes) -> Path:
    """Run launch over the legs (the judge command: touch JUDGE/judged); expect its exit status."""
    judge = tmp_path / "judge"
    (judge / "start").mkdir(parents=True, exist_ok=True)
    env = {"PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}", "J": str(judge),
           "GATE_SEED": "1", "STEPS": "600", "POLL": "0.2", "RUN_LOG": " ".join(str(log) for log, _ in legs),
           "RUN_DIR": " ".join(str(run) for _, run in legs), **env_changes}
    done = subprocess.run(["bash", str(SCRIPT), "launch", "--", "touch", str(judge / "judged")], env=env, timeout=60,
                          cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == expect, done.stderr
    return judge


def test_the_judge_runs_when_every_leg_passes_the_stop_rule(tmp_path):
    judge = _launch(tmp_path, [_leg(tmp_path, "a", 0.74), _leg(tmp_path, "b", 0.71)])
    assert (judge / "judged").exists()
    lines = (judge / "stop-rule.txt").read_text().splitlines()
    assert len(lines) == 2 and lines[0].endswith("0.740 (10 logged steps) -> judge") and "0.710" in lines[1]


def test_one_leg_below_the_stop_rule_stops_the_judge(tmp_path):
    judge = _launch(tmp_path, [_leg(tmp_path, "a", 0.74), _leg(tmp_path, "b", 0.55)])
    assert not (judge / "judged").exists()
    assert "-> stop" in (judge / "stop-rule.txt").read_text()
    assert "stop rule: stop" in (judge / "launch.log").read_text()


def test_the_judge_waits_for_a_leg_still_training(tmp_path):
    """The second leg's log says "trained to step 600" only after launch has started: the judge runs after it."""
    a, b = _leg(tmp_path, "a", 0.74), _leg(tmp_path, "b", 0.71)
    b[0].write_text("step 580\n")
    finish = threading.Timer(1.0, lambda: b[0].write_text("trained to step 600; weights in b\n"))
    finish.start()
    started = time.monotonic()
    judge = _launch(tmp_path, [a, b])
    finish.join()
    assert (judge / "judged").exists() and time.monotonic() - started >= 1.0


def test_mismatched_or_empty_leg_lists_and_an_unreadable_run_are_errors_not_stops(tmp_path):
    a, b = _leg(tmp_path, "a", 0.74), _leg(tmp_path, "b", 0.71)
    _launch(tmp_path, [a, b], expect=2, RUN_DIR=str(a[1]))
    _launch(tmp_path, [a], expect=2, RUN_LOG=" ", RUN_DIR=" ")
    judge = _launch(tmp_path, [a, (b[0], tmp_path / "missing")], expect=2)
    assert not (judge / "judged").exists()
    log = (judge / "launch.log").read_text()
    assert "stop rule could not be read" in log and "stop rule: stop" not in log
