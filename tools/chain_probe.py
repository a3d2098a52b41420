"""Where a chained camera trajectory goes wrong: its rotations or its translations? (issue 14, stage 76)

    python tools/chain_probe.py CHECKPOINT [CHECKPOINT ...] --out probe.json

Why: every model trained on from the shipped weights recovers more of the camera's rotation than they do (stages 38,
69-74) while the trajectory chained from one-frame fits (``pose_pairs="adjacent"``, the shipped recipe) gets worse,
and most of the loss comes from a few clips whose camera turns by 30-60 degrees. For the 48 held-out clips of
``tools/camera_probe.py --every 1 --frames 24 --time-stride 1`` (seeds 8,000,000 + index), each model's chained
trajectory is cut into its frame-to-frame steps (camera-to-world, ``P_i = P_(i-1) @ step_i``) and rebuilt four
ways, each scored like ``d4rt eval`` (ATE after Sim(3) alignment):

- ``model``: the model's steps (the recipe's trajectory itself);
- ``true_rotations``: each step's rotation replaced by the true one, the model's translation kept;
- ``true_translations``: each step's translation replaced by the true one (the Sim(3) alignment absorbs the
  model's scale), the model's rotation kept;
- ``similarity_chain``: the recipe's own answers (the 12 x 12 grid of frame i in cameras i and i - 1) fitted with a
  scale as well (Umeyama Sim(3) instead of rigid) and the similarities chained, so that a model whose answers in
  camera i - 1 are at another scale than in camera i does not turn that into travel. Exact on the oracle (every
  scale 1); ``step_scale`` gives the fitted scales' median and 5th-95th percentiles.

So a trajectory that ``true_rotations`` repairs lost itself in its rotations. Per step, also the angle between the
model's and the true rotation (``step_rotation_error``, degrees) and the model's step angle over the true one
(``step_rotation_ratio``, over steps that turn by more than 0.5 degrees); each step's travel against the truth's
(``step_translation_cosine``, and ``step_length_ratio``: the length ratio over the clip's median one). Reported per
model: the mean and median over clips of each ATE, the medians (and 5th-95th percentiles) of the step figures, and
the clips with the largest ``model`` ATE. Writes JSON.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from d4rt.evaluation.metrics.pose import pose_metrics, rotation_angle
from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.geometry.camera import cell_centres_uv
from d4rt.geometry.transforms import invert_rigid
from d4rt.geometry.umeyama import batched_umeyama
from d4rt.model import D4RT
from d4rt.reconstruction import Reconstruction
from d4rt.reconstruction.query_patterns import grid_queries
from d4rt.reconstruction.reconstruction import DEFAULT_GRID, ask_in_chunks
from d4rt.reconstruction.sources import flipped_encode
from d4rt.synthetic import render_clip

HELD_OUT_SEED = 8_000_000  # tools/camera_probe.py's clips
FRAMES = 24
MIN_STEP_DEGREES = 0.5
WAYS = ("model", "true_rotations", "true_translations", "similarity_chain")


def steps(cam_to_world: np.ndarray) -> np.ndarray:
    """(T, 4, 4) camera-to-world -> (T - 1, 4, 4) frame-to-frame steps, ``P_i = P_(i-1) @ step_i``."""
    return invert_rigid(cam_to_world[:-1]) @ cam_to_world[1:]


def chain(step: np.ndarray) -> np.ndarray:
    """Steps (T - 1, 4, 4) -> the trajectory (T, 4, 4) from the identity."""
    poses = [np.eye(4)]
    for s in step:
        poses.append(poses[-1] @ s)
    return np.stack(poses)


def rebuilt(model: np.ndarray, truth: np.ndarray) -> dict[str, np.ndarray]:
    """The model's trajectory and its two hybrids with the truth (module docstring), each (T, 4, 4)."""
    model_steps, true_steps = steps(model), steps(truth)
    rotations, translations = model_steps.copy(), model_steps.copy()
    rotations[:, :3, :3] = true_steps[:, :3, :3]
    translations[:, :3, 3] = true_steps[:, :3, 3]
    return {"model": chain(model_steps), "true_rotations": chain(rotations), "true_translations": chain(translations)}


def similarity_chain(scene, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The adjacent recipe's answers fitted with a scale and chained: camera-to-world (T, 4, 4) in camera 0's
    units (rotations without the scale) and the T - 1 fitted scales. It asks the recipe's grid again (the recipe
    keeps only its rigid fits): a diagnosis's cost, twice the camera queries."""
    uv = cell_centres_uv(DEFAULT_GRID)
    frames = np.arange(1, num_frames)
    queries = np.concatenate([np.stack([grid_queries(uv, [i], [i], [c]) for c in (i, i - 1)], 1).reshape(-1, 5)
                              for i in frames])
    answers = {k: v.reshape(len(frames), len(uv), 2, *v.shape[1:])
               for k, v in ask_in_chunks(scene, queries, 1 << 16).items()}
    here, there = answers["points"][:, :, 0], answers["points"][:, :, 1]
    weights = answers["confidence"][:, :, 0] * answers["confidence"][:, :, 1]
    weights = np.where(np.isfinite(weights) & (weights > 0), weights, 0.0)
    fits = batched_umeyama(*(torch.from_numpy(a) for a in (here, there, weights)), with_scale=True)
    maps = [np.eye(4)]
    for step in fits.matrix().double().numpy():  # camera i -> camera i - 1, scale included
        maps.append(maps[-1] @ step)
    maps = np.stack(maps)
    poses = maps.copy()
    poses[:, :3, :3] = maps[:, :3, :3] / np.cbrt(np.linalg.det(maps[:, :3, :3]))[:, None, None]
    return poses, fits.scale.double().numpy()


def probe_clip(model: D4RT, clip) -> dict:
    with torch.no_grad():
        scene = flipped_encode(model)(clip.rgb)
        predicted = Reconstruction(scene, clip.rgb, pose_pairs="adjacent", progress=False).cameras().cam_to_world
        similar, scales = similarity_chain(scene, clip.num_frames)
    truth = clip.cam_to_world
    ates = {way: pose_metrics(poses, truth)["ate"] for way, poses in rebuilt(predicted, truth).items()}
    ates["similarity_chain"] = pose_metrics(similar, truth)["ate"]
    model_steps, true_steps = steps(predicted), steps(truth)
    model_r, true_r = model_steps[:, :3, :3], true_steps[:, :3, :3]
    error = np.degrees(rotation_angle(np.swapaxes(model_r, 1, 2) @ true_r))
    true_angle, model_angle = np.degrees(rotation_angle(true_r)), np.degrees(rotation_angle(model_r))
    turning = true_angle > MIN_STEP_DEGREES
    # Each step's travel against the truth's: the cosine of the angle between the two, and the length ratio over
    # the clip's median ratio (the model's scale is its own), over steps that travel at all.
    model_t, true_t = model_steps[:, :3, 3], true_steps[:, :3, 3]
    lengths = np.linalg.norm(model_t, axis=1), np.linalg.norm(true_t, axis=1)
    moving = lengths[1] > 1e-6 * max(lengths[1].max(), 1e-12)
    ratio = lengths[0][moving] / lengths[1][moving]
    cosine = (model_t[moving] * true_t[moving]).sum(1) / np.maximum(lengths[0][moving] * lengths[1][moving], 1e-12)
    return {"ate": ates, "step_scale": scales.tolist(), "step_translation_cosine": cosine.tolist(),
            "step_length_ratio": (ratio / np.median(ratio)).tolist() if len(ratio) else [],
            "step_rotation_error": error.tolist(),
            "step_rotation_ratio": (model_angle[turning] / true_angle[turning]).tolist(),
            "true_rotation": float(np.degrees(rotation_angle(truth[0, :3, :3].T @ truth[-1, :3, :3])))}


def summarise(rows: dict[str, dict], worst: int) -> dict:
    ates = {way: np.array([row["ate"][way] for row in rows.values()]) for way in WAYS}
    errors = np.concatenate([row["step_rotation_error"] for row in rows.values()])
    ratios = np.concatenate([row["step_rotation_ratio"] for row in rows.values()])
    scales = np.concatenate([row["step_scale"] for row in rows.values()])
    cosines = np.concatenate([row["step_translation_cosine"] for row in rows.values()])
    lengths = np.concatenate([row["step_length_ratio"] for row in rows.values()])
    order = sorted(rows, key=lambda name: -rows[name]["ate"]["model"])[:worst]
    return {"ate": {way: {"mean": round(float(a.mean()), 4), "median": round(float(np.median(a)), 4)}
                    for way, a in ates.items()},
            "median_step_rotation_error": round(float(np.median(errors)), 3),
            "median_step_rotation_ratio": round(float(np.median(ratios)), 3) if len(ratios) else None,
            "step_scale": [round(float(q), 4) for q in np.percentile(scales, [5, 50, 95])],
            "step_translation_cosine": [round(float(q), 3) for q in np.percentile(cosines, [5, 50, 95])],
            "step_length_ratio": [round(float(q), 3) for q in np.percentile(lengths, [5, 50, 95])],
            "worst_clips": [{"clip": name, "true_rotation": round(rows[name]["true_rotation"], 1),
                             **{way: round(rows[name]["ate"][way], 4) for way in WAYS}} for name in order]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--out", required=True)
    parser.add_argument("--worst", type=int, default=6, help="clips listed by their model ATE (default 6)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()]
    clips = {f"held_out_{s.index:02d}": render_clip(s.seed, FRAMES, s.height, s.width,
                                                     **(vars(s.options) | {"time_stride": 1})) for s in specs}
    report = {"held_out_seed": HELD_OUT_SEED, "frames": FRAMES, "models": {}}
    for checkpoint in args.checkpoints:
        model = D4RT.from_pretrained(checkpoint)
        rows = {name: probe_clip(model, clip) for name, clip in clips.items()}
        report["models"][checkpoint] = summarise(rows, args.worst) | {"clips": rows}
    Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    for name, row in report["models"].items():
        print(name, "ATE mean / median:", "; ".join(f"{way} {v['mean']} / {v['median']}" for way, v in row["ate"].items()),
              f"| step rotation error {row['median_step_rotation_error']} deg, ratio {row['median_step_rotation_ratio']}, "
              f"scale 5/50/95% {row['step_scale']}; step travel cosine {row['step_translation_cosine']}, "
              f"length over the clip's median {row['step_length_ratio']}")
        for clip in row["worst_clips"]:
            print("  ", clip)


if __name__ == "__main__":
    main()
