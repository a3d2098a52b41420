"""The paper's Tab. 3 protocol: the most full-video 3D tracks produced while holding a target FPS.

Definition (D4RT Tab. 3; ``shared/reference/evaluation.md``): a run takes the T-frame clip, encodes
it and decodes N full-video tracks (N sources (u, v, t_src), each queried at t_tgt = t_cam = k for
every frame k: N * T queries). It holds F FPS when it processes the clip at F video frames per second
or faster: wall time <= T / F. The answer is the largest such N (0 when the encoder alone is too slow).

Search: the track-query throughput gives a first guess; each candidate N is then measured (the whole
run, encoder included), stepping up or down from the guess until a count that holds and one that does
not are found, then bisecting between them until they are within ``tolerance`` of each other. The
reported N was measured to hold; nothing is extrapolated.
"""

from __future__ import annotations

import math

import torch
from d4rt.progress import progress_bar

from d4rt.speed.decoder import random_sources, track_queries
from d4rt.speed.options import BenchOptions
from d4rt.speed.timing import time_once


class TrackRun:
    """Encode + N tracks, timed; the queries of the largest N asked for so far are kept on the device."""

    def __init__(self, model, video: torch.Tensor, options: BenchOptions):
        self.model, self.video, self.options = model, video, options
        self.device = torch.device(options.device)
        self.frames = video.shape[0]
        self.generator = torch.Generator().manual_seed(options.seed + 2)
        self.sources = torch.zeros(0, 3)
        self.queries = torch.zeros(0, 5, device=self.device)

    def _queries(self, n: int) -> torch.Tensor:
        if n > len(self.sources):
            more = random_sources(max(n, 2 * len(self.sources)) - len(self.sources), self.frames, self.generator)
            self.sources = torch.cat([self.sources, more])
            self.queries = track_queries(self.sources, self.frames).to(self.device)
        return self.queries[: n * self.frames]

    def seconds(self, n: int, repeats: int) -> float:
        """Best wall time of encoding the clip and decoding ``n`` tracks (sources fixed per n)."""
        queries = self._queries(n)

        def run():
            scene = self.model.encode(self.video)
            if n:
                scene.query(queries)

        with self.options.autocast():
            return min(time_once(run, self.device) for _ in range(repeats))


def max_tracks_at_fps(run: TrackRun, fps: float, track_queries_per_s: float, tolerance: float,
                      max_trials: int) -> dict:
    """The largest measured N with T / seconds(N) >= fps (module docstring), with every trial."""
    budget = run.frames / fps
    repeats = 3 if budget < 0.5 else 1  # short runs are noisier and cheap to repeat
    trials = []

    def holds(n: int) -> bool:
        seconds = run.seconds(n, repeats)
        trials.append({"tracks": n, "seconds": seconds, "fps": run.frames / seconds, "holds": seconds <= budget})
        return seconds <= budget

    if not holds(0):
        return {"tracks": 0, "budget_s": budget, "bracketed": True, "trials": trials}
    encode_s = trials[0]["seconds"]
    n = max(1, int((budget - encode_s) * track_queries_per_s / run.frames))
    lo, hi = 0, None  # lo holds (0 does here), hi does not
    step = 2 * tolerance  # relative step while looking for the bracket, doubled each time
    while len(trials) < max_trials:
        if holds(n):
            lo = n
        else:
            hi = n
        if hi is not None and hi - lo <= max(1, math.floor(tolerance * lo)):
            break
        if hi is None:  # everything so far held: step up
            n = max(n + 1, math.ceil(n * (1 + step)))
            step *= 2
        elif lo == 0:  # nothing above 0 has held yet: step down from the failure
            n = max(1, math.floor(hi * (1 - step)))
            step *= 2
        else:
            n = (lo + hi) // 2
    return {"tracks": lo, "budget_s": budget, "bracketed": hi is not None, "trials": trials}


def bench_tracks_at_fps(model, video: torch.Tensor, options: BenchOptions, track_queries_per_s: float) -> dict:
    """``{fps: result}`` of :func:`max_tracks_at_fps` for every target FPS of the options."""
    run = TrackRun(model, video, options)
    run.seconds(1, 1)  # warm-up
    results = {}
    for fps in progress_bar(options.fps_targets, desc="tracks at target FPS", unit="target", disable=not options.progress,
                    leave=False):
        results[fps] = max_tracks_at_fps(run, fps, track_queries_per_s, options.tolerance, options.max_trials)
    return results
