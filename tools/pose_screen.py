"""Camera poses of checkpoints on synthetic-dynamic-v1 in a minute or two each (issue 14's pose screen)

    python tools/pose_screen.py CHECKPOINT [CHECKPOINT ...] --out screen.json [--limit N]

The `d4rt eval` harness restricted to the pose task: every clip of the benchmark, the camera recipe's
cam_to_world scored as `d4rt eval` scores it (ATE, RPE-trans, RPE-rot, AUC@30), then, as in the model card,
the mean ATE on the clips that both the checkpoint and pycolmap pose against pycolmap's
(docs/model-card/eval-synthetic-dynamic-v1-colmap.json). Depth, tracks and point clouds are skipped, which is
what makes it fast (measured on the 2-core Xeon: 80 s per checkpoint against 19 min for a full `d4rt eval`).
A screen for training runs, not a gate: a candidate is still judged by the full `d4rt eval`. Writes JSON (per clip and per checkpoint) and prints one line per checkpoint.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from d4rt.evaluation.benchmarks import get_benchmark
from d4rt.evaluation.harness import evaluate_sequence
from d4rt.evaluation.predictions import d4rt_predictor
from d4rt.config import POSE_PAIRS, D4RTConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from model_card import BENCHMARK, pose_comparison  # noqa: E402  (a sibling script, not a package)

COLMAP = Path(__file__).resolve().parents[1] / "docs" / "model-card" / f"eval-{BENCHMARK}-colmap.json"
POSE_KEYS = ("ate", "rpe_trans", "rpe_rot", "auc@30")


def screen(checkpoints: list[str], limit: int | None = None, pose_pairs: str | None = None) -> dict:
    """Per checkpoint: the camera pairing used (``pose_pairs``, by default the model's own), per-clip pose
    metrics, their means over all clips, and the pycolmap comparison."""
    colmap = [m for m in json.loads(COLMAP.read_text())["methods"] if m["name"] == "colmap"]
    benchmark = get_benchmark(BENCHMARK)
    names = benchmark.sequence_names(None)[:limit]
    predictors = {c: d4rt_predictor(c, pose_pairs=pose_pairs) for c in checkpoints}
    clips: dict[str, list[dict]] = {c: [] for c in checkpoints}
    for name in names:
        sequence = benchmark.load(None, name)
        for checkpoint, predictor in predictors.items():
            result = evaluate_sequence(benchmark, sequence, predictor.predict(sequence, {"pose"}))
            clips[checkpoint].append({"name": name, "metrics": {k: result.metrics.get(k) for k in POSE_KEYS}})
    report = {}
    for checkpoint, rows in clips.items():
        means = {k: float(np.mean([r["metrics"][k] for r in rows if r["metrics"][k] is not None])) for k in POSE_KEYS}
        comparison = pose_comparison({"methods": [{"name": "d4rt", "sequences": rows}] + colmap})
        comparison["ratio"] = comparison["d4rt_ate"] / comparison["colmap_ate"]
        pairs = pose_pairs or D4RTConfig.load(Path(checkpoint) / "config.json").pose_pairs
        report[checkpoint] = {"pose_pairs": pairs, "mean": means, "colmap_comparison": comparison, "clips": rows}
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--out", required=True)
    parser.add_argument("--limit", type=int, default=None, help="only the first N clips")
    parser.add_argument("--pose-pairs", choices=POSE_PAIRS,
                        help="the camera recipe's pairing (default: each model's own, its config's pose_pairs)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    report = {"benchmark": BENCHMARK, "models": screen(args.checkpoints, args.limit, args.pose_pairs)}
    Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    for name, row in report["models"].items():
        c, m = row["colmap_comparison"], row["mean"]
        print(f"{name} ({row['pose_pairs']}): ATE {m['ate']:.4f}, on the {len(c['common'])} clips pycolmap poses "
              f"{c['d4rt_ate']:.4f} vs {c['colmap_ate']:.4f} = {c['ratio']:.2f}x; "
              f"RPE-trans {m['rpe_trans']:.4f}, RPE-rot {m['rpe_rot']:.3f} deg")


if __name__ == "__main__":
    main()
