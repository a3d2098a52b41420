"""Training recipes compared at equal CPU time: every variant trained from scratch for the same wall-clock
budget on the same pre-rendered clip pool, scored on the same held-out clips.

    d4rt generate --out POOL --num-clips 700 --frames 24 --height 96 --width 96 --aspect 0.5 2 --fov 30 110
    d4rt generate --out HELDOUT --num-clips 8 --frames 24 --height 96 --width 96 --aspect 0.5 2 --fov 30 110 \\
        --seed 7000000
    python benchmarks/recipe_study.py --pool POOL --heldout HELDOUT --out RUNS --minutes 3 --parallel 2

Each variant runs as ``d4rt train`` in its own process with one torch thread and no loader workers
(``--parallel`` of them side by side, so each has one core of a machine with that many). Equal time
needs a step count: each variant first trains ``--calibration-steps`` steps to measure its own speed
under the same load, then trains ``minutes * steps/s`` steps from scratch, so that its learning-rate
schedule ends with its budget. At the end ``validation`` scores the held-out clips exactly as
``d4rt eval`` does (depth AbsRel, ATE, APD3D, OA); the focal error is measured with the intrinsics recipe
(``model.reconstruct(video).cameras()``, median over frames of |fx / fx_true - 1|, median over clips).

Writes ``RUNS/results.json`` (every variant's steps, time and metrics) and prints a markdown table. The
held-out clips must come from a seed range that neither the pool nor any benchmark uses.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import yaml

from d4rt.errors import UserError
from d4rt.training.logger import read_metrics, training_seconds

# The recipe every variant starts from: the tiny preset on 8-frame clips of the pool.
BASE = {
    "model": {"preset": "tiny", "overrides": {}},
    "data": {"batch_size": 1, "workers": 0, "dataset": {
        "source": "files", "frames": 8, "size": [64, 64],
        "sampler": {"num_queries": 1024}}},
    "loss": {},
    "optim": {"lr": 3.0e-4, "min_lr": 1.0e-6, "warmup_steps": 50, "weight_decay": 0.03, "grad_clip": 10.0},
    "run": {"max_steps": 100, "seed": 0, "device": "cpu", "precision": "fp32", "log_every": 10,
            "checkpoint_every": 100000, "keep_checkpoints": 1, "tensorboard": False, "progress": False},
    "validation": {"every": 0, "num_clips": 8, "frames": 24, "num_queries": 1024, "track_points": 64,
                   "tasks": ["depth", "pose", "tracks"]},
}

# name -> dotted overrides of BASE (a list of two dicts: a curriculum, each phase half the budget).
VARIANTS: dict[str, dict | list[dict]] = {
    "base": {},
    "base-seed1": {"run.seed": 1, "data.dataset.seed": 1},
    "frames-12": {"data.dataset.frames": 12},
    "frames-16": {"data.dataset.frames": 16},
    "frames-8to24": {"data.dataset.frame_choices": [8, 8, 8, 12, 16, 24]},
    "crop-centered": {"data.dataset.augment.crop_policy": "centered"},
    "crop-none": {"data.dataset.augment.crop_policy": "none"},
    "crop-none-seed1": {"data.dataset.augment.crop_policy": "none", "run.seed": 1, "data.dataset.seed": 1},
    "depth-25pct": {"data.dataset.sampler.depth_fraction": 0.25},
    "input-96": {"model.overrides": {"image_size": 96}, "data.dataset.size": [96, 96]},
    "narrow-128": {"model.overrides": {"encoder_dim": 128, "encoder_heads": 4, "encoder_mlp_dim": 512,
                                       "decoder_dim": 128, "decoder_heads": 4, "decoder_mlp_dim": 512}},
    "no-confidence": {"loss.confidence_weighting": False},
    "bf16": {"run.precision": "bf16"},
    "curriculum": [{"data.dataset.sampler.depth_fraction": 0.6, "data.dataset.sampler.tgt_equals_cam_prob": 1.0},
                   {}],
}


def _set(config: dict, key: str, value) -> None:
    *parents, leaf = key.split(".")
    node = config
    for part in parents:
        node = node.setdefault(part, {})
    node[leaf] = value


def variant_config(overrides: dict, pool: Path, heldout: Path) -> dict:
    config = copy.deepcopy(BASE)
    _set(config, "data.dataset.directory", str(pool))
    _set(config, "validation.directory", str(heldout))
    for key, value in overrides.items():
        _set(config, key, value)
    return config


def run_train(config: dict, out: Path, steps: int, validate: bool, init_from: Path | None = None) -> float:
    """``d4rt train`` in a subprocess with one torch thread -> wall seconds of training (metrics.jsonl)."""
    config = copy.deepcopy(config)
    config["run"]["max_steps"] = steps
    config["run"]["checkpoint_every"] = steps
    config["optim"]["warmup_steps"] = min(config["optim"]["warmup_steps"], max(1, steps // 10))
    config["validation"]["every"] = steps if validate else 0
    if init_from is not None:
        config["model"]["init_from"] = str(init_from)
    out.mkdir(parents=True, exist_ok=True)
    (out.parent / f"{out.name}.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    d4rt_train(["--config", str(out.parent / f"{out.name}.yaml"), "--out", str(out)], out.parent / f"{out.name}.log")
    return training_seconds(read_metrics(out), 1)


def d4rt_train(arguments: list[str], log: Path, append: bool = False, threads: int = 1) -> None:
    """``d4rt train ARGUMENTS`` in a subprocess with ``threads`` torch threads (its loader workers too), its output
    in ``log`` (appended to with ``append``, e.g. by a resumed run); a failed run raises one line naming the log."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a" if append else "w") as stream:
        code = subprocess.run([sys.executable, "-m", "d4rt", "train", *arguments], env=env, stdout=stream,
                              stderr=subprocess.STDOUT).returncode
    if code != 0:
        raise UserError(f"d4rt train {' '.join(arguments)} exited with {code}; its output is in {log}")


def steps_per_second(out: Path, skip: int = 10) -> float:
    rates = [r["throughput/clips_per_s"] for r in read_metrics(out) if "throughput/clips_per_s" in r and r["step"] > skip]
    return float(np.mean(rates))


def focal_error(model_dir: Path, heldout: Path, limit: int) -> float:
    """Median over held-out clips of the median over frames of |fx / fx_true - 1|."""
    import torch

    from d4rt.model import D4RT
    from d4rt.synthetic import load_clip

    torch.set_num_threads(1)
    model = D4RT.from_pretrained(model_dir)
    errors = []
    for path in sorted(heldout.glob("*.npz"))[:limit]:
        clip = load_clip(path)
        fx = model.reconstruct(clip.rgb, progress=False).cameras().intrinsics[:, 0, 0]
        errors.append(float(np.median(np.abs(np.asarray(fx) / clip.intrinsics[:, 0, 0] - 1.0))))
    return float(np.median(errors))


def study_variant(name: str, spec, args) -> dict:
    phases = spec if isinstance(spec, list) else [spec]
    root = args.out / name
    if (root / "result.json").is_file() and not args.fresh:  # an earlier invocation's finished variant
        return json.loads((root / "result.json").read_text())
    if root.exists():
        shutil.rmtree(root)
    budget = args.minutes * 60.0
    result = {"name": name, "phases": [], "train_seconds": 0.0, "steps": 0}
    previous = None
    for index, overrides in enumerate(phases):
        config = variant_config(overrides, args.pool, args.heldout)
        calibration = root / f"calibrate-{index}"
        run_train(config, calibration, args.calibration_steps, validate=False, init_from=previous)
        rate = steps_per_second(calibration)
        steps = max(20, int(rate * budget / len(phases)))
        last = index == len(phases) - 1
        out = root / f"phase-{index}"
        seconds = run_train(config, out, steps, validate=last, init_from=previous)
        result["phases"].append({"overrides": overrides, "calibrated_steps_per_s": rate, "steps": steps,
                                 "train_seconds": seconds})
        result["train_seconds"] += seconds
        result["steps"] += steps
        previous = out
    records = read_metrics(previous)
    final = {}
    for r in records:
        final.update(r)
    result["metrics"] = {k: v for k, v in final.items() if k.startswith("val/")}
    result["final_train_loss_3d"] = next((r["loss/3d"] for r in reversed(records) if "loss/3d" in r), None)
    result["focal_error"] = focal_error(previous, args.heldout, args.focal_clips)
    (root / "result.json").write_text(json.dumps(result, indent=1))
    print(f"{name}: {result['steps']} steps, {row(result)}", flush=True)
    return result


COLUMNS = [("steps", "steps"), ("abs_rel s&s", "val/abs_rel_scale_shift"), ("δ<1.25 s&s", "val/delta_1.25_scale_shift"),
           ("focal err", "focal_error"), ("ATE", "val/ate"), ("APD3D", "val/apd3d"), ("OA", "val/oa"),
           ("val L3D", "val/loss/3d")]


def _value(result: dict, key: str):
    if key in ("steps", "focal_error"):
        return result[key]
    return result["metrics"].get(key)


def row(result: dict) -> str:
    cells = []
    for _, key in COLUMNS:
        value = _value(result, key)
        cells.append("-" if value is None else (f"{value:d}" if isinstance(value, int) else f"{value:.4g}"))
    return " | ".join(cells)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pool", type=Path, required=True, help="d4rt generate output to train on")
    parser.add_argument("--heldout", type=Path, required=True, help="d4rt generate output to score on")
    parser.add_argument("--out", type=Path, required=True, help="directory for the runs and results.json")
    parser.add_argument("--minutes", type=float, default=3.0, help="training budget per variant")
    parser.add_argument("--parallel", type=int, default=2, help="variants trained side by side (one core each)")
    parser.add_argument("--calibration-steps", type=int, default=30)
    parser.add_argument("--focal-clips", type=int, default=8)
    parser.add_argument("--fresh", action="store_true", help="retrain variants that already have a result.json "
                        "in --out (default: reuse them, so an interrupted study continues)")
    parser.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated subset of: "
                        + ", ".join(VARIANTS))
    args = parser.parse_args()
    names = [n for n in args.variants.split(",") if n]
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        parser.error(f"unknown variants {unknown}")
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.time()
    with ThreadPoolExecutor(args.parallel) as pool:
        results = list(pool.map(lambda n: study_variant(n, VARIANTS[n], args), names))
    summary = {"minutes": args.minutes, "parallel": args.parallel, "pool": str(args.pool),
               "heldout": str(args.heldout), "wall_seconds": time.time() - started, "variants": results}
    (args.out / "results.json").write_text(json.dumps(summary, indent=1))
    print("| variant | " + " | ".join(c for c, _ in COLUMNS) + " |")
    print("|---" * (len(COLUMNS) + 1) + "|")
    for result in results:
        print(f"| {result['name']} | {row(result)} |")


if __name__ == "__main__":
    main()
