"""Decoder throughput: queries/s per chunk size with and without the scene key/value cache, and the
gain of sharing the source embedding between queries that differ only in time (3D tracks)."""

from __future__ import annotations

import torch
from d4rt.progress import progress_bar

from d4rt.speed.flops import decoder_flops_per_query
from d4rt.speed.options import BenchOptions
from d4rt.speed.timing import time_once
from d4rt.model.encoded_scene import auto_chunk_size


def random_queries(n: int, frames: int, generator: torch.Generator) -> torch.Tensor:
    """``(n, 5)`` queries with (u, v) uniform in [0, 1] and independent uniform times in [0, frames)."""
    uv = torch.rand(n, 2, generator=generator)
    times = torch.randint(0, frames, (n, 3), generator=generator).float()
    return torch.cat([uv, times], 1)


def track_queries(sources: torch.Tensor, frames: int) -> torch.Tensor:
    """Full-video camera-frame tracks: ``sources (N, 3)`` [u, v, t_src] -> ``(N * frames, 5)`` queries,
    source-major, with t_tgt = t_cam = k for k = 0..frames-1 (paper Tab. 1)."""
    n = sources.shape[0]
    k = torch.arange(frames, dtype=sources.dtype, device=sources.device)
    q = torch.empty(n, frames, 5, dtype=sources.dtype, device=sources.device)
    q[..., :3] = sources[:, None]
    q[..., 3] = k
    q[..., 4] = k
    return q.reshape(-1, 5)


def random_sources(n: int, frames: int, generator: torch.Generator) -> torch.Tensor:
    """``(n, 3)`` track sources [u, v, t_src]: uniform positions, uniform source frames."""
    return torch.cat([torch.rand(n, 2, generator=generator),
                      torch.randint(0, frames, (n, 1), generator=generator).float()], 1)


def _alternating_best(settings: dict, device: torch.device, repeats: int) -> dict:
    """Best time of each setting's callable, the settings taking turns within each repeat so that
    background load on a shared machine hits all of them alike."""
    best = {name: float("inf") for name in settings}
    for _ in range(repeats):
        for name, fn in settings.items():
            best[name] = min(best[name], time_once(fn, device))
    return best


def bench_decoder(model, scene, options: BenchOptions) -> dict:
    """Queries/s of ``scene.query`` on ``options.queries`` random queries at each chunk size (plus the
    config's default and the memory-derived "auto" size), with the scene keys/values cached (projected
    once per run, as once per clip) and recomputed for every chunk. Then 3D-track queries with and
    without source sharing at the default chunk size."""
    device = torch.device(options.device)
    config = model.config
    frames = scene.num_frames
    g = torch.Generator().manual_seed(options.seed + 1)
    queries = random_queries(options.queries, frames, g).to(device)
    default_chunk = config.query_chunk_size
    with options.autocast():
        auto = auto_chunk_size(config, scene.tokens.shape[1], device)
    chunks = sorted({*options.chunks, default_chunk, auto})
    rows = []
    with options.autocast():
        for chunk in progress_bar(chunks, desc="decoder chunk sizes", unit="size", disable=not options.progress, leave=False):
            def run(cache: bool, chunk=chunk):
                scene.clear_cache()  # cached: one projection per run, as once per clip
                return scene.query(queries, chunk_size=chunk, cache_kv=cache)

            warm = queries[: min(len(queries), 2 * chunk)]
            for cache in (True, False):
                scene.query(warm, chunk_size=chunk, cache_kv=cache)
            best = _alternating_best({"cached": lambda: run(True), "uncached": lambda: run(False)}, device,
                                     options.repeats)
            rows.append({
                "chunk_size": chunk,
                "default": chunk == default_chunk,
                "auto": chunk == auto,
                "cached_queries_per_s": len(queries) / best["cached"],
                "uncached_queries_per_s": len(queries) / best["uncached"],
                "kv_cache_speedup": best["uncached"] / best["cached"],
            })

        # Tracks: (u, v, t_src) repeated for every t_tgt; the source part of the embedding is shared.
        n_tracks = max(1, options.queries // frames)
        tracks = track_queries(random_sources(n_tracks, frames, g), frames).to(device)
        scene.query(tracks[: 2 * default_chunk], share_sources=True)
        scene.query(tracks[: 2 * default_chunk], share_sources=False)
        best = _alternating_best({share: (lambda share=share: scene.query(tracks, share_sources=share))
                                  for share in (True, False)}, device, options.repeats)
    by_chunk = {row["chunk_size"]: row for row in rows}
    flops = decoder_flops_per_query(config, frames)
    default = by_chunk[default_chunk]
    return {
        "chunks": rows,
        "default_chunk_size": default_chunk,
        "auto_chunk_size": auto,
        "queries_per_s": default["cached_queries_per_s"],
        "kv_cache_speedup_256": by_chunk[256]["kv_cache_speedup"],
        "flops_per_query": flops,
        "tflops_per_s": flops * default["cached_queries_per_s"] / 1e12,
        "track_queries": int(len(tracks)),
        "track_shared_queries_per_s": len(tracks) / best[True],
        "track_unshared_queries_per_s": len(tracks) / best[False],
        "track_sharing_speedup": best[False] / best[True],
    }
