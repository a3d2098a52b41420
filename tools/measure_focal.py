"""Focal lengths estimated by a D4RT model, measured where ``d4rt eval`` does not score them.

    python tools/measure_focal.py --checkpoint src/d4rt/assets/d4rt-tiny --out docs/model-card/focal.json

Two measurements, both with the paper's pinhole-median recipe (``model.reconstruct(video).cameras()``,
intrinsics in pixels of the input frames):

- ``synthetic-dynamic-v1``: every clip of the benchmark (or the first ``--limit``); per clip the median
  over its frames of the relative focal error |fx / fx_true - 1| (the engine's cameras have square
  pixels, fx = fy; zooming clips change fx per frame, and each frame is compared with its own), then the
  median and mean over clips.
- the 17 real TUM RGB-D fr3 frames bundled for ``d4rt demo``: the median fx over the frames against the
  published fx = 535.4 px (the value ``d4rt demo`` prints).

``--held-out`` measures the synthetic clips on the benchmark's 48 clip definitions drawn from seeds the benchmark
never uses (7,000,000 + index, the stream of ``tools/focal_motion_probe.py``), under the key ``synthetic-held-out``:
for choosing between weights without looking at the benchmark. ``--gate-seed N`` measures them on the same
definitions with seeds N + index instead, under the key ``synthetic-gate-N``: a judge's gate set, drawn for one
judgment and never measured before (docs/training.md, "Gate sets drawn per judgment").

``--camera single`` and ``--square-pixels`` measure the other intrinsics recipes of ``Reconstruction.cameras`` (one
camera fitted to every frame's points; fx = fy fitted together) instead of the paper's per-frame one; the JSON says
which under ``recipe``. ``--render-pixels N`` renders each synthetic clip at about N pixels per frame, its aspect
ratio kept (e.g. 6400, the training's ``render_pixels``), instead of the benchmark's size. (On the shipped weights
none of the three moves the focal error: docs/training.md, "Focal error by frame size".)

Writes JSON (every number the model card quotes about focal lengths) and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from d4rt.cli.demo import TUM_FOLDER, TUM_FX, tum_frames_dir
from d4rt.evaluation.synthetic_benchmark import NAME as BENCHMARK
from d4rt.evaluation.synthetic_benchmark import GATE_SEEDS, clip_specs, gate_specs
from d4rt.io.frames import load_frames
from d4rt.model import D4RT


HELD_OUT = "synthetic-held-out"
HELD_OUT_SEED = 7_000_000  # as tools/focal_motion_probe.py


def gate_key(seed_base: int) -> str:
    """The JSON key of a gate set's clips."""
    return f"synthetic-gate-{seed_base}"


def at_pixels(spec, pixels: float | None):
    """``spec`` with its frame size scaled to about ``pixels`` per frame, aspect ratio kept (None: unchanged)."""
    if pixels is None:
        return spec
    scale = math.sqrt(pixels / (spec.height * spec.width))
    return replace(spec, height=max(8, round(spec.height * scale)), width=max(8, round(spec.width * scale)))


def synthetic_focal_errors(model: D4RT, limit: int | None, held_out: bool = False,
                           seed_base: int | None = None, recipe: dict | None = None,
                           render_pixels: float | None = None) -> dict:
    """Per-clip median relative fx error on synthetic-dynamic-v1 (``held_out``: its clip definitions drawn from
    unused seeds; ``seed_base``: a gate set, drawn from seeds ``seed_base`` + index), and its median / mean over
    clips. recipe: keyword arguments of ``Reconstruction.cameras`` (None: the paper's per-frame median);
    render_pixels: see :func:`at_pixels`."""
    if held_out and seed_base is not None:
        raise ValueError("held_out and seed_base name two different clip sets; pass one")
    if seed_base is not None:
        specs = gate_specs(seed_base)[:limit]
    elif held_out:
        specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[:limit]]
    else:
        specs = clip_specs()[:limit]
    label = HELD_OUT if held_out else gate_key(seed_base) if seed_base is not None else BENCHMARK
    clips = []
    for spec in tqdm([at_pixels(s, render_pixels) for s in specs], desc=f"focal {label}", unit="clip"):
        sequence = spec.render()
        estimated = model.reconstruct(sequence.rgb).cameras(**(recipe or {})).intrinsics[:, 0, 0]
        true = sequence.intrinsics[:, 0, 0]
        errors = np.abs(estimated / true - 1.0)
        clips.append({"name": spec.name, "size": [spec.height, spec.width],
                      "true_fx_median": float(np.median(true)), "estimated_fx_median": float(np.median(estimated)),
                      "focal_error": float(np.median(errors))})
    errors = [c["focal_error"] for c in clips]
    return {"clips": clips, "median_focal_error": float(np.median(errors)), "mean_focal_error": float(np.mean(errors))}


def tum_focal(model: D4RT, recipe: dict | None = None) -> dict:
    """The median estimated fx over the bundled TUM frames, against the published calibration (recipe: as for
    :func:`synthetic_focal_errors`)."""
    frames = load_frames(tum_frames_dir())
    fx = float(np.median(model.reconstruct(frames.rgb).cameras(**(recipe or {})).intrinsics[:, 0, 0]))
    return {"frames": len(frames.rgb), "size": list(frames.rgb.shape[1:3]), "estimated_fx": fx,
            "published_fx": TUM_FX, "relative_error": fx / TUM_FX - 1.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default=None, help="model directory (default: the bundled model)")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write")
    parser.add_argument("--limit", type=int, default=None, help="only the first N benchmark clips")
    parser.add_argument("--held-out", action="store_true",
                        help="the benchmark's clip definitions from seeds it never uses, instead of its clips")
    parser.add_argument("--gate-seed", type=int, default=None, metavar="N",
                        help="the benchmark's clip definitions from seeds N + index (a judge's gate set)")
    parser.add_argument("--camera", choices=("per-frame", "single"), default="per-frame",
                        help="fit each frame's intrinsics (the paper's recipe) or one camera to all frames")
    parser.add_argument("--square-pixels", action="store_true", help="fit one focal length to x and y (fx = fy)")
    parser.add_argument("--render-pixels", type=float, default=None, metavar="N",
                        help="render the synthetic clips at about N pixels per frame, aspect kept (default: their size)")
    args = parser.parse_args()
    if args.gate_seed is not None and args.held_out:
        parser.error("--held-out and --gate-seed name two different clip sets; pass one")
    if args.render_pixels is not None and args.render_pixels < 64:
        parser.error(f"--render-pixels must be at least 64, got {args.render_pixels:g}")
    if args.gate_seed is not None and args.gate_seed not in GATE_SEEDS:
        parser.error(f"--gate-seed must lie in {GATE_SEEDS.start:,}-{GATE_SEEDS.stop - 1:,}, got {args.gate_seed:,}")

    model = D4RT.from_pretrained(args.checkpoint)
    key = HELD_OUT if args.held_out else gate_key(args.gate_seed) if args.gate_seed is not None else BENCHMARK
    recipe = {"camera": args.camera, "square_pixels": args.square_pixels}
    result = {"checkpoint": args.checkpoint or "bundled", "recipe": recipe, "render_pixels": args.render_pixels,
              key: synthetic_focal_errors(model, args.limit, args.held_out, args.gate_seed, recipe, args.render_pixels),
              TUM_FOLDER: tum_focal(model, recipe)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    synthetic, tum = result[key], result[TUM_FOLDER]
    print(f"{key}: median focal error {synthetic['median_focal_error']:.1%} over {len(synthetic['clips'])} clips")
    print(f"{TUM_FOLDER}: fx {tum['estimated_fx']:.1f} px vs published {TUM_FX} ({tum['relative_error']:+.1%})")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
