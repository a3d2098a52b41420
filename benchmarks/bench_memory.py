"""Peak memory of decoding many queries and of dense tracking, over what the loaded model already holds.

    python benchmarks/bench_memory.py [--queries 1000000] [--out results.json]

One process, the bundled model, a rendered 24-frame 64x64 clip encoded once. Each figure is the peak
resident set (VmHWM, reset through /proc/self/clear_refs before each part, Linux) minus the resident set
just before the part (model, clip, Python and torch): what the part itself adds.

- ``query``: ``EncodedScene.query`` of N random queries at the default chunk size (the answers, float32,
  13 values per query, are part of what it must hold: 52 MB at 1M).
- ``reconstruction``: the same queries through the reconstruction layer (``ask_in_chunks``: float64 numpy
  answers of the 7 values the recipes use).
- ``dense``: what a user runs, ``Reconstruction.from_model(model, video).dense_tracks((128, 128))``
  (Alg. 1, the occupancy grid) on synthetic-dynamic-v1's clip_00 (24 frames of 128x128) with the bundled
  model. (``d4rt bench``'s dense part is larger: it also records the exact oracle's answers to steer a
  random-weight model.)
Issue 15's targets: query <= 200 MiB over the loaded model at 1M queries; dense tracking <= 500 MiB.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch


def resident_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc/self/status (Linux only)")


def part(fn) -> dict:
    from d4rt.speed.timing import peak_rss_bytes, reset_peak_memory

    before = resident_bytes()
    if not reset_peak_memory(torch.device("cpu")):
        raise SystemExit("cannot reset the resident-set peak (/proc/self/clear_refs): Linux only")
    result = fn()
    peak = peak_rss_bytes()
    return {"before_mib": before / 2**20, "peak_mib": peak / 2**20, "added_mib": (peak - before) / 2**20}, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=1_000_000)
    parser.add_argument("--out", type=Path, help="write the figures as JSON here")
    args = parser.parse_args()

    from d4rt.model import D4RT
    from d4rt.reconstruction.reconstruction import ask_in_chunks
    from d4rt.evaluation.synthetic_benchmark import FRAMES, clip_specs
    from d4rt.reconstruction import Reconstruction
    from d4rt.synthetic import render_clip

    torch.set_grad_enabled(False)
    model = D4RT.from_pretrained()
    clip = render_clip(0, 24, 64, 64)
    scene = model.encode(clip.rgb)
    rng = np.random.default_rng(0)
    n = args.queries
    queries = np.concatenate([rng.random((n, 2)), rng.integers(0, 24, (n, 3))], 1)
    tensor = torch.from_numpy(queries).float()
    scene.query(tensor[:4096])  # keys/values cached, allocator warmed: not counted as the part's own
    figures = {"queries": n, "chunk_size": model.config.query_chunk_size}
    # Dense tracking first: it must not inherit what the allocator keeps from the 1M-query parts.
    spec = clip_specs()[0]
    video = render_clip(spec.seed, FRAMES, spec.height, spec.width, **vars(spec.options)).rgb
    figures["dense"], dense = part(lambda: Reconstruction.from_model(model, video, progress=False).dense_tracks(
        (spec.height, spec.width)))
    figures["dense"].update(clip=spec.name, grid=[spec.height, spec.width], tracks=len(dense.sources),
                            queries=dense.num_queries, coverage=dense.coverage)
    del dense
    figures["query"], out = part(lambda: scene.query(tensor))
    del out
    figures["reconstruction"], out = part(lambda: ask_in_chunks(scene, queries, 1 << 16))
    del out
    for name in ("dense", "query", "reconstruction"):
        f = figures[name]
        print(f"{name:<15} peak {f['peak_mib']:7.0f} MiB, {f['added_mib']:+7.0f} MiB over the {f['before_mib']:.0f} MiB "
              "held before it")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
