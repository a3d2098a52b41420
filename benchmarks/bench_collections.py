"""Wall time of `d4rt reconstruct` over a collection of videos: one process vs. N processes under torchrun
(gloo on CPU, NCCL on GPUs), the same generated videos and options, and a check that both wrote the same
arrays.

    python benchmarks/bench_collections.py [--videos 8] [--frames 12] [--size 96x72] [--processes 2]

Prints one line per run (processes, wall seconds, videos per minute) and the speed-up. Each process loads
the model once; on a CPU the processes share its cores, so set ``OMP_NUM_THREADS`` (default here: cores /
processes) to keep them from oversubscribing.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from d4rt.cli import parse_size
from d4rt.io.video import write_video
from d4rt.synthetic import render_clip

OPTIONS = ["--outputs", "npz,tum", "--resolution", "encoder", "--tracks", "8", "--no-progress"]


def timed(command: list[str], env: dict) -> float:
    start = time.perf_counter()
    run = subprocess.run(command, capture_output=True, text=True, env=env)
    if run.returncode != 0:
        raise SystemExit(f"failed: {' '.join(command)}\n{run.stdout[-2000:]}{run.stderr[-2000:]}")
    return time.perf_counter() - start


def same_arrays(a: Path, b: Path) -> bool:
    for folder in sorted(p for p in a.iterdir() if p.is_dir()):
        x, y = np.load(folder / "reconstruction.npz"), np.load(b / folder.name / "reconstruction.npz")
        if any(not np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind == "f") for k in x.files):
            return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--videos", type=int, default=8)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--size", default="96x72", help="WIDTHxHEIGHT of the generated videos")
    parser.add_argument("--processes", type=int, default=2)
    args = parser.parse_args()
    height, width = parse_size(args.size, "--size")
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        videos = Path(tmp) / "videos"
        for i in range(args.videos):
            write_video(videos / f"clip{i:03d}.mp4", render_clip(i, args.frames, height, width).rgb, fps=10)
        base = [sys.executable, "-m", "d4rt", "reconstruct", str(videos)]
        launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
                    str(args.processes), "-m", "d4rt", "reconstruct", str(videos)]
        runs = []
        for processes, command in ((1, base), (args.processes, launcher)):
            threads = os.environ.get("OMP_NUM_THREADS", str(max(1, cores // processes)))
            out = Path(tmp) / f"out-{processes}"
            seconds = timed(command + ["-o", str(out), *OPTIONS], {**os.environ, "OMP_NUM_THREADS": threads})
            runs.append((processes, seconds, out))
            print(f"{processes} process(es) x {threads} thread(s): {seconds:.1f} s for {args.videos} videos of "
                  f"{args.frames} frames {width}x{height} ({60 * args.videos / seconds:.1f} videos/min)")
        (_, one, out1), (n, many, outn) = runs
        print(f"speed-up with {n} processes: {one / many:.2f}x on {cores} cores; same arrays: {same_arrays(out1, outn)}")


if __name__ == "__main__":
    main()
