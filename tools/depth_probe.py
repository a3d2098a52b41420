"""Held-out depth of checkpoints, scored exactly as ``d4rt eval`` scores synthetic-dynamic-v1 (issue 14).

    python tools/depth_probe.py CHECKPOINT [CHECKPOINT ...] --out probe.json [--clips 16]

Why: a checkpoint must never be chosen on the benchmark, and the 4 training-validation clips (rendered at
64x96 like the training clips) say little about the benchmark's depth (stage 17: 0.21 there, 0.41 on the
benchmark). This probe renders clips drawn like synthetic-dynamic-v1's (the same sizes, field-of-view bands,
camera motions, environments, zoom and objects: clip definition i with its seed replaced by 9,000,000 + i, a
range no benchmark, probe or training stage draws from) and scores each checkpoint's depth maps with the
harness's own depth scoring (``Reconstruction.depth`` at the clip's resolution, AbsRel and delta<1.25 after
per-sequence scale and scale&shift alignment, aggregated over all pixels as the benchmark does).

The clips are the definitions i = 6b + s for each field-of-view band b (0-7) and two sizes s per band:
first s = 2b mod 6 for every band, then s = (2b + 3) mod 6, so any 8 first clips cover every band and all 16
every size; ``--clips N`` keeps the first N (default 16; up to 48, the other clip definitions in order, as many
clips as the benchmark has), ``--skip S`` leaves out the first S of them. A clip costs about 15-25 s per checkpoint on one CPU thread.
Also reported: the median over clips of each clip's AbsRel. Why: the alignment minimises the L1 error of depth
itself, so in an outdoor clip whose model depth range is too narrow the far pixels (tens of metres) decide the
scale and every near pixel's relative error can reach 10x or more (the shipped weights on held-out clip 34:
AbsRel 9.6, where its other seven clips are 0.12-0.55); with 8-16 clips one such clip outweighs all the others.
Also reported, because no alignment can hide it: per clip with pixels truly beyond 30 and within 10 (outdoor clips:
no room reaches 15), the ratio of the median predicted depth of the far pixels to that of the near
ones, beside the true ratio, and over those clips the median of |log(predicted / true ratio)|
(``far_near_log_error``; 0 = the far range in the right proportion to the near one).
With ``--gate-seed N`` the clips are a judge's gate set instead (definition i with seed N + i, the clips of
``tools/measure_focal.py --gate-seed N``; docs/training.md, "Gate sets drawn per judgment").
With ``--dense-head`` (stage 67) each checkpoint's depth maps come from its dense depth head
(``d4rt.model.dense_depth``, a training aid) instead of its queries: the head's log-depth at encoder resolution,
resized bilinearly to the clip, exponentiated and scored alike. Why: it says whether the scene tokens hold the depth
that the queries fail to read out (a decoder limit) or not (an encoder limit).
With ``--window W [--overlap O]`` each clip is encoded as overlapping windows of W frames stitched by Sim(3) (the
long-video recipe, paper App. B) instead of one window: it says how much depth a model draws from a longer context
(the shipped weights on the 16 held-out clips, 2026-12-07: median clip AbsRel (s&s) 0.2842 with 8-frame windows
overlapping by 4, against 0.2658 whole; docs/training.md, stage 150).
Writes JSON (per checkpoint the aggregate and per-clip rows) and prints one line per checkpoint.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from d4rt.errors import UserError
from d4rt.evaluation.benchmarks import Benchmark
from d4rt.evaluation.harness import aggregate, evaluate_sequence
from d4rt.evaluation.predictions import Prediction, d4rt_predictor
from d4rt.evaluation.synthetic_benchmark import NUM_CLIPS, SIZES, clip_specs, gate_specs
from d4rt.reconstruction.windows import window_overlap

HELD_OUT_SEED = 9_000_000
DEFAULT_CLIPS = 16  # the probe every stage since 20 reports
# True depths (scene units, metres in the synthetic engine) that split far from near for the far/near ratio.
FAR_DEPTH, NEAR_DEPTH = 30.0, 10.0
PROBE = Benchmark("depth-probe", "held-out clips drawn like synthetic-dynamic-v1", None, ("depth",))


def probe_indices() -> list[int]:
    """All 48 clip definitions, ordered so that any first N are balanced: one per field-of-view band, then a
    second size per band (the first 16 hold every size as often), then the other 32 in order."""
    sizes, bands = len(SIZES), range(NUM_CLIPS // len(SIZES))
    first = ([sizes * band + 2 * band % sizes for band in bands]
             + [sizes * band + (2 * band + 3) % sizes for band in bands])
    return first + [i for i in range(NUM_CLIPS) if i not in first]


def render_probe_clips(count: int, skip: int = 0, gate_seed: int | None = None) -> list:
    """The first ``count`` probe clips (``probe_indices`` order), less the first ``skip`` of them; with
    ``gate_seed``, those definitions from a judge's gate set instead of the held-out seeds."""
    specs = gate_specs(gate_seed) if gate_seed is not None else [
        replace(spec, seed=HELD_OUT_SEED + spec.index) for spec in clip_specs()]
    return [specs[i].render() for i in probe_indices()[skip:count]]


class DenseHeadPredictor:
    """Depth maps from a model's dense depth head (module docstring): ``predict(sequence, tasks)`` as the harness
    asks it, depth only."""

    name = "d4rt-dense-head"

    def __init__(self, checkpoint: str):
        from d4rt.model import D4RT

        self.model = D4RT.from_pretrained(checkpoint)
        if self.model.dense_depth is None:
            raise UserError(f"{checkpoint} has no dense depth head (config dense_depth_head is false)")

    def predict(self, sequence, tasks: set[str]) -> Prediction:
        if sequence.num_frames > self.model.config.max_frames:
            raise UserError(f"{sequence.name}: {sequence.num_frames} frames exceed the model's "
                            f"{self.model.config.max_frames}; the dense head reads one window only")
        scene = self.model.encode(sequence.rgb)
        size = self.model.config.image_size
        with torch.no_grad():
            log_depth = self.model.dense_depth(scene.tokens, sequence.num_frames, size, size)
            log_depth = torch.nn.functional.interpolate(log_depth, size=tuple(sequence.image_size), mode="bilinear",
                                                        align_corners=False)
        return Prediction(depth=torch.exp(log_depth[0]).numpy())


def far_near_ratio(pred: np.ndarray, true: np.ndarray) -> tuple[float, float] | None:
    """(predicted, true) ratio of the median depth of the pixels truly beyond FAR_DEPTH to that of the pixels
    truly within NEAR_DEPTH (0 < depth). pred, true: (T, H, W). None when either set is empty or either
    predicted median is not positive (no ratio to speak of)."""
    far, near = true > FAR_DEPTH, (true > 0) & (true < NEAR_DEPTH)
    if not far.any() or not near.any():
        return None
    pred_far, pred_near = float(np.median(pred[far])), float(np.median(pred[near]))
    if pred_far <= 0 or pred_near <= 0:
        return None
    return pred_far / pred_near, float(np.median(true[far]) / np.median(true[near]))


def probe(predictor, sequences: list) -> dict:
    rows, ratios = [], {}
    with torch.no_grad():
        for sequence in sequences:
            prediction = predictor.predict(sequence, {"depth"})
            rows.append(evaluate_sequence(PROBE, sequence, prediction))
            ratios[sequence.name] = far_near_ratio(prediction.depth, sequence.depth)
    summary = {k: round(v, 4) for k, v in aggregate(PROBE, rows).items() if v is not None}
    for align in PROBE.depth_alignments:  # robust to one clip whose alignment the far pixels decide (see above)
        summary[f"median_clip_abs_rel[{align}]"] = round(float(np.median([r.metrics[f"abs_rel[{align}]"]
                                                                          for r in rows])), 4)
    log_errors = [abs(np.log(r[0] / r[1])) for r in ratios.values() if r is not None]
    summary["far_near_log_error"] = round(float(np.median(log_errors)), 4) if log_errors else None
    clips = []
    for r in rows:
        clip = {"clip": r.name, **{k: round(v, 4) for k, v in r.metrics.items() if v is not None},
                "valid_pixels": r.valid_pixels}  # its weight in the pooled figures
        if ratios[r.name] is not None:
            clip["far_near_ratio"] = {"predicted": round(ratios[r.name][0], 3), "true": round(ratios[r.name][1], 3)}
        clips.append(clip)
    return summary | {"clips": clips}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--out", required=True)
    available = len(probe_indices())
    parser.add_argument("--clips", type=int, default=DEFAULT_CLIPS,
                        help=f"how many of the {available} held-out clips (default {DEFAULT_CLIPS}; {available}: "
                             "as many as the benchmark, about 16 min per checkpoint)")
    parser.add_argument("--skip", type=int, default=0,
                        help="leave out the first SKIP of those clips (e.g. --clips 48 --skip 16: the 32 clips that "
                             "the default probe never scored, to confirm a finding on fresh clips)")
    parser.add_argument("--gate-seed", type=int, default=None, metavar="N",
                        help="the clips of a judge's gate set (seeds N + index) instead of the held-out clips")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--window", type=int, default=None, metavar="W",
                        help="encode each clip as overlapping windows of W frames, stitched (default: one window)")
    parser.add_argument("--overlap", type=int, default=None, metavar="O",
                        help="frames shared by consecutive windows (default: a quarter of --window)")
    parser.add_argument("--dense-head", action="store_true",
                        help="score the depth of each checkpoint's dense depth head instead of its queries")
    args = parser.parse_args()
    if not 1 <= args.clips <= available:
        parser.error(f"--clips must be 1-{available}, got {args.clips}")
    if not 0 <= args.skip < args.clips:
        parser.error(f"--skip must be 0-{args.clips - 1} (fewer than --clips), got {args.skip}")
    if args.dense_head and args.window is not None:
        parser.error("--window reads depth by queries; the dense head reads one window only")
    if args.overlap is not None and args.window is None:
        parser.error("--overlap needs --window")
    if args.window is not None:
        try:  # checked before anything is loaded or rendered, as the reconstruction would check it per clip
            window_overlap(args.window, args.overlap)
        except UserError as error:
            parser.error(str(error))
    torch.set_num_threads(args.threads)
    try:  # every checkpoint loads (strictly) before the clips are rendered: a bad path fails in one line, at once
        if args.dense_head:
            predictors = {checkpoint: DenseHeadPredictor(checkpoint) for checkpoint in args.checkpoints}
        else:
            predictors = {checkpoint: d4rt_predictor(checkpoint, window=args.window, overlap=args.overlap)
                          for checkpoint in args.checkpoints}
    except UserError as error:
        parser.error(str(error))
    try:
        sequences = render_probe_clips(args.clips, args.skip, args.gate_seed)
    except UserError as error:
        parser.error(str(error))
    report = {"held_out_seed": HELD_OUT_SEED if args.gate_seed is None else None, "gate_seed": args.gate_seed,
              "clip_definitions": probe_indices()[args.skip:args.clips],
              "depth_from": "dense depth head" if args.dense_head else "queries",
              "window": args.window, "overlap": args.overlap, "models": {}}
    for checkpoint, predictor in predictors.items():
        start = time.perf_counter()
        report["models"][str(checkpoint)] = row = probe(predictor, sequences)
        print(checkpoint, "median clip AbsRel (s&s)", row["median_clip_abs_rel[scale&shift]"],
              "AbsRel (s&s)", row["abs_rel[scale&shift]"], "delta<1.25 (s&s)",
              row["delta<1.25[scale&shift]"], "AbsRel (scale)", row["abs_rel[scale]"],
              "far/near log error", row["far_near_log_error"],
              f"({time.perf_counter() - start:.0f} s)", flush=True)
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
