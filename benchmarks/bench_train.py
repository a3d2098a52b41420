"""Training throughput: the real trainer (data loading, forward, loss, backward, AdamW) for a few steps.

    python benchmarks/bench_train.py                                   # tiny on CPU
    python benchmarks/bench_train.py --preset base --frames 48 --size 256 --queries 2048 --device cuda
    torchrun --nproc_per_node 8 benchmarks/bench_train.py --preset giant --frames 48 --size 256 \\
        --queries 2048 --strategy fsdp --checkpointing                   # the paper's setting

Prints steps/s, clips/s and queries/s measured after a warm-up (clips rendered on the fly by the data
workers, so a slow CPU shows up here), and the peak GPU memory per process on CUDA.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import torch

from d4rt.training import TrainConfig, train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--size", type=int, default=64, help="encoder input side (the preset's image_size or less)")
    parser.add_argument("--queries", type=int, default=512)
    parser.add_argument("--batch-size", type=int, default=1, help="clips per process per step")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=10, help="steps left out of the measurement")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--precision", default="auto", choices=["auto", "fp32", "bf16"])
    parser.add_argument("--strategy", default="auto", choices=["auto", "single", "ddp", "fsdp"])
    parser.add_argument("--checkpointing", action="store_true", help="activation checkpointing")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as out:
        config = TrainConfig.from_dict({
            "model": {"preset": args.preset, "overrides": {"gradient_checkpointing": args.checkpointing}},
            "data": {"batch_size": args.batch_size, "workers": args.workers,
                     "dataset": {"frames": args.frames, "size": [args.size, args.size],
                                 "render_pixels": (args.size * 3 // 2) ** 2,
                                 "sampler": {"num_queries": args.queries}}},
            "optim": {"warmup_steps": 1},
            "run": {"max_steps": args.steps, "device": args.device, "precision": args.precision,
                    "strategy": args.strategy, "log_every": args.warmup, "checkpoint_every": 10 ** 9,
                    "tensorboard": False, "progress": False},
        })
        if torch.cuda.is_available():
            torch.cuda.reset_peak_memory_stats()
        train(config, out)
        if os.environ.get("RANK", "0") != "0":
            return
        records = [json.loads(line) for line in (Path(out) / "metrics.jsonl").read_text().splitlines()]
    measured = [r for r in records if r["step"] > args.warmup]
    clips = sum(r["throughput/clips_per_s"] for r in measured) / len(measured)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    print(f"{args.preset}: {args.frames} frames at {args.size}x{args.size}, {args.queries} queries/clip, "
          f"batch {args.batch_size} x {world} process(es), {args.strategy}, {args.precision}")
    print(f"  {clips / (args.batch_size * world):.2f} steps/s   {clips:.2f} clips/s   {clips * args.queries:,.0f} queries/s")
    if torch.cuda.is_available():
        print(f"  peak GPU memory (rank 0): {torch.cuda.max_memory_allocated() / 2**30:.2f} GiB")


if __name__ == "__main__":
    main()
