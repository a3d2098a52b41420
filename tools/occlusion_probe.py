"""Occlusion accuracy of checkpoints on held-out clips, against calling every point visible (issue 14, stage 65).

    python tools/occlusion_probe.py CHECKPOINT [CHECKPOINT ...] --out probe.json [--clips 16]

Why: the issue asks for OA >= 0.85 on synthetic-dynamic-v1 and the shipped model scores 0.755, while a tracker that
calls every point visible scores the clips' visible fraction (about 0.78 there). This probe shows how far a model's
visibility head is from that constant, without looking at the benchmark: clips drawn like synthetic-dynamic-v1's
(every 3rd clip definition, ``--clips`` of them, seeds 7,000,000 + index as ``tools/measure_focal.py --held-out``),
tracked exactly as ``d4rt eval`` tracks them (``Reconstruction.tracks`` of the benchmark's query points in each
frame's camera, visible where the probability exceeds 0.5) and scored with the harness's TAPVid-3D metrics.

Per clip and checkpoint: ``oa``, ``apd3d``, ``aj`` (the benchmark's median scaling); OA at the thresholds in
``THRESHOLDS``; the true and the predicted visible fraction; ``occluded_recall``, the share of truly hidden points
(occluded or out of frame) called hidden; ``hidden_out_of_frame``, the share of truly hidden points that are out of
frame or behind the camera (the rest are occluded); and ``oa_in_frame_gate``, OA when a point whose predicted (u, v)
leaves the image is called hidden whatever its visibility (a point the model itself puts out of frame cannot be
seen), with the paired bootstrap of the gated OA against the plain OA per clip. Per checkpoint their means over
clips; for every checkpoint after the first,
the paired bootstrap of the per-clip OA against the first (``tools/compare_evals.py``). Writes JSON, prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare_evals import paired_bootstrap  # noqa: E402

from d4rt.errors import UserError  # noqa: E402
from d4rt.evaluation.benchmarks import get_benchmark  # noqa: E402
from d4rt.evaluation.harness import track_intrinsics  # noqa: E402
from d4rt.evaluation.metrics.tracks import tapvid3d_metrics  # noqa: E402
from d4rt.evaluation.synthetic_benchmark import NAME, clip_specs  # noqa: E402
from d4rt.geometry.camera import project  # noqa: E402
from d4rt.model import D4RT  # noqa: E402

HELD_OUT_SEED = 7_000_000  # as tools/measure_focal.py --held-out
THRESHOLDS = (0.3, 0.5, 0.7, 0.9)
TRACK_SCALING = get_benchmark(NAME).track_scaling  # as d4rt eval scores synthetic-dynamic-v1


def visibility_scores(probability: np.ndarray, visible: np.ndarray, predicted_in_frame: np.ndarray | None = None,
                      truly_in_frame: np.ndarray | None = None) -> dict:
    """probability, visible: (T, N) predicted probability and truth -> OA per threshold, visible fractions and the
    recall of hidden points at 0.5; with ``predicted_in_frame`` (T, N) bool (the predicted (u, v) inside the image)
    also ``oa_in_frame_gate``, with ``truly_in_frame`` (T, N) bool also ``hidden_out_of_frame`` (module docstring)."""
    hidden = ~visible
    called_hidden = probability <= 0.5
    out = {f"oa@{t}": float(np.mean((probability > t) == visible)) for t in THRESHOLDS}
    out.update(constant_oa=float(np.mean(visible)), predicted_visible=float(np.mean(~called_hidden)),
               occluded_recall=float(np.mean(called_hidden[hidden])) if hidden.any() else float("nan"))
    if predicted_in_frame is not None:
        out["oa_in_frame_gate"] = float(np.mean(((probability > 0.5) & predicted_in_frame) == visible))
    if truly_in_frame is not None:
        out["hidden_out_of_frame"] = float(np.mean(~truly_in_frame[hidden])) if hidden.any() else float("nan")
    return out


def in_frame(points: np.ndarray, intrinsics: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """points: (T, N, 3) in each frame's camera; intrinsics: (T, 3, 3) pixels -> (T, N) bool, in front of the
    camera and projecting inside the image (pixel centres at i + 0.5, so the image spans [0, W] x [0, H])."""
    with np.errstate(divide="ignore", invalid="ignore"):
        xy, z = project(points, intrinsics[:, None])
    x, y = xy[..., 0] + 0.5, xy[..., 1] + 0.5
    height, width = image_size
    return (z > 0) & (x >= 0) & (x <= width) & (y >= 0) & (y <= height)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", help="model directories")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--clips", type=int, default=16, help="held-out clips (every 3rd clip definition, at most 16)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1: beside a training run)")
    args = parser.parse_args()
    definitions = clip_specs()[::3]
    if not 1 <= args.clips <= len(definitions):
        parser.error(f"--clips must be 1-{len(definitions)}, got {args.clips}")
    torch.set_num_threads(args.threads)
    try:  # every checkpoint loads (strictly) before the clips are rendered: a bad path fails in one line, at once
        models = {c: D4RT.from_pretrained(c) for c in args.checkpoints}
    except UserError as error:
        parser.error(str(error))
    specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in definitions[:args.clips]]
    rows = {c: [] for c in models}
    for spec in tqdm(specs, desc="occlusion probe", unit="clip"):
        sequence = spec.render()
        tracks = sequence.tracks
        sources = np.concatenate([tracks.query_frames[:, None], tracks.query_xy], 1)
        for name, model in models.items():
            predicted = model.reconstruct(sequence.rgb).tracks(sources, frame="camera")
            probability = predicted.visibility.T
            metrics = tapvid3d_metrics(predicted.points.transpose(1, 0, 2), probability > 0.5, tracks.points,
                                       tracks.visible, track_intrinsics(sequence), sequence.image_size, TRACK_SCALING)
            uv = predicted.uv.transpose(1, 0, 2)
            predicted_in_frame = np.isfinite(uv).all(-1) & (uv >= 0).all(-1) & (uv <= 1).all(-1)
            truly_in_frame = in_frame(tracks.points, sequence.intrinsics, sequence.image_size)
            rows[name].append({"clip": spec.name, **metrics, **visibility_scores(probability, tracks.visible,
                                                                                 predicted_in_frame, truly_in_frame)})
    report = {"held_out_seed": HELD_OUT_SEED, "clips": [s.name for s in specs], "models": {}, "paired_oa": {}}
    for name, clip_rows in rows.items():
        keys = [k for k in clip_rows[0] if k != "clip"]
        report["models"][name] = {"mean": {k: float(np.nanmean([r[k] for r in clip_rows])) for k in keys},
                                  "clips": clip_rows}
    report["paired_in_frame_gate"] = {  # per checkpoint: the gated OA against its own plain OA, clip by clip
        name: paired_bootstrap(np.array([r["oa"] for r in clip_rows]),
                               np.array([r["oa_in_frame_gate"] for r in clip_rows]),
                               np.ones(len(clip_rows)), lower_is_better=False) for name, clip_rows in rows.items()}
    reference, *others = args.checkpoints
    base = np.array([r["oa"] for r in rows[reference]])
    for name in others:
        new = np.array([r["oa"] for r in rows[name]])
        report["paired_oa"][name] = paired_bootstrap(base, new, np.ones_like(base), lower_is_better=False)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    for name, model in report["models"].items():
        m = model["mean"]
        paired = report["paired_oa"].get(name)
        against = (f"  vs first {paired['difference']:+.4f} [{paired['low']:+.4f}, {paired['high']:+.4f}]"
                   if paired else "")
        gate = report["paired_in_frame_gate"][name]
        print(f"{name}: in-frame gate OA - OA {gate['difference']:+.4f} [{gate['low']:+.4f}, {gate['high']:+.4f}]")
        print(f"{name}: OA {m['oa']:.4f} (every point visible: {m['constant_oa']:.4f}; called visible "
              f"{m['predicted_visible']:.3f}, hidden points found {m['occluded_recall']:.3f}, of them out of frame "
              f"{m['hidden_out_of_frame']:.3f}; in-frame gate OA {m['oa_in_frame_gate']:.4f}) APD3D {m['apd3d']:.4f}"
              f"{against}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
