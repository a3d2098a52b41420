"""Does a model use t_cam? (issue 14's stage-9 diagnosis)

    python tools/camera_probe.py CHECKPOINT [CHECKPOINT ...] --out probe.json

For 16 synthetic clips drawn like synthetic-dynamic-v1's (every 3rd clip definition; ``--every 1``: all 48) from
seeds the benchmark never uses (8,000,000 + index; 16 frames at time stride 2), an 8 x 8 grid of every frame i is
asked twice, in its own camera (i, i, i) and in camera 0 (i, i, 0): the camera recipe's question. Per clip and
frame, against the clip's exact oracle:

- ``rotation``: the angle of the rigid fit between the two answers (what ``Reconstruction.cameras`` turns into
  the pose of frame i) against the true rotation between cameras i and 0, in degrees;
- ``change``: how far the answer moves when t_cam goes from i to 0, relative to the point's distance
  (mean |P(i,i,0) - P(i,i,i)| / mean |P(i,i,i)|), model against truth;
- ``rotation_error``: the angle between the fitted and the true rotation, in degrees (a camera that never
  moves scores the true rotation itself);
- ``translation_cosine`` and ``translation_ratio``: the rigid fit's translation, divided by the mean distance
  of the points in camera i (so each side in its own scale), against the truth's: the cosine of the angle
  between the two, and the length of the model's over the truth's.

A model that ignores t_cam recovers no rotation and its answer does not move. Reported: per clip the last
frame's figures, and over all frames with a true rotation above 5 degrees the median of model / truth for both
(1 = the full camera motion recovered, 0 = none), the median rotation error over all frames but the
first beside the median true rotation, and over the frames whose camera travelled more than a tenth of the
points' mean distance the median translation cosine and ratio (1 and 1 = the direction and length of travel
recovered); ``by_gap`` gives the rotation error and translation cosine per bin of 4 frames (the gap between
t_src and t_cam). ``--frames 24 --time-stride 1`` asks 24-frame clips at synthetic-dynamic-v1's frame rate.

``trajectory_ate``: the whole trajectory as ``Reconstruction.cameras`` returns it, for each ``pose_pairs``
(``first``: the paper's recipe, every frame against camera 0; ``adjacent``: every frame against the previous one,
the fits chained), scored like ``d4rt eval`` (ATE after Sim(3) alignment, in the clip's units): mean and median
over the clips; the adjacent chain again with each step's rotation (``adjacent_true_rotations``) or translation
(``adjacent_true_translations``) replaced by the truth's, which says which half of the steps its error comes from
(and the translation's direction or length alone: ``adjacent_true_translation_directions``, ``..._lengths``),
and with each step's translation averaged over the 5 steps centred on it (``adjacent_smoothed_5``: the share of its
error that is step-to-step scatter);
beside a camera that never moves (the RMS distance of the true positions from their mean) and
one that walks a straight line at constant speed (``constant_velocity``: the RMS distance of the true positions
from the best straight line in time; on these smooth paths the floor a camera has to beat). ``adjacent_steps``: the
adjacent chain's frame-to-frame steps against the true ones, over the steps that travel at least a quarter of their
clip's median step: the median cosine of the step translations, the median share of a step's length along the
optical axis, the model's and the truth's (a chain that walks straight ahead reads a share near 1), and the median
deviation of the log step-length ratio from its clip's median (the chain's scale drift from step to step).
Writes JSON and prints it.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from d4rt.evaluation.baselines import constant_velocity_poses
from d4rt.evaluation.metrics.pose import pose_metrics, rotation_angle
from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.geometry.camera import cell_centres_uv
from d4rt.model import D4RT
from d4rt.reconstruction import Reconstruction
from d4rt.reconstruction.cameras import relative_poses
from d4rt.reconstruction.sources import flipped_encode
from d4rt.reconstruction.query_patterns import grid_queries
from d4rt.config import POSE_PAIRS
from d4rt.synthetic import render_clip

HELD_OUT_SEED = 8_000_000
FRAMES, TIME_STRIDE, GRID = 16, 2, 8
MIN_ROTATION = 5.0  # degrees: frames with less true rotation say little about the ratio
MIN_TRAVEL = 0.1  # of the points' mean distance: frames whose camera travelled less say little about direction
CHAIN_PARTS = ("rotation", "translation", "translation_direction", "translation_length")  # see chain_with_true
SMOOTHING = 5  # steps averaged by the smoothed chain of trajectory_ate (adjacent_smoothed_5)
MIN_STEP = 0.25  # of a clip's median true frame-to-frame travel: shorter steps say little about direction


def own_and_first_camera(answer, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Grid points of every frame i in camera i and in camera 0: two (T, GRID^2, 3) arrays."""
    frames = np.arange(num_frames)
    uv = cell_centres_uv(GRID)
    queries = np.stack([grid_queries(uv, frames, frames, frames),
                        grid_queries(uv, frames, frames, np.zeros_like(frames))], 1).reshape(-1, 5)
    points = np.asarray(answer(queries)["points"], dtype=np.float64)
    return points[0::2].reshape(num_frames, -1, 3), points[1::2].reshape(num_frames, -1, 3)


def camera_figures(here: np.ndarray, there: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per frame: rotation (3, 3) of the rigid fit here -> there, its angle (degrees), the relative change,
    and the fit's translation (3,) over the mean distance of the points here."""
    pose = relative_poses(here, there, np.ones(here.shape[:2]))
    distance = np.linalg.norm(here, axis=-1).mean(1)
    change = np.linalg.norm(there - here, axis=-1).mean(1) / distance
    return pose[:, :3, :3], np.degrees(rotation_angle(pose[:, :3, :3])), change, pose[:, :3, 3] / distance[:, None]


def by_gap(errors: np.ndarray, cosines: np.ndarray) -> list[dict]:
    """Medians per bin of frames 1-3, 4-7, 8-11, ... (the gap to frame 0): rotation error (degrees) and
    translation cosine (over the travelled frames). errors, cosines: (clips, frames), NaN = not counted."""
    frames = errors.shape[1]
    bins = [(1, min(4, frames))] + [(a, min(a + 4, frames)) for a in range(4, frames, 4)]

    def median(values: np.ndarray) -> float | None:
        values = values[np.isfinite(values)]
        return round(float(np.median(values)), 3) if values.size else None

    return [{"frames": [a, b - 1], "median_rotation_error": median(errors[:, a:b]),
             "median_translation_cosine": median(cosines[:, a:b]),
             "frames_travelled": int(np.isfinite(cosines[:, a:b]).sum())} for a, b in bins]


def trajectory_ates(scene, clip) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """ATE of the recipe's trajectory for each pose pairing, from the clip's encoded ``scene`` (anything with
    ``query`` and ``num_frames``), of a camera that never moves and of one walking a straight line at constant
    speed (the two pose floors of ``d4rt eval``); and the adjacent chain's step directions (:func:`step_directions`)."""
    truth = clip.cam_to_world
    poses = {pairs: Reconstruction(scene, clip.rgb, pose_pairs=pairs, progress=False).cameras().cam_to_world
             for pairs in POSE_PAIRS}
    ates = {pairs: pose_metrics(pose, truth)["ate"] for pairs, pose in poses.items()}
    for part in CHAIN_PARTS:
        ates[f"adjacent_true_{part}s"] = pose_metrics(chain_with_true(poses["adjacent"], truth, part), truth)["ate"]
    ates[f"adjacent_smoothed_{SMOOTHING}"] = pose_metrics(chain_smoothed(poses["adjacent"], SMOOTHING), truth)["ate"]
    centres = truth[:, :3, 3]
    ates["static"] = float(np.sqrt(((centres - centres.mean(0)) ** 2).sum(1).mean()))
    ates["constant_velocity"] = pose_metrics(constant_velocity_poses(len(truth)), truth)["ate"]
    return ates, step_directions(poses["adjacent"], truth)


def step_directions(poses: np.ndarray, truth: np.ndarray) -> dict[str, np.ndarray]:
    """The frame-to-frame steps of ``poses`` (T, 4, 4) camera-to-world against the truth's (T, 4, 4), over the steps
    whose true travel is at least ``MIN_STEP`` of the clip's median true step (a turn on the spot has no direction):
    ``cosine``, the cosine between the model's and the true step translation (in the earlier camera's axes; each in
    its own scale), ``axial_share`` / ``true_axial_share``, the share of the step's length along the optical axis
    (|z| / length), and ``length_deviation``, how far the log of the step's length over the true one lies from that
    log's median over the clip's counted steps (0 when every step keeps one scale; the chain's scale drift). Each
    (steps,); empty for a camera that never travels."""
    steps, true_steps = ((np.linalg.inv(p[:-1]) @ p[1:])[:, :3, 3] for p in (poses, truth))
    length, true_length = np.linalg.norm(steps, axis=-1), np.linalg.norm(true_steps, axis=-1)
    counted = true_length >= max(MIN_STEP * float(np.median(true_length)), 1e-9)
    cosine = (steps * true_steps).sum(-1) / np.maximum(length * true_length, 1e-12)  # 0 for a vanished step
    log_ratio = np.log(np.maximum(length[counted], 1e-12) / true_length[counted])
    return {"cosine": cosine[counted], "axial_share": np.abs(steps[:, 2])[counted] / np.maximum(length[counted], 1e-12),
            "true_axial_share": np.abs(true_steps[:, 2])[counted] / true_length[counted],
            "length_deviation": np.abs(log_ratio - np.median(log_ratio)) if log_ratio.size else log_ratio}


def summarise_steps(per_clip: list[dict]) -> dict:
    """Medians over every counted step of every clip of :func:`step_directions`' figures, and the count."""
    values = {key: np.concatenate([row[key] for row in per_clip]) for key in per_clip[0]}
    count = len(values["cosine"])
    return {f"median_{key}": round(float(np.median(v)), 3) if count else None for key, v in values.items()} | {
        "steps": count}


def chain(first: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (T, 4, 4) from the first pose (4, 4) and the frame-to-frame steps (T - 1, 4, 4), each
    step the later camera in the earlier one's axes (``inv(pose[i]) @ pose[i + 1]``)."""
    chained = [first]
    for step in steps:
        chained.append(chained[-1] @ step)
    return np.stack(chained)


def chain_with_true(poses: np.ndarray, truth: np.ndarray, part: str) -> np.ndarray:
    """``poses`` (T, 4, 4) camera-to-world re-chained from its frame-to-frame steps with each step's ``part``
    replaced by the truth's (T, 4, 4): which half of the steps the chain's ATE comes from. ``part``: "rotation",
    "translation", or one factor of the translation: "translation_direction" (the true direction at the model's
    length, rescaled by one median ratio per clip) or "translation_length" (the model's direction at the true length).
    The truth's translations are in the truth's units; ATE's Sim(3) alignment needs one scale for the whole path, which
    the true translations with the model's rotations keep."""
    if part not in CHAIN_PARTS:
        raise ValueError(f"part must be one of {', '.join(repr(p) for p in CHAIN_PARTS)}, got {part!r}")
    steps, true_steps = (np.linalg.inv(p[:-1]) @ p[1:] for p in (poses, truth))
    if part == "rotation":
        steps[:, :3, :3] = true_steps[:, :3, :3]
    elif part == "translation":
        steps[:, :3, 3] = true_steps[:, :3, 3]
    else:  # one factor of the translation from the truth, the other the model's, in the truth's units for both
        length, true_length = (np.linalg.norm(s[:, :3, 3], axis=-1, keepdims=True) for s in (steps, true_steps))
        direction = steps[:, :3, 3] / np.maximum(length, 1e-12)
        true_direction = true_steps[:, :3, 3] / np.maximum(true_length, 1e-12)
        # the model's lengths in the truth's units: one scale per clip (the median ratio), as ATE's alignment has
        scale = np.median(true_length[true_length > 0] / np.maximum(length[true_length > 0], 1e-12)) \
            if (true_length > 0).any() else 1.0
        steps[:, :3, 3] = (true_direction * length * scale if part == "translation_direction"
                           else direction * true_length)
    return chain(truth[0], steps)


def chain_smoothed(poses: np.ndarray, window: int) -> np.ndarray:
    """``poses`` (T, 4, 4) camera-to-world re-chained from its frame-to-frame steps with each step's translation
    replaced by the mean of the translations of the ``window`` steps centred on it (fewer at the ends), its rotation
    kept: how much of the chain's ATE is step-to-step scatter that a smoothness prior would remove. The steps are in
    each earlier camera's axes, which turn by about a degree per frame on these clips."""
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be an odd number >= 1, got {window}")
    steps = np.linalg.inv(poses[:-1]) @ poses[1:]
    half = window // 2
    translations = steps[:, :3, 3].copy()
    for i in range(len(steps)):
        steps[i, :3, 3] = translations[max(0, i - half):i + half + 1].mean(0)
    return chain(poses[0], steps)


def summarise_ates(per_clip: list[dict]) -> dict:
    return {key: {"mean": round(float(np.mean([row[key] for row in per_clip])), 4),
                  "median": round(float(np.median([row[key] for row in per_clip])), 4)} for key in per_clip[0]}


def probe(model: D4RT, clips: list, frames: int = FRAMES) -> dict:
    rows, rot_ratio, change_ratio, errors, truths, cosines, lengths = [], [], [], [], [], [], []
    error_table, cosine_table, ates, steps = [], [], [], []
    for name, clip in clips:
        with torch.no_grad():  # one encoding serves the probe's queries and both trajectories
            scene = flipped_encode(model)(clip.rgb)  # as the recipes encode
            clip_ates, clip_steps = trajectory_ates(scene, clip)
            ates.append(clip_ates)
            steps.append(clip_steps)
            model_r, model_rot, model_change, model_t = camera_figures(*own_and_first_camera(scene.query, frames))
        true_r, true_rot, true_change, true_t = camera_figures(*own_and_first_camera(clip.oracle.query, frames))
        travelled = np.linalg.norm(true_t, axis=-1) > MIN_TRAVEL
        model_length, true_length = np.linalg.norm(model_t, axis=-1), np.linalg.norm(true_t, axis=-1)
        cosine = (model_t * true_t).sum(-1) / np.maximum(model_length * true_length, 1e-12)  # 0 for no travel
        cosines += list(cosine[travelled])
        lengths += list(model_length[travelled] / true_length[travelled])
        error = np.degrees(rotation_angle(np.swapaxes(model_r, 1, 2) @ true_r))
        error_table.append(error)
        cosine_table.append(np.where(travelled, cosine, np.nan))
        errors += list(error[1:])
        truths += list(true_rot[1:])
        moving = true_rot > MIN_ROTATION
        rot_ratio += list(model_rot[moving] / true_rot[moving])
        change_ratio += list(model_change[moving] / true_change[moving])
        rows.append({"clip": name, "true_rotation": round(float(true_rot[-1]), 2),
                     "rotation": round(float(model_rot[-1]), 2), "rotation_error": round(float(error[-1]), 2),
                     "true_change": round(float(true_change[-1]), 4),
                     "change": round(float(model_change[-1]), 4),
                     "trajectory_ate": {k: round(v, 4) for k, v in ates[-1].items()}})
    return {"median_rotation_ratio": round(float(np.median(rot_ratio)), 3) if rot_ratio else None,
            "median_change_ratio": round(float(np.median(change_ratio)), 3) if change_ratio else None,
            "frames_counted": len(rot_ratio), "median_rotation_error": round(float(np.median(errors)), 2),
            "median_true_rotation": round(float(np.median(truths)), 2),
            "median_translation_cosine": round(float(np.median(cosines)), 3) if cosines else None,
            "median_translation_ratio": round(float(np.median(lengths)), 3) if lengths else None,
            "frames_travelled": len(cosines),
            "by_gap": by_gap(np.array(error_table), np.array(cosine_table)),
            "trajectory_ate": summarise_ates(ates), "adjacent_steps": summarise_steps(steps), "clips": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--out", required=True)
    parser.add_argument("--frames", type=int, default=FRAMES, help=f"frames per clip (default {FRAMES})")
    parser.add_argument("--every", type=int, default=3,
                        help="every Nth clip definition of synthetic-dynamic-v1 (default 3: 16 clips; 1: all 48)")
    parser.add_argument("--time-stride", type=int, default=TIME_STRIDE,
                        help=f"time steps between frames (default {TIME_STRIDE}; synthetic-dynamic-v1 uses 1)")
    args = parser.parse_args()
    if args.every < 1:
        parser.error(f"--every must be at least 1, got {args.every}")
    torch.set_num_threads(1)
    specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[::args.every]]
    clips = [(f"held_out_{s.index:02d}", render_clip(s.seed, args.frames, s.height, s.width,
                                                      **(vars(s.options) | {"time_stride": args.time_stride})))
             for s in specs]
    report = {"frames": args.frames, "time_stride": args.time_stride, "every": args.every,
              "held_out_seed": HELD_OUT_SEED,
              "models": {str(c): probe(D4RT.from_pretrained(c), clips, args.frames) for c in args.checkpoints}}
    Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    for name, row in report["models"].items():
        print(name, "rotation recovered (median model/true):", row["median_rotation_ratio"],
              "answer change:", row["median_change_ratio"], f"({row['frames_counted']} frames);",
              "rotation error", row["median_rotation_error"], f"deg vs true rotation {row['median_true_rotation']};",
              "translation cosine", row["median_translation_cosine"], "length ratio", row["median_translation_ratio"],
              f"({row['frames_travelled']} frames)")
        print("  trajectory ATE (mean / median over clips):",
              "; ".join(f"{k} {v['mean']} / {v['median']}" for k, v in row["trajectory_ate"].items()))
        steps = row["adjacent_steps"]
        print(f"  adjacent steps ({steps['steps']}): median cosine with the true step {steps['median_cosine']}, "
              f"share along the optical axis {steps['median_axial_share']} (true {steps['median_true_axial_share']}), "
              f"log length deviation {steps['median_length_deviation']}")
        for gap in row["by_gap"]:
            print(f"  frames {gap['frames'][0]}-{gap['frames'][1]}: rotation error {gap['median_rotation_error']} deg, "
                  f"translation cosine {gap['median_translation_cosine']} ({gap['frames_travelled']} frames)")


if __name__ == "__main__":
    main()
