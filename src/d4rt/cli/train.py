"""``d4rt train``: train a model from a YAML config, on one process or under torchrun."""

from __future__ import annotations

import argparse
import os

import yaml

from d4rt.errors import UserError
from d4rt.cli import COMMANDS


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "train", help=COMMANDS["train"],
        description="Train D4RT as a config file describes (configs/tiny-cpu.yaml, configs/small-gpu.yaml, "
                    "configs/paper-giant.yaml). Weights land in OUT as model.safetensors + config.json; "
                    "checkpoints in OUT/checkpoints. Several processes: torchrun --nproc_per_node N "
                    "-m d4rt train ...")
    parser.add_argument("--config", required=True, metavar="YAML", help="training config file")
    parser.add_argument("-o", "--out", default="runs/d4rt", metavar="DIR", help="run directory (default: runs/d4rt)")
    parser.add_argument("--max-steps", type=int, metavar="N", help="optimiser steps (overrides run.max_steps)")
    parser.add_argument("--resume", action="store_true",
                        help="continue from the newest complete checkpoint in DIR (start afresh if there is none)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config field, e.g. --set optim.lr=3e-4 (repeatable; VALUE is YAML)")
    parser.set_defaults(func=run)


def parse_overrides(items: list[str]) -> dict:
    """``["optim.lr=3e-4", ...]`` -> ``{"optim.lr": "3e-4"-as-YAML, ...}``."""
    overrides = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            overrides[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as err:
            raise UserError(f"--set {key}: value is not valid YAML: {' '.join(str(err).split())}") from None
    return overrides


def run(args) -> int:
    from d4rt.training import TrainConfig, train
    from d4rt.training.stop import exit_status

    overrides = parse_overrides(args.set)
    if args.max_steps is not None:
        if args.max_steps < 1:
            raise UserError(f"--max-steps must be at least 1, got {args.max_steps}")
        overrides["run.max_steps"] = args.max_steps
    config = TrainConfig.load(args.config, overrides)
    result = train(config, args.out, resume=args.resume)
    if result.stopped_by is not None:  # a checkpoint of this step was written
        if os.environ.get("RANK", "0") == "0":
            print(f"stopped at step {result.step} by {result.stopped_by}; continue with --resume")
        return exit_status(result.stopped_by)
    if os.environ.get("RANK", "0") == "0":
        print(f"trained to step {result.step}; weights in {result.out}")
    return 0
