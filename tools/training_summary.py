"""What a finished ``d4rt train`` run did, as JSON for the model card, read from the run directory.

    python tools/training_summary.py /work/runs/ship-tiny --log /work/runs/ship-tiny.log \\
        --out docs/model-card/training.json --copy-metrics docs/model-card/metrics.jsonl

Reads the newest checkpoint's ``trainer.json`` (step, samples consumed, the training config), the
run's ``metrics.jsonl`` (throughput of every logged window) and the model's ``config.json``, and
records the machine this script runs on (run it where the training ran), or the one a GPU lease's snapshot
describes in ``hardware.json``. Times:

- ``training_seconds``: the sum of the logged windows (optimiser steps and data loading), which the
  trainer measures without validation and checkpoint writes;
- ``wall_seconds``: from ``train_config.yaml`` (written when the run started; rewritten by a resume, so
  then it is the time since the last resume, and ``resumed`` says so, from the console output ``--log``)
  to the newest checkpoint.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from pathlib import Path

import torch
import yaml

from d4rt.devices import cpu_name
from d4rt.model import D4RT
from d4rt.training.checkpoint import latest_checkpoint
from d4rt.training.logger import read_metrics, training_seconds


def hardware(run: Path, config: dict) -> dict:
    """The machine the run trained on: ``run/hardware.json`` where the run brought one (a GPU lease's snapshot,
    benchmarks/gpu_session.sh, written on the GPU machine), else this machine's, so run it where the training ran."""
    written = run / "hardware.json"
    if written.exists():
        return {**json.loads(written.read_text()), "device": config["run"]["device"]}
    return {"cpu": cpu_name(), "logical_cpus": os.cpu_count(), "device": config["run"]["device"],
            "torch": torch.__version__, "torch_threads": torch.get_num_threads()}


def summarise(run: Path, log: Path | None = None) -> dict:
    checkpoint = latest_checkpoint(run / "checkpoints")
    records = read_metrics(run)
    if checkpoint is not None:
        trainer = json.loads((checkpoint / "trainer.json").read_text())
        config, step, samples, written = trainer["config"], trainer["step"], trainer["next_sample"], checkpoint
    else:  # a run brought back without its checkpoints (the sixth GPU lease): its final weights, config and log
        config = yaml.safe_load((run / "train_config.yaml").read_text())
        if any(r.get("skipped_steps") for r in records):
            raise SystemExit(f"{run}: no checkpoint, and the log counts skipped steps: its samples cannot be known")
        step, written = records[-1]["step"], run
        samples = step * config["data"]["batch_size"] * config["run"]["grad_accum"]  # one process, as a lease
    model = D4RT.from_pretrained(written)
    batch = config["data"]["batch_size"] * config["run"]["grad_accum"]  # clips per optimiser step
    dataset = config["data"]["dataset"]
    return {
        "preset": config["model"]["preset"],
        "parameters": model.parameter_counts()["total"],
        "max_frames": model.config.max_frames,
        "steps": step,
        "clips_seen": samples,
        "clips_per_step": batch,
        "frames_per_clip": dataset["frames"],
        "input_size": dataset["size"],
        "queries_per_clip": dataset["sampler"]["num_queries"],
        "training_seconds": training_seconds(records, batch),
        "wall_seconds": (written / ("trainer.json" if checkpoint else "model.safetensors")).stat().st_mtime
        - (run / "train_config.yaml").stat().st_mtime,
        "resumed": log is not None and "resumed from" in log.read_text(errors="replace"),
        "hardware": hardware(run, config),
        "config": config,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="the run directory of d4rt train")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write")
    parser.add_argument("--log", type=Path, help="the console output of d4rt train (tells whether it resumed)")
    parser.add_argument("--copy-metrics", type=Path, help="also copy the run's metrics.jsonl here")
    parser.add_argument("--starts-from", metavar="TEXT",
                        help="what the run's model.init_from weights were, in words for the model card (default: "
                             "the previous stage's weights)")
    args = parser.parse_args()
    summary = summarise(args.run, args.log)
    if args.starts_from:
        summary["starts_from"] = args.starts_from
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=1) + "\n")
    if args.copy_metrics:
        shutil.copyfile(args.run / "metrics.jsonl", args.copy_metrics)
    print(f"{summary['preset']}: {summary['steps']} steps, {summary['clips_seen']} clips, "
          f"{summary['training_seconds'] / 60:.1f} min training, {summary['wall_seconds'] / 60:.1f} min wall")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
