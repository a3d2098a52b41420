"""Dense tracking (paper Alg. 1): queries decoded by the occupancy grid against the naive T * T * H * W,
and its wall time with the model.

Which cells a track covers depends on the answers, and a random-weight model's answers are
meaningless, so coverage is decided by exact answers: the clips of the frozen ``synthetic-dynamic-v1``
benchmark and their ground-truth oracle. ``Reconstruction.dense_tracks`` first runs on the oracle
(recording every block of queries it asks and the answers); then the same recipe runs on the model,
which decodes exactly those queries while the oracle's recorded answers steer the grid. The model's
wall time is thus that of a model as accurate as the oracle: decoding, transfers and grid bookkeeping
included, ray casting excluded.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from d4rt.progress import progress_bar

from d4rt.speed.options import BenchOptions
from d4rt.speed.timing import synchronize
from d4rt.evaluation.synthetic_benchmark import FRAMES, NAME, clip_specs
from d4rt.reconstruction import Reconstruction
from d4rt.synthetic import render_clip


class RecordingAnswerer:
    """An answerer (the oracle) whose every query block and answer is kept, in order."""

    def __init__(self, answerer):
        self.answerer, self.num_frames = answerer, answerer.num_frames
        self.log: list[tuple[np.ndarray, dict]] = []

    def query(self, queries) -> dict:
        out = self.answerer.query(queries)
        self.log.append((np.array(queries, copy=True), out))
        return out


class ReplayAnswerer:
    """Decodes each query block with the model (its answers fetched to the host, as the recipes do,
    then dropped) and returns the recorded answers to the same block."""

    def __init__(self, scene, log: list[tuple[np.ndarray, dict]], device: torch.device, progress: bool = False):
        self.scene, self.log, self.device = scene, log, device
        self.num_frames = scene.num_frames
        self.model = scene.model  # the recipes read the encoder size from it
        self.position = 0
        self.bar = progress_bar(total=sum(len(q) for q, _ in log), desc="dense tracking with the model", unit="query",
                        unit_scale=True, disable=not progress, leave=False)

    def query(self, queries) -> dict:
        expected, answer = self.log[self.position]
        if not np.array_equal(np.asarray(queries), expected):
            raise AssertionError("the replayed dense tracking asked different queries")  # a bug, not input
        self.position += 1
        out = self.scene.query(torch.as_tensor(np.asarray(queries), dtype=torch.float32, device=self.device))
        for key in ("points", "uv", "visibility", "confidence"):
            out[key].cpu()
        synchronize(self.device)
        self.bar.update(len(expected))
        return answer


def bench_dense(model, options: BenchOptions) -> dict:
    """Dense tracking of the first ``options.dense_clips`` clips of synthetic-dynamic-v1 on a grid of
    ``dense_size`` squared cells (default: each clip's own resolution)."""
    device = torch.device(options.device)
    rows = []
    for spec in progress_bar(clip_specs()[: options.dense_clips], desc="dense tracking clips", unit="clip",
                     disable=not options.progress, leave=False):
        clip = render_clip(spec.seed, FRAMES, spec.height, spec.width, **vars(spec.options))
        resolution = (options.dense_size, options.dense_size) if options.dense_size else (clip.height, clip.width)
        recorder = RecordingAnswerer(clip.oracle)
        start = time.perf_counter()
        exact = Reconstruction(recorder, clip.rgb, progress=False).dense_tracks(resolution)
        oracle_s = time.perf_counter() - start

        with options.autocast():
            synchronize(device)
            start = time.perf_counter()
            scene = model.encode(clip.rgb)
            synchronize(device)
            encode_s = time.perf_counter() - start
            replay = ReplayAnswerer(scene, recorder.log, device, options.progress)
            start = time.perf_counter()
            replayed = Reconstruction(replay, clip.rgb, progress=False).dense_tracks(resolution)
            tracking_s = time.perf_counter() - start
            replay.bar.close()
        if replayed.num_queries != exact.num_queries or replay.position != len(recorder.log):
            raise AssertionError("the replay decoded a different number of queries")
        rows.append({
            "clip": spec.name,
            "frames": FRAMES,
            "grid": list(resolution),
            "tracks": int(len(exact.sources)),
            "queries": int(exact.num_queries),
            "naive_queries": int(exact.naive_num_queries),
            "reduction": exact.naive_num_queries / exact.num_queries,
            "coverage": float(exact.coverage),
            "oracle_s": oracle_s,
            "encode_s": encode_s,
            "tracking_s": tracking_s,
            "wall_s": encode_s + tracking_s,
            "queries_per_s": exact.num_queries / tracking_s,
        })
    queries = sum(r["queries"] for r in rows)
    naive = sum(r["naive_queries"] for r in rows)
    return {"benchmark": NAME, "clips": rows, "queries": queries, "naive_queries": naive,
            "query_reduction": naive / queries, "min_reduction": min(r["reduction"] for r in rows),
            "wall_s": sum(r["wall_s"] for r in rows)}
