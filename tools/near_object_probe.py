"""How far off a checkpoint reads the depth of bodies near the camera, resting on the floor against floating (stage 112).

    python tools/near_object_probe.py CHECKPOINT [CHECKPOINT ...] --out near.json [--clips 24]

Why: the gate sets' worst depth clips (AbsRel (s&s) 0.5-0.9) are clips where a body within about 2 m fills 20-50% of
the frame; the shipped weights read it 2-4x too far, and those pixels carry 60-90% of the clip's error. The synthetic
scenes place half of their bodies resting on the floor and half floating, each of a log-uniform size (half-extent
0.15-0.65 m, ``d4rt.synthetic.sampling``): a floating body of unknown size is near and small or far and large in one
frame, and when it moves on its own, motion does not tell them apart either; only shadows and occlusions do. A resting
body's contact with the floor fixes its depth. This probe says which of the two the model gets wrong.

Clips are drawn like the training stream of stages 103-111 (``render_clip`` at 80x80, 8 frames, field of view 20-120
degrees, half the camera paths walked; every other scene option drawn by the generator), from seeds 14,000,000 + i
(a range no benchmark, probe, gate set or training stream draws from), keeping the first ``--clips`` clips with at
least 5% of their pixels on bodies nearer than NEAR_DEPTH. Each checkpoint's depth maps (``Reconstruction.depth``
through the evaluation predictor) get the benchmark's per-sequence L1 scale and shift; then, per body with at least
MIN_PIXELS near pixels, the median of log(aligned predicted / true depth) over its near pixels. Reported per group
(resting / floating / articulated: the parts of the generator's arm, grounded through its base): how many bodies, the median of |that log ratio| and the median ratio itself (> 1: read too far).
Writes JSON (per checkpoint the groups and per-body rows) and prints one line per checkpoint.

With ``--size-prior-floor`` (no checkpoint) it instead scores, on the first 16 held-out clips of
``tools/depth_probe.py`` (drawn like synthetic-dynamic-v1), the depth maps of an observer that knows every depth
exactly except each floating body's scale: it sees the body's shape and image size and takes the size prior's median,
so every pixel of a floating body of half-extents h is read at its true depth x m / g(h), g the geometric mean of the
half-extents and m the median of g over the generator's own shape draws. What AbsRel (s&s) that ambiguity alone
leaves when nothing else (shadows, occlusion) resolves it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from depth_probe import probe, render_probe_clips  # noqa: E402

from d4rt.errors import UserError  # noqa: E402
from d4rt.evaluation.metrics.depth import l1_scale_and_shift  # noqa: E402
from d4rt.evaluation.predictions import Prediction, d4rt_predictor  # noqa: E402
from d4rt.evaluation.synthetic_benchmark import sequence_from_clip  # noqa: E402
from d4rt.synthetic.clip import Clip  # noqa: E402
from d4rt.synthetic.generate import render_clip  # noqa: E402
from d4rt.synthetic.sampling import _random_shape  # noqa: E402  (the generator's own size prior)

SEED = 14_000_000
NEAR_DEPTH = 2.5  # metres: a body this near fills much of a frame at these fields of view
MIN_NEAR_FRACTION = 0.05  # of a clip's pixels, on near bodies, for the clip to be kept
MIN_PIXELS = 50  # near pixels of one body for its row
GROUPS = ("resting", "floating", "articulated")
RENDER = dict(frames=8, height=80, width=80, fov_degrees=(20.0, 120.0), walk_fraction=0.5)


def body_group(clip: Clip, body: int) -> str:
    """"articulated" for the parts of the generator's arm (grounded through its base), else "resting" or "floating"."""
    if clip.scene.bodies[body].name.startswith("arm"):
        return "articulated"
    return "resting" if is_resting(clip, body) else "floating"


def is_resting(clip: Clip, body: int, tol: float = 1e-3) -> bool:
    """Whether rigid body ``body`` rests on the floor for the whole clip: its centre at its half height above z = 0
    and its local z axis upright (turned about the vertical only), as the generator places resting bodies."""
    pose = clip.object_to_world[:, body]  # (T, 4, 4)
    half_height = clip.scene.bodies[body].half_extents[2]
    return bool(np.all(np.abs(pose[:, 2, 3] - half_height) < tol) and np.all(pose[:, 2, 2] > 1 - tol))


def body_log_ratios(pred: np.ndarray, true: np.ndarray, object_ids: np.ndarray) -> dict[int, float]:
    """Per body id (> 0) with at least MIN_PIXELS pixels truly nearer than NEAR_DEPTH: the median over those pixels of
    log(aligned / true depth), after one L1 scale and shift over every valid pixel (the benchmark's alignment).
    pred, true: (T, H, W) depth; object_ids: (T, H, W) int, 0 = the static environment."""
    valid = np.isfinite(true) & (true > 0) & np.isfinite(pred)
    scale, shift = l1_scale_and_shift(pred[valid], true[valid])
    aligned = scale * pred + shift
    near = valid & (true < NEAR_DEPTH) & (object_ids > 0)
    ratios = {}
    for body in np.unique(object_ids[near]):
        mask = near & (object_ids == body)
        if mask.sum() >= MIN_PIXELS:  # an aligned depth at or behind the camera counts as 1e-6 m: a large error, kept
            ratios[int(body)] = float(np.median(np.log(np.maximum(aligned[mask], 1e-6) / true[mask])))
    return ratios


def summarise(rows: list[dict]) -> dict:
    """Per group (resting / floating / articulated): bodies, median |log ratio|, median ratio."""
    out = {}
    for group in GROUPS:
        logs = np.array([r["log_ratio"] for r in rows if r["group"] == group])
        out[group] = {"bodies": len(logs),
                      "median_abs_log_ratio": round(float(np.median(np.abs(logs))), 4) if len(logs) else None,
                      "median_ratio": round(float(np.exp(np.median(logs))), 3) if len(logs) else None}
    return out


def size_prior_median(draws: int = 20_000, seed: int = 0) -> float:
    """m: the median over the generator's random shapes of the geometric mean of their half-extents (metres)."""
    rng = np.random.default_rng(seed)
    return float(np.median([np.exp(np.mean(np.log(_random_shape(rng)[1]))) for _ in range(draws)]))


def size_prior_depth(clip: Clip, median_size: float) -> np.ndarray:
    """(T, H, W): the clip's true depth with each floating body's pixels scaled by median_size / g(its half-extents)
    (the module docstring's observer)."""
    depth = clip.depth.copy()
    for body in range(1, len(clip.scene.bodies)):
        if body_group(clip, body) == "floating":
            size = float(np.exp(np.mean(np.log(clip.scene.bodies[body].half_extents))))
            depth[clip.object_ids == body] *= median_size / size
    return depth


def size_prior_floor() -> dict:
    """The size-prior observer scored as tools/depth_probe.py scores a checkpoint, on its first 16 held-out clips."""
    median_size = size_prior_median()

    class Observer:
        def predict(self, sequence, tasks):
            return Prediction(depth=size_prior_depth(sequence.clip, median_size))

    return {"median_size": round(median_size, 4)} | probe(Observer(), render_probe_clips(16))


def near_clips(count: int) -> list[tuple[int, Clip]]:
    """The first ``count`` clips of seeds SEED, SEED + 1, ... with at least MIN_NEAR_FRACTION near-body pixels."""
    clips, seed = [], SEED
    while len(clips) < count:
        clip = render_clip(seed, RENDER["frames"], RENDER["height"], RENDER["width"],
                           fov_degrees=RENDER["fov_degrees"], walk_fraction=RENDER["walk_fraction"])
        near = (clip.depth > 0) & (clip.depth < NEAR_DEPTH) & (clip.object_ids > 0)
        if near.mean() >= MIN_NEAR_FRACTION:
            clips.append((seed, clip))
        seed += 1
    return clips


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="*")
    parser.add_argument("--size-prior-floor", action="store_true",
                        help="score the size-prior observer (module docstring) instead of checkpoints")
    parser.add_argument("--out", required=True)
    parser.add_argument("--clips", type=int, default=24, help="clips with near bodies to score (default 24)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()
    if args.clips < 1:
        parser.error(f"--clips must be at least 1, got {args.clips}")
    torch.set_num_threads(args.threads)
    if args.size_prior_floor:
        if args.checkpoints:
            parser.error("--size-prior-floor scores no checkpoint; give none")
        floor = size_prior_floor()
        Path(args.out).write_text(json.dumps(floor, indent=1) + "\n")
        print("size-prior observer: AbsRel (s&s)", floor["abs_rel[scale&shift]"], "median clip",
              floor["median_clip_abs_rel[scale&shift]"], "delta<1.25 (s&s)", floor["delta<1.25[scale&shift]"])
        return
    if not args.checkpoints:
        parser.error("give at least one checkpoint (or --size-prior-floor)")
    try:  # every checkpoint loads (strictly) before anything is rendered: a bad path fails in one line, at once
        predictors = {checkpoint: d4rt_predictor(checkpoint) for checkpoint in args.checkpoints}
    except UserError as error:
        parser.error(str(error))
    clips = near_clips(args.clips)
    report = {"seed": SEED, "near_depth": NEAR_DEPTH, "render": {k: list(v) if isinstance(v, tuple) else v
                                                                 for k, v in RENDER.items()},
              "clip_seeds": [seed for seed, _ in clips], "models": {}}
    for checkpoint, predictor in predictors.items():
        start, rows = time.perf_counter(), []
        for seed, clip in clips:
            sequence = sequence_from_clip(clip, f"seed_{seed}", 16, track_seed=seed)
            with torch.no_grad():
                depth = predictor.predict(sequence, {"depth"}).depth
            for body, log_ratio in body_log_ratios(depth, clip.depth, clip.object_ids).items():
                rows.append({"seed": seed, "body": body, "group": body_group(clip, body),
                             "log_ratio": round(log_ratio, 4)})
        summary = summarise(rows)
        report["models"][str(checkpoint)] = summary | {"bodies": rows}
        print(checkpoint, *(f"{g}: {s['bodies']} bodies, median |log| {s['median_abs_log_ratio']}, "
                            f"median ratio {s['median_ratio']};" for g, s in summary.items()),
              f"({time.perf_counter() - start:.0f} s)", flush=True)
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
