"""`d4rt reconstruct` of this tree against an older tree, side by side in one run: wall time and peak memory
with each tree's default outputs, and how far the new answers are from the old fp32 ones.

    git worktree add --detach /tmp/d4rt-old 9974330     # the code issue 15 starts from
    python benchmarks/bench_reconstruct.py --old /tmp/d4rt-old [--frames 48] [--size 128x128] [--repeats 2]

Both trees run the same checkpoint (default: this tree's bundled model) on the same rendered clip, each as
a fresh `python -m d4rt reconstruct` process with that tree's `src` first on PYTHONPATH, alternating old
and new so a change in machine load hits both alike. Time is the process's wall time (imports, decoding
the input, writing every file); peak memory its maximum resident set (wait4's ru_maxrss).

Answers: the new code run in float32 with the old code's output choices (per-frame cameras with fx != fy,
the point cloud from direct queries) must give the old arrays (relative error ~1e-7); the new defaults
(bf16 autocast where the CPU has it natively) are compared with the new float32 run of the same options.
Error = ||new - old|| / ||old|| over each array of reconstruction.npz (finite entries). Prints a table and
writes JSON (--out). Name the CPU with the figures: it is printed first.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
OLD_CHOICES = ["--camera", "per-frame", "--non-square-pixels", "--points-from", "queries"]
COMPARED = ("depth", "confidence", "intrinsics", "video_intrinsics", "cam_to_world", "points", "point_confidence",
            "tracks", "track_visibility", "track_uv")


def cpu_name() -> str:
    from d4rt.devices import cpu_name as model_name

    return f"{model_name()}, {os.cpu_count()} logical cores"


def run_tree(tree: Path, video: Path, out: Path, checkpoint: Path, extra: list[str]) -> dict:
    """One `d4rt reconstruct` process of ``tree``: wall seconds and peak resident MiB."""
    env = dict(os.environ, PYTHONPATH=str(tree / "src"))
    command = [sys.executable, "-m", "d4rt", "reconstruct", str(video), "-o", str(out), "--checkpoint",
               str(checkpoint), *extra]
    start = time.perf_counter()
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    output = process.stdout.read()
    _, status, usage = os.wait4(process.pid, 0)  # reaped here, not by Popen, to get the child's own rusage
    process.returncode = os.waitstatus_to_exitcode(status)
    seconds = time.perf_counter() - start
    if process.returncode:
        raise SystemExit(f"{tree}: d4rt reconstruct failed:\n{output[-2000:]}")
    return {"seconds": seconds, "peak_mib": usage.ru_maxrss / 1024}  # Linux: kilobytes


def relative_errors(new: Path, old: Path) -> dict:
    a, b = np.load(new / "reconstruction.npz"), np.load(old / "reconstruction.npz")
    errors = {}
    for key in COMPARED:
        x, y = a[key].astype(np.float64), b[key].astype(np.float64)
        if x.shape != y.shape:
            errors[key] = f"shapes differ: {x.shape} vs {y.shape}"
            continue
        ok = np.isfinite(x) & np.isfinite(y)
        errors[key] = float(np.linalg.norm((x - y)[ok]) / max(np.linalg.norm(y[ok]), 1e-30))
    return errors


def render_video(path: Path, frames: int, height: int, width: int, seed: int) -> None:
    from d4rt.synthetic import render_clip

    np.save(path, render_clip(seed, frames, height, width).rgb)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", required=True, type=Path, help="root of the older tree (a git worktree)")
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--size", default="128x128", help="WIDTHxHEIGHT of the clip")
    parser.add_argument("--seed", type=int, default=7, help="seed of the rendered clip")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs of each tree (default 2)")
    parser.add_argument("--checkpoint", type=Path, default=HERE / "src/d4rt/assets/d4rt-tiny")
    parser.add_argument("--out", type=Path, help="write the figures as JSON here")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE / "src"))
    from d4rt.cli import parse_size

    height, width = parse_size(args.size, "--size")
    work = Path(tempfile.mkdtemp(prefix="bench-reconstruct-"))
    try:
        video = work / "video.npy"
        render_video(video, args.frames, height, width, args.seed)
        print(f"CPU: {cpu_name()}; clip: {args.frames} frames of {width}x{height}; checkpoint {args.checkpoint}")
        runs = {"old": [], "new": []}
        for r in range(args.repeats):
            for name, tree in (("old", args.old), ("new", HERE)):
                out = work / f"{name}-{r}"
                runs[name].append(run_tree(tree, video, out, args.checkpoint, []))
                print(f"  {name} run {r + 1}: {runs[name][-1]['seconds']:.1f} s, peak {runs[name][-1]['peak_mib']:.0f} MiB")
                if r + 1 < args.repeats:
                    shutil.rmtree(out)
        # The answers: new fp32 with the old choices vs old; new defaults vs new fp32 of the same choices.
        run_tree(HERE, video, work / "new-fp32-old-choices", args.checkpoint, ["--dtype", "fp32", *OLD_CHOICES])
        run_tree(HERE, video, work / "new-fp32", args.checkpoint, ["--dtype", "fp32"])
        last = args.repeats - 1
        result = {
            "cpu": cpu_name(), "frames": args.frames, "size": [width, height], "checkpoint": str(args.checkpoint),
            "old_tree": str(args.old), "runs": runs,
            "old_seconds": float(np.median([r["seconds"] for r in runs["old"]])),
            "new_seconds": float(np.median([r["seconds"] for r in runs["new"]])),
            "old_peak_mib": float(max(r["peak_mib"] for r in runs["old"])),
            "new_peak_mib": float(max(r["peak_mib"] for r in runs["new"])),
            "fp32_vs_old": relative_errors(work / "new-fp32-old-choices", work / f"old-{last}"),
            "default_vs_fp32": relative_errors(work / f"new-{last}", work / "new-fp32"),
        }
        result["speedup"] = result["old_seconds"] / result["new_seconds"]
        print(f"\nd4rt reconstruct, default outputs: old {result['old_seconds']:.1f} s, new {result['new_seconds']:.1f} s "
              f"(median of {args.repeats}): {result['speedup']:.2f}x; peak memory old {result['old_peak_mib']:.0f} MiB, "
              f"new {result['new_peak_mib']:.0f} MiB")
        print(f"{'array':<18} {'new fp32 vs old':>16} {'default vs fp32':>16}")
        for key in COMPARED:
            a, b = result["fp32_vs_old"][key], result["default_vs_fp32"][key]
            print(f"{key:<18} {a if isinstance(a, str) else f'{a:.2e}':>16} {b if isinstance(b, str) else f'{b:.2e}':>16}")
        if args.out:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(result, indent=2) + "\n")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
