"""Decoder throughput by chunk size and CPU thread count, side by side in one process: the measurement
behind the CPU defaults (chunks of the preset's ``query_chunk_size``, 4,096 for tiny; torch's thread
count, one per core).

    python benchmarks/bench_threads.py [--queries 100000] [--chunks 256,1024,4096,16384] [--dtype bf16]

The bundled model encodes a rendered 24-frame 64x64 clip once; N random queries are decoded at each
(chunk, threads) pair, best of --repeats, pairs interleaved so machine load hits all alike. Prints
queries per second per pair and each chunk's speed-up from 1 thread to the most.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import time
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=100_000)
    parser.add_argument("--chunks", default="256,1024,4096,16384")
    parser.add_argument("--threads", default=None, help="thread counts, comma-separated (default: 1 and all cores)")
    parser.add_argument("--dtype", choices=("fp32", "bf16"), default="bf16")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()

    from d4rt.model import D4RT
    from d4rt.synthetic import render_clip

    chunks = [int(c) for c in args.chunks.split(",")]
    threads = [int(t) for t in args.threads.split(",")] if args.threads else sorted({1, os.cpu_count() or 1})
    torch.set_grad_enabled(False)
    model = D4RT.from_pretrained()
    autocast = (torch.autocast("cpu", dtype=torch.bfloat16) if args.dtype == "bf16" else contextlib.nullcontext())
    rng = np.random.default_rng(0)
    queries = torch.from_numpy(np.concatenate([rng.random((args.queries, 2)), rng.integers(0, 24, (args.queries, 3))],
                                              1)).float()
    with autocast:
        scene = model.encode(render_clip(0, 24, 64, 64).rgb)
        scene.query(queries[:4096])  # keys/values cached, allocator warm
        best = {}
        for _ in range(args.repeats):
            for chunk in chunks:
                for n in threads:
                    torch.set_num_threads(n)
                    start = time.perf_counter()
                    scene.query(queries, chunk_size=chunk)
                    rate = args.queries / (time.perf_counter() - start)
                    best[(chunk, n)] = max(best.get((chunk, n), 0.0), rate)
    print(f"{args.queries:,} queries, {args.dtype}, {os.cpu_count()} logical cores; queries/s (best of {args.repeats})")
    print(f"{'chunk':>7} " + " ".join(f"{f'{n} thread(s)':>13}" for n in threads) + "   most vs 1")
    for chunk in chunks:
        row = [best[(chunk, n)] for n in threads]
        print(f"{chunk:>7} " + " ".join(f"{r:>13,.0f}" for r in row) + f"   {row[-1] / row[0]:.2f}x")
    if args.out:
        args.out.write_text(json.dumps({"queries": args.queries, "dtype": args.dtype, "cores": os.cpu_count(),
                                        "queries_per_s": {f"{c}x{n}": r for (c, n), r in best.items()}}, indent=2) + "\n")


if __name__ == "__main__":
    main()
