"""Camera accuracy against the size of the camera recipe's grid, to choose the default (speed is
``d4rt bench --pose-grid N``; the decoding cost grows with N^2).

    python benchmarks/pose_grid_accuracy.py [--checkpoint DIR] [--clips 48] [--grids 24 16 12 8] [--json out.json]

For every clip of synthetic-dynamic-v1 (exact ground truth) and every grid, ``model.reconstruct(video,
grid=N).cameras()``: ATE and RPE (Sim(3)-aligned, ``d4rt.evaluation.metrics.pose``) and the median
relative focal error over the clip's frames. Prints the means over clips (median for the focal
error) per grid, and each grid's change against the finest one.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch
from tqdm import tqdm

from d4rt.evaluation.metrics.pose import pose_metrics
from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.model import D4RT
from d4rt.reconstruction import Reconstruction


def measure(model: D4RT, clips: int, grids: list[int]) -> list[dict]:
    rows = []
    for spec in tqdm(clip_specs()[:clips], desc="clips", unit="clip"):
        sequence = spec.render()
        row = {"name": spec.name}
        scene = model.encode(sequence.rgb)  # one encoding serves every grid
        for grid in grids:
            cams = Reconstruction(scene, sequence.rgb, grid=grid).cameras()
            metrics = pose_metrics(cams.cam_to_world, sequence.cam_to_world)
            focal = np.abs(cams.intrinsics[:, 0, 0] / sequence.intrinsics[:, 0, 0] - 1)
            row[str(grid)] = {"ate": metrics["ate"], "rpe_trans": metrics["rpe_trans"],
                              "rpe_rot": metrics["rpe_rot"], "focal_error": float(np.median(focal))}
        rows.append(row)
    return rows


def summarise(rows: list[dict], grids: list[int]) -> dict:
    summary = {}
    for grid in grids:
        values = {k: np.array([r[str(grid)][k] for r in rows]) for k in ("ate", "rpe_trans", "rpe_rot", "focal_error")}
        summary[str(grid)] = {"mean_ate": float(values["ate"].mean()), "mean_rpe_trans": float(values["rpe_trans"].mean()),
                              "mean_rpe_rot": float(values["rpe_rot"].mean()),
                              "median_focal_error": float(np.median(values["focal_error"]))}
    finest = str(max(grids))
    for grid in grids:
        ratio = np.array([r[str(grid)]["ate"] / r[finest]["ate"] for r in rows])
        summary[str(grid)]["ate_vs_finest_max"] = float(ratio.max())
        summary[str(grid)]["ate_vs_finest_mean"] = float(ratio.mean())
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", help="model directory (default: the bundled model)")
    parser.add_argument("--clips", type=int, default=48)
    parser.add_argument("--grids", type=int, nargs="+", default=[24, 16, 12, 8])
    parser.add_argument("--threads", type=int)
    parser.add_argument("--json", help="write the per-clip figures and the summary here")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    model = D4RT.from_pretrained(args.checkpoint)
    rows = measure(model, args.clips, args.grids)
    summary = summarise(rows, args.grids)
    finest = max(args.grids)
    print(f"synthetic-dynamic-v1, {len(rows)} clips, checkpoint {args.checkpoint or 'bundled'}")
    print(f"{'grid':>6} {'mean ATE':>10} {'RPE trans':>10} {'RPE rot':>9} {'focal err':>10} "
          f"{'ATE / ' + str(finest) + ' (mean, max)':>26}")
    for grid in args.grids:
        s = summary[str(grid)]
        print(f"{grid:>6} {s['mean_ate']:>10.4f} {s['mean_rpe_trans']:>10.4f} {s['mean_rpe_rot']:>9.3f} "
              f"{s['median_focal_error']:>10.3f} {s['ate_vs_finest_mean']:>15.3f} {s['ate_vs_finest_max']:>9.3f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"checkpoint": args.checkpoint or "bundled", "clips": rows, "summary": summary}, f, indent=1)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
