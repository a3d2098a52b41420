"""Peak memory and per-window latency of streaming reconstruction (d4rt.reconstruction.streaming) on a
stream and on one 10x longer: memory must not grow with the stream's length.

    python benchmarks/bench_stream.py [--frames 48] [--factor 10] [--size 128x96] [--depth-resolution 32x24]

Each length runs in a fresh process (peak RSS, ``ru_maxrss``, only grows within a process), pushing the
frames of a rendered clip, cycled, one at a time into the bundled model's stream, with depth maps decoded
per frame. Prints frames, windows, peak RSS and latency per window for both, and the memory ratio.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys

import numpy as np


def one_run(frames: int, height: int, width: int, depth_size: tuple[int, int]) -> dict:
    import torch

    from d4rt.model import D4RT
    from d4rt.reconstruction.streaming import StreamingReconstruction
    from d4rt.synthetic import render_clip

    model = D4RT.from_pretrained()
    clip = render_clip(0, 24, height, width).rgb
    stream = StreamingReconstruction.from_model(model, depth_size=depth_size)
    latencies = []
    with torch.inference_mode():
        for i in range(frames):
            latencies += [r.seconds for r in stream.push(clip[i % len(clip)])]
        latencies += [r.seconds for r in stream.finish()]
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kilobytes
    return {"frames": frames, "windows": len(latencies), "peak_rss_mb": peak_mb,
            "latency_median_s": float(np.median(latencies)), "latency_max_s": float(np.max(latencies))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--factor", type=int, default=10)
    parser.add_argument("--size", default="128x96", help="WIDTHxHEIGHT of the frames")
    parser.add_argument("--depth-resolution", default="32x24", help="WIDTHxHEIGHT of the depth maps per frame")
    parser.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)  # a child run
    args = parser.parse_args()
    from d4rt.cli import parse_size

    height, width = parse_size(args.size, "--size")
    depth_size = parse_size(args.depth_resolution, "--depth-resolution")
    if args.one is not None:
        print(json.dumps(one_run(args.one, height, width, depth_size)))
        return
    results = []
    for frames in (args.frames, args.frames * args.factor):
        child = subprocess.run([sys.executable, __file__, "--one", str(frames), "--size", args.size,
                                "--depth-resolution", args.depth_resolution], capture_output=True, text=True,
                               check=True)
        result = json.loads(child.stdout.strip().splitlines()[-1])
        results.append(result)
        print(f"{result['frames']:5d} frames of {width}x{height}, {result['windows']:3d} windows: peak RSS "
              f"{result['peak_rss_mb']:.0f} MB; latency per window {result['latency_median_s']:.2f} s median, "
              f"{result['latency_max_s']:.2f} s max")
    print(f"peak memory, {args.factor}x longer stream: {results[1]['peak_rss_mb'] / results[0]['peak_rss_mb']:.3f}x")


if __name__ == "__main__":
    main()
