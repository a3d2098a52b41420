"""Synthetic-clip generation speed: clips per second with full ground truth (RGB, depth, normals,
object ids, cameras, body poses), and the cost of a training sample (clip + 2,048 oracle queries).

    python benchmarks/bench_synthetic.py [--threads 1] [--device cpu] [--clips 10] [--json out.json]

The issue's target: at least 5 clips/s at 16x128x128 on one core. Figures depend on the scene drawn,
so each size is timed over several seeds and the mean is reported.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np
import torch

from d4rt.data import ClipQueryDataset, DatasetConfig
from d4rt.synthetic import render_clip


def time_clips(frames: int, height: int, width: int, clips: int, device: str) -> dict:
    render_clip(10_000, frames, height, width, device=device)  # warm-up
    times = []
    for seed in range(clips):
        start = time.perf_counter()
        render_clip(seed, frames, height, width, device=device)
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    t = np.array(times)
    return {"frames": frames, "height": height, "width": width, "clips": clips, "mean_s": float(t.mean()),
            "max_s": float(t.max()), "clips_per_s": float(1.0 / t.mean()),
            "pixels_per_s": float(frames * height * width / t.mean())}


def time_samples(samples: int) -> dict:
    ds = ClipQueryDataset(DatasetConfig(num_clips=samples + 1, frames=16, size=(128, 128)))
    ds[samples]  # warm-up
    start = time.perf_counter()
    for i in range(samples):
        ds[i]
    dt = (time.perf_counter() - start) / samples
    return {"samples": samples, "mean_s": dt, "samples_per_s": 1.0 / dt}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--device", default="cpu")
    p.add_argument("--clips", type=int, default=10)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    rows = [time_clips(16, 128, 128, args.clips, args.device),
            time_clips(48, 256, 256, max(2, args.clips // 4), args.device)]
    sample = time_samples(max(3, args.clips // 2)) if args.device == "cpu" else None
    where = f"{args.device}, {args.threads} thread(s), {platform.processor() or platform.machine()}"
    print(f"synthetic clips with full ground truth ({where})")
    print("| frames x H x W | clips/s | mean s/clip | max s/clip | Mpixel/s |")
    print("| --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['frames']}x{r['height']}x{r['width']} | {r['clips_per_s']:.2f} | {r['mean_s']:.3f} | "
              f"{r['max_s']:.3f} | {r['pixels_per_s'] / 1e6:.2f} |")
    if sample:
        print(f"training sample (16x128x128 video, render + augment + 2,048 oracle queries): "
              f"{sample['samples_per_s']:.2f} samples/s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"device": args.device, "threads": args.threads, "clips": rows, "training_sample": sample},
                      fh, indent=1)


if __name__ == "__main__":
    main()
