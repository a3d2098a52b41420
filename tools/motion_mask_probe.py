"""How well a checkpoint's moving-object masks (``Reconstruction.motion_masks``) find the moving surfaces, on held-out
clips whose exact masks the oracle gives.

    python tools/motion_mask_probe.py [CHECKPOINT] --out probe.json [--clips 8] [--resolution encoder]

Clips: drawn like synthetic-dynamic-v1's (every 3rd clip definition, ``--clips`` of them, seeds 7,000,000 + index as
``tools/measure_focal.py --held-out``: never the benchmark's). Truth: the same recipe on the clip's oracle (exact:
tested against the clip's object poses in tests/reconstruction/test_motion_masks.py), at the same resolution and
target frames, moving where its relative motion exceeds the library's default threshold (``MOTION_THRESHOLD``). Per clip: the moving share of the pixels
with a surface, AUROC of the checkpoint's relative motion as a score for "moving", and precision, recall, F1 and IoU of
its mask at each threshold of ``THRESHOLDS``; then their means over clips. Writes JSON, prints a table.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from d4rt.config import MOTION_THRESHOLD
from d4rt.evaluation.synthetic_benchmark import FRAMES, clip_specs
from d4rt.model import D4RT
from d4rt.reconstruction import Reconstruction
from d4rt.synthetic import render_clip

HELD_OUT_SEED = 7_000_000  # as tools/measure_focal.py --held-out
THRESHOLDS = (0.02, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.8)


def auroc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for ``positive`` (1-D), ties counted half (Mann-Whitney U)."""
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if not n_pos or not n_neg:
        return float("nan")
    order = np.argsort(score, kind="stable")
    ranks = np.empty(len(score))
    sorted_scores = score[order]
    # Average ranks over ties.
    _, first, counts = np.unique(sorted_scores, return_index=True, return_counts=True)
    for f, c in zip(first, counts):
        ranks[order[f:f + c]] = f + (c + 1) / 2
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def mask_scores(predicted: np.ndarray, truth: np.ndarray) -> dict:
    """precision, recall, F1 and IoU of a boolean mask against the truth (same shape)."""
    tp = float((predicted & truth).sum())
    fp, fn = float((predicted & ~truth).sum()), float((~predicted & truth).sum())
    precision = tp / (tp + fp) if tp + fp else float("nan")
    recall = tp / (tp + fn) if tp + fn else float("nan")
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan")
    iou = tp / (tp + fp + fn) if tp + fp + fn else float("nan")
    return {"precision": precision, "recall": recall, "f1": f1, "iou": iou}


def probe_clip(model: D4RT, spec, resolution) -> dict:
    clip = render_clip(spec.seed, FRAMES, spec.height, spec.width, **vars(spec.options))
    rec = model.reconstruct(clip.rgb)
    size = rec.output_size(resolution if resolution != "original" else None)
    truth = Reconstruction.from_clip(clip).motion_masks(size)
    guess = rec.motion_masks(size)
    surface = np.isfinite(truth.relative_motion) & np.isfinite(guess.relative_motion)
    moving = truth.dynamic[surface]
    score = guess.relative_motion[surface]
    row = {"clip": spec.index, "seed": spec.seed, "size": list(size), "moving_share": float(moving.mean()),
           "auroc": auroc(score, moving), "median_relative_motion_static": float(np.median(score[~moving])),
           "median_relative_motion_moving": float(np.median(score[moving])) if moving.any() else float("nan")}
    for t in THRESHOLDS:
        row[f"@{t}"] = mask_scores(score > t, moving)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", nargs="?", default=None, help="model folder (default: the bundled model)")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--clips", type=int, default=8)
    parser.add_argument("--resolution", default="encoder", help="'encoder', 'original' or HxW")
    args = parser.parse_args()
    resolution = (args.resolution if args.resolution in ("encoder", "original")
                  else tuple(int(v) for v in args.resolution.split("x")))
    model = D4RT.from_pretrained(args.checkpoint).eval()
    specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[::3][:args.clips]]
    rows = [probe_clip(model, spec, resolution) for spec in tqdm(specs, desc="motion masks", unit="clip")]
    summary = {"auroc": float(np.nanmean([r["auroc"] for r in rows])),
               "moving_share": float(np.mean([r["moving_share"] for r in rows]))}
    for t in THRESHOLDS:
        for k in ("precision", "recall", "f1", "iou"):
            summary[f"{k}@{t}"] = float(np.nanmean([r[f"@{t}"][k] for r in rows]))
    args.out.write_text(json.dumps({"checkpoint": args.checkpoint or "bundled", "truth_threshold": MOTION_THRESHOLD,
                                    "resolution": args.resolution, "clips": rows, "mean": summary}, indent=1))
    print(f"{len(rows)} clips, moving share {summary['moving_share']:.3f}, AUROC {summary['auroc']:.3f}")
    print("threshold  precision  recall  F1     IoU")
    for t in THRESHOLDS:
        print(f"{t:<9}  {summary[f'precision@{t}']:.3f}      {summary[f'recall@{t}']:.3f}   "
              f"{summary[f'f1@{t}']:.3f}  {summary[f'iou@{t}']:.3f}")


if __name__ == "__main__":
    main()
