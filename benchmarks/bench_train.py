"""Training throughput: the real trainer (data loading, forward, loss, backward, AdamW) for a few steps.

    python benchmarks/bench_train.py                                   # tiny on CPU
    python benchmarks/bench_train.py --compare --pool POOL             # CPU set-ups side by side, one run
    python benchmarks/bench_train.py --profile --pool POOL             # where one step's time goes (--device
                                                                       # cuda: the model on the GPU, CUDA kernels)
    python benchmarks/bench_train.py --compile                         # eager vs torch.compile, same batches
    python benchmarks/bench_train.py --pool POOL --freeze 'encoder.*'  # the readout alone (stage 152)
    python benchmarks/bench_train.py --pool POOL --tubelet-frames 1    # one encoder token per frame (stage 154)
    python benchmarks/bench_train.py --pool POOL --tubelet-stride 1    # overlapping two-frame tubelets (stage 155)
    python benchmarks/bench_train.py --pool POOL --muon 'encoder.blocks.*' 'decoder.blocks.*'  # Muon (stage 156)
    python benchmarks/bench_train.py --preset base --frames 48 --size 256 --queries 2048 --device cuda
    torchrun --nproc_per_node 8 benchmarks/bench_train.py --preset giant --frames 48 --size 256 \\
        --queries 2048 --strategy fsdp --checkpointing                   # the paper's setting

Prints steps/s, clips/s and queries/s measured after a warm-up, and the peak GPU memory per process on
CUDA. ``--compare`` runs, one after the other in this process, the ways a CPU run can be set up: clips
rendered on the fly by loader workers (which compete with training for the cores) or read from a
pre-rendered pool (``d4rt generate``), fp32 or bf16 autocast, and the torch thread count; every ratio in
its table is taken in the same run. ``--profile`` times the parts of one step (data, forward, loss,
backward, optimiser) with torch's profiler. ``--compile`` times the model's step (forward, loss, backward,
AdamW) on the same pre-loaded batches eager and under ``torch.compile``, and the compilation itself.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import torch

from d4rt.training import TrainConfig, train


def build_config(args, **changes) -> TrainConfig:
    source = changes.get("source", "render")
    dataset = {"frames": args.frames, "size": [args.size, args.size],
               "render_pixels": args.render_pixels or (args.size * 3 // 2) ** 2,
               "sampler": {"num_queries": args.queries}, "augment": {"crop_policy": args.crop_policy}}
    if source == "files":
        dataset.update(source="files", directory=str(args.pool))
    return TrainConfig.from_dict({
        "model": {"preset": args.preset, "overrides": {"gradient_checkpointing": args.checkpointing,
                                                      **({"tubelet_frames": args.tubelet_frames}
                                                         if args.tubelet_frames else {}),
                                                      **({"tubelet_stride": args.tubelet_stride}
                                                         if args.tubelet_stride else {})}},
        "data": {"batch_size": args.batch_size, "workers": changes.get("workers", args.workers), "dataset": dataset},
        "optim": {"warmup_steps": 1, "freeze": args.freeze, "muon": args.muon},
        "run": {"max_steps": args.steps, "grad_accum": args.grad_accum, "device": args.device,
                "precision": changes.get("precision", args.precision), "strategy": args.strategy,
                "log_every": args.warmup, "checkpoint_every": 10 ** 9, "tensorboard": False, "progress": False},
    })


def measure(config: TrainConfig, warmup: int) -> float:
    """Clips per second over the steps after ``warmup`` (the trainer's own training-time throughput)."""
    with tempfile.TemporaryDirectory() as out:
        train(config, out)
        if os.environ.get("RANK", "0") != "0":
            return float("nan")
        records = [json.loads(line) for line in (Path(out) / "metrics.jsonl").read_text().splitlines()]
    measured = [r for r in records if r["step"] > warmup and "throughput/clips_per_s" in r]
    return sum(r["throughput/clips_per_s"] for r in measured) / len(measured)


# name -> (source, workers, precision, torch threads); None keeps this process's setting.
CPU_SETUPS = {
    "render, 2 workers, fp32, 2 threads": ("render", 2, "fp32", 2),
    "render, 1 worker, fp32, 2 threads": ("render", 1, "fp32", 2),
    "render, 1 worker, fp32, 1 thread": ("render", 1, "fp32", 1),
    "render, 1 worker, bf16, 2 threads": ("render", 1, "bf16", 2),
    "render, 1 worker, bf16, 1 thread": ("render", 1, "bf16", 1),
    "pool, 0 workers, fp32, 2 threads": ("files", 0, "fp32", 2),
    "pool, 1 worker, fp32, 2 threads": ("files", 1, "fp32", 2),
    "pool, 1 worker, bf16, 2 threads": ("files", 1, "bf16", 2),
    "pool, 0 workers, bf16, 1 thread": ("files", 0, "bf16", 1),
}


def compare(args) -> None:
    rows = []
    for name, (source, workers, precision, threads) in CPU_SETUPS.items():
        torch.set_num_threads(threads)
        clips = measure(build_config(args, source=source, workers=workers, precision=precision), args.warmup)
        rows.append((name, clips / args.batch_size))
        print(f"  {name}: {rows[-1][1]:.2f} steps/s", flush=True)
    base = rows[0][1]
    print(f"\n{args.preset}: {args.frames} frames at {args.size}x{args.size}, {args.queries} queries/clip, "
          f"{args.steps} steps ({args.warmup} left out), {os.cpu_count()} CPUs")
    print("| set-up | steps/s | vs first |\n|---|---|---|")
    for name, rate in rows:
        print(f"| {name} | {rate:.2f} | {rate / base:.2f}x |")


def profile(args) -> None:
    """Time of each part of a training step, from the profiler's record_function ranges."""
    from d4rt.model import D4RT
    from d4rt.training.losses import d4rt_loss
    from d4rt.training.optimization import build_optimizer

    config = build_config(args, source="files" if args.pool else "render", workers=0)
    model_config = config.validate()
    device = torch.device("cuda" if args.device in ("auto", "cuda") and torch.cuda.is_available() else
                          "cpu" if args.device == "auto" else args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit(f"bench_train: --device {args.device} asked for but CUDA is not available on this machine")
    model = D4RT(model_config).train().to(device)
    optimizer = build_optimizer(model, config.optim)
    dataset = config.data.build_dataset()  # rendered on the CPU, in this process: the data row is one core's
    bf16 = config.run.precision == "bf16" or (config.run.precision == "auto" and device.type == "cuda")
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16)
    parts: dict[str, float] = {}

    def timed(name, fn):  # on a GPU each part is waited for, so its row is its own kernels' time
        start = time.perf_counter()
        value = fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        parts[name] = parts.get(name, 0.0) + time.perf_counter() - start
        return value

    def step(index: int) -> None:
        batch = timed("data (load, sample, oracle, augment)",
                      lambda: {k: v[None].to(device) for k, v in dataset[index % len(dataset)].items()})
        with autocast:
            out = timed("forward (encoder + decoder)",
                        lambda: model(batch["video"], batch["queries"], batch["aspect_ratio"]))
        loss, _ = timed("loss", lambda: d4rt_loss(out, batch, config.loss))
        timed("backward", loss.backward)
        timed("optimiser (clip + AdamW)", lambda: (torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0),
                                                   optimizer.step(), optimizer.zero_grad(set_to_none=True)))

    for i in range(args.warmup):
        step(i)
    parts.clear()
    activities = [torch.profiler.ProfilerActivity.CPU]
    if device.type == "cuda":
        activities.append(torch.profiler.ProfilerActivity.CUDA)
    with torch.profiler.profile(activities=activities) as prof:
        for i in range(args.warmup, args.steps):
            step(i)
    total = sum(parts.values())
    n = args.steps - args.warmup
    print(f"{args.preset}, {args.frames} frames at {args.size}, {args.queries} queries, {device}, "
          f"{'bf16' if bf16 else 'fp32'}, {torch.get_num_threads()} threads: {total / n * 1000:.0f} ms per step")
    for name, seconds in parts.items():
        print(f"  {name:40s} {seconds / n * 1000:7.1f} ms  {seconds / total:6.1%}")
    sort = "self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total"
    print(prof.key_averages().table(sort_by=sort, row_limit=args.profile_rows))


def compile_compare(args) -> None:
    """Steps/s of the model's training step, eager and under torch.compile, on the same pre-loaded batches (data
    loading left out, as it is a loader worker's in a real run), and the seconds the first compiled step took."""
    import copy

    from d4rt.model import D4RT
    from d4rt.training.losses import d4rt_loss
    from d4rt.training.optimization import build_optimizer

    config = build_config(args, source="files" if args.pool else "render", workers=0)
    dataset = config.data.build_dataset()
    batches = [{k: v[None] for k, v in dataset[i].items()} for i in range(args.steps - args.warmup)]
    device = "cuda" if args.device in ("auto", "cuda") and torch.cuda.is_available() else "cpu"
    batches = [{k: v.to(device) for k, v in b.items()} for b in batches]
    autocast = torch.autocast(device, dtype=torch.bfloat16, enabled=args.precision == "bf16")
    torch.manual_seed(0)
    start_model = D4RT(config.validate()).train().to(device)
    rates = {}
    for mode in ("eager", "torch.compile"):
        model = copy.deepcopy(start_model)
        optimizer = build_optimizer(model, config.optim)
        forward = torch.compile(model) if mode == "torch.compile" else model

        def step(batch) -> None:
            with autocast:
                out = forward(batch["video"], batch["queries"], batch["aspect_ratio"])
            loss, _ = d4rt_loss(out, batch, config.loss)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)

        first = time.perf_counter()
        step(batches[0])  # compiles (once per input shape)
        first = time.perf_counter() - first
        begin = time.perf_counter()
        for batch in batches[1:]:
            step(batch)
        if device == "cuda":
            torch.cuda.synchronize()
        rates[mode] = (len(batches) - 1) / (time.perf_counter() - begin)
        print(f"  {mode}: {rates[mode]:.2f} steps/s, first step {first:.1f} s", flush=True)
    print(f"{args.preset}, {args.frames} frames at {args.size}x{args.size}, {args.queries} queries, {args.precision}, "
          f"{device}, {torch.get_num_threads()} threads: torch.compile {rates['torch.compile'] / rates['eager']:.2f}x eager")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--size", type=int, default=64, help="encoder input side (the preset's image_size or less)")
    parser.add_argument("--queries", type=int, default=1024)
    parser.add_argument("--render-pixels", type=int, default=None, help="pixels per rendered frame "
                        "(default: 1.5 x the input side, squared)")
    parser.add_argument("--crop-policy", default="paper", choices=["paper", "centered", "none"])
    parser.add_argument("--batch-size", type=int, default=1, help="clips per process per step")
    parser.add_argument("--grad-accum", type=int, default=1, help="micro-batches per optimiser step (run.grad_accum)")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--warmup", type=int, default=10, help="steps left out of the measurement")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--precision", default="auto", choices=["auto", "fp32", "bf16"])
    parser.add_argument("--strategy", default="auto", choices=["auto", "single", "ddp", "fsdp"])
    parser.add_argument("--checkpointing", action="store_true", help="activation checkpointing")
    parser.add_argument("--tubelet-frames", type=int, default=None,
                        help="frames per encoder token (default: the preset's; 1: one token per frame, stage 154)")
    parser.add_argument("--tubelet-stride", type=int, default=None,
                        help="frames between tubelet starts (default: the tubelet's frames; 1: overlapping two-frame "
                             "tubelets, stage 155)")
    parser.add_argument("--freeze", nargs="+", default=[], metavar="PATTERN",
                        help="optim.freeze: parameter-name patterns that do not train, e.g. 'encoder.*'")
    parser.add_argument("--muon", nargs="+", default=[], metavar="PATTERN",
                        help="step the 2-D weights these parameter-name patterns match with Muon (optim.muon)")
    parser.add_argument("--pool", type=Path, default=None, help="d4rt generate output (for --compare / --profile)")
    parser.add_argument("--compare", action="store_true", help="CPU set-ups side by side (needs --pool)")
    parser.add_argument("--profile", action="store_true", help="time the parts of a step")
    parser.add_argument("--profile-rows", type=int, default=15)
    parser.add_argument("--compile", action="store_true", help="eager vs torch.compile on the same batches")
    args = parser.parse_args()
    if args.compile:
        if args.steps - args.warmup < 2:
            parser.error("--compile needs --steps at least --warmup + 2 (one step to compile, one or more to time)")
        return compile_compare(args)
    if args.compare:
        if args.pool is None:
            parser.error("--compare needs --pool (a d4rt generate directory)")
        return compare(args)
    if args.profile:
        return profile(args)

    if torch.cuda.is_available():
        torch.cuda.reset_peak_memory_stats()
    clips = measure(build_config(args, source="files" if args.pool else "render"), args.warmup)
    if os.environ.get("RANK", "0") != "0":
        return
    world = int(os.environ.get("WORLD_SIZE", "1"))
    print(f"{args.preset}: {args.frames} frames at {args.size}x{args.size}, {args.queries} queries/clip, "
          f"batch {args.batch_size} x {world} process(es), {args.strategy}, {args.precision}"
          + (f", frozen {' '.join(args.freeze)}" if args.freeze else "")
          + (f", {args.tubelet_frames}-frame tubelets" if args.tubelet_frames else "")
          + (f", a tubelet every {args.tubelet_stride} frame(s)" if args.tubelet_stride else "")
          + (f", {args.grad_accum} micro-batches a step" if args.grad_accum > 1 else "")
          + (f", Muon for {' '.join(args.muon)}" if args.muon else ""))
    steps = clips / (args.batch_size * world * args.grad_accum)
    print(f"  {steps:.2f} steps/s   {clips:.2f} clips/s   {clips * args.queries:,.0f} queries/s")
    if torch.cuda.is_available():
        print(f"  peak GPU memory (rank 0): {torch.cuda.max_memory_allocated() / 2**30:.2f} GiB")


if __name__ == "__main__":
    main()
