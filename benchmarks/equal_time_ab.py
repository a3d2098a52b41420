"""Two or more variants of one training config, each trained for the same wall-clock budget from the same start.

    python benchmarks/equal_time_ab.py --config configs/ship-tiny-cpu-stage40.yaml --minutes 25 --out RUNS \\
        --arm q1024 data.dataset.sampler.num_queries=1024 --arm q256 data.dataset.sampler.num_queries=256

Why (issue 14): a recipe that makes each clip cheaper (fewer queries, smaller frames) sees more clips per minute;
whether that teaches more per CPU-minute is only answered at equal time. Each arm (``--arm NAME KEY=VALUE ...``,
overrides as ``d4rt train --set`` takes them) runs one after the other on the same machine, so run it alone on an
idle one: first ``--calibration-steps`` steps in ``RUNS/NAME-calibration`` to measure its own speed (its logged
clips per second after the first logging window), then ``minutes x steps/s`` optimiser steps from the config's
``model.init_from`` in ``RUNS/NAME`` with the cosine's ``optim.decay_steps`` set to that count, so that each
arm's learning-rate schedule ends with its budget. An arm whose run is there unfinished is resumed (``--resume``);
a finished one is kept. An arm's ``threads=N`` (not a config key) runs it with N torch threads (default 1), e.g. an
arm whose loader has less to do (``data.dataset.echo=2``) giving the model the core it frees. Writes ``RUNS/arms.json`` (per arm: the overrides, calibrated steps/s, steps, the seconds
actually spent in optimiser steps) and prints a table. Judge the final weights (``RUNS/NAME``) afterwards, with
held-out probes (``tools/loss_probe.py``, ``tools/measure_focal.py --held-out``, ``tools/depth_probe.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from recipe_study import d4rt_train, steps_per_second  # noqa: E402

from d4rt.errors import UserError  # noqa: E402
from d4rt.training.logger import read_metrics, training_seconds  # noqa: E402


def train(config: Path, out: Path, steps: int, overrides: list[str], resume: bool = False) -> None:
    """``d4rt train`` for ``steps`` optimiser steps with ``overrides`` (``threads=N`` among them sets its torch
    threads); its log beside ``out``."""
    arguments = ["--config", str(config), "--out", str(out), "--max-steps", str(steps), "--no-progress"]
    threads = 1
    for item in overrides:
        if item.startswith("threads="):
            threads = int(item.partition("=")[2])
        else:
            arguments += ["--set", item]
    d4rt_train(arguments + (["--resume"] if resume else []), out.parent / f"{out.name}.log", append=True,
               threads=threads)


def finished(out: Path, steps: int) -> bool:
    """Whether the run in ``out`` checkpointed its last step (a run stopped early checkpoints an earlier one)."""
    return (out / "checkpoints" / f"step-{steps:08d}").is_dir()


def run_arm(name: str, overrides: list[str], args: argparse.Namespace, clips_per_step: int) -> dict:
    calibration = args.out / f"{name}-calibration"
    if not finished(calibration, args.calibration_steps):
        train(args.config, calibration, args.calibration_steps,
              overrides + ["run.log_every=10", f"run.checkpoint_every={args.calibration_steps}", "validation.every=0"],
              resume=calibration.exists())
    rate = steps_per_second(calibration, skip=10) / clips_per_step
    steps = max(1, int(rate * args.minutes * 60))
    out = args.out / name
    arm_overrides = overrides + [f"optim.decay_steps={steps}"]
    if not finished(out, steps):
        train(args.config, out, steps, arm_overrides, resume=out.exists())
    result = {"name": name, "overrides": overrides, "calibrated_steps_per_s": rate, "steps": steps,
              "clips": steps * clips_per_step, "train_seconds": training_seconds(read_metrics(out), clips_per_step)}
    print(f"| {name} | {' '.join(overrides)} | {rate:.3f} | {steps} | {result['clips']} | "
          f"{result['train_seconds'] / 60:.1f} |", flush=True)
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, required=True, help="the training config every arm starts from")
    parser.add_argument("--out", type=Path, required=True, help="directory for the runs and arms.json")
    parser.add_argument("--minutes", type=float, required=True, help="the budget of optimiser steps per arm")
    parser.add_argument("--calibration-steps", type=int, default=60)
    parser.add_argument("--arm", nargs="+", action="append", required=True, metavar=("NAME", "KEY=VALUE"),
                        help="an arm: its name, then its overrides of the config (repeat for each arm)")
    args = parser.parse_args(argv)
    if args.minutes <= 0 or args.calibration_steps <= 20:
        parser.error("--minutes must be positive and --calibration-steps above 20 (the first window is skipped)")
    names = [arm[0] for arm in args.arm]
    if len(set(names)) != len(names) or len(names) < 2:
        parser.error(f"need at least two arms with distinct names, got {names}")
    for arm in args.arm:
        bad = [item for item in arm[1:] if "=" not in item]
        if bad:
            parser.error(f"arm {arm[0]}: overrides must be KEY=VALUE, got {bad}")
    config = yaml.safe_load(args.config.read_text())
    run = config.get("run", {})
    clips_per_step = int(run.get("grad_accum", 1)) * int(config.get("data", {}).get("batch_size", 1))
    print("| arm | overrides | steps/s | steps | clips | minutes in steps |\n|---|---|---|---|---|---|", flush=True)
    try:
        results = [run_arm(arm[0], arm[1:], args, clips_per_step) for arm in args.arm]
    except UserError as error:
        sys.exit(f"equal_time_ab.py: {error}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "arms.json").write_text(json.dumps({"config": str(args.config), "minutes": args.minutes,
                                                    "arms": results}, indent=1))


if __name__ == "__main__":
    main()
