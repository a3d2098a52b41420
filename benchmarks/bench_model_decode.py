"""Query decoding speed: cached vs uncached scene keys/values, for a few chunk sizes.

    PYTHONPATH=src python benchmarks/bench_model_decode.py --preset tiny --frames 16 --queries 20000

Prints one line per setting: encode time once, then decode throughput (queries per second). The model is
randomly initialised: speed does not depend on the weights.
"""

from __future__ import annotations

import argparse
import time

import torch

from d4rt.config import D4RTConfig
from d4rt.model import D4RT


def timed(fn, repeats: int) -> float:
    """Best wall time of ``repeats`` runs (seconds), after one warm-up run."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        start = time.perf_counter()
        fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="tiny", choices=D4RTConfig.preset_names())
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--queries", type=int, default=20000)
    parser.add_argument("--chunks", type=int, nargs="+", default=[256, 1024, 4096])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--bf16", action="store_true", help="run under bf16 autocast")
    args = parser.parse_args()

    device = "cuda" if torch.cuda.is_available() else "cpu"
    config = D4RTConfig.preset(args.preset)
    model = D4RT(config).to(device).eval()
    frames = min(args.frames, config.max_frames)
    video = torch.randint(0, 256, (frames, 360, 640, 3), dtype=torch.uint8)
    queries = torch.cat([torch.rand(args.queries, 2), torch.randint(0, frames, (args.queries, 3)).float()], dim=1)
    autocast = torch.autocast(device, dtype=torch.bfloat16, enabled=args.bf16)

    with autocast:
        encode_s = timed(lambda: model.encode(video), args.repeats)
        scene = model.encode(video)
    print(f"device {device}, preset {args.preset}, {frames} frames, {scene.tokens.shape[1]} scene tokens, "
          f"bf16 {args.bf16}, threads {torch.get_num_threads()}")
    print(f"encode: {encode_s * 1e3:.1f} ms")
    for chunk in args.chunks:
        # Alternate the two settings so background load on a shared machine hits both alike.
        best = {True: float("inf"), False: float("inf")}
        for _ in range(args.repeats):
            for cache in (True, False):
                scene.clear_cache()
                with autocast:
                    best[cache] = min(best[cache], timed(
                        lambda: scene.query(queries, chunk_size=chunk, cache_kv=cache), 1))
        for cache in (True, False):
            print(f"decode chunk {chunk:>6} cache_kv {str(cache):>5}: {args.queries / best[cache]:>12,.0f} queries/s")

if __name__ == "__main__":
    main()
