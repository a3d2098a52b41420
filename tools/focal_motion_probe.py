"""How much a model's focal length follows the motion between frames (issue 14's stage-6 diagnosis).

    python tools/focal_motion_probe.py CHECKPOINT [CHECKPOINT ...] --out probe.json

Two probes, both with the paper's pinhole-median recipe (``model.reconstruct(video).cameras()``):

- the 17 real TUM frames (about 1 s apart): fx against the published 535.4 px for all frames, every 2nd and
  every 3rd frame (more motion between frames), each frame twice (less), the first and the last 9;
- 16 synthetic clips drawn like synthetic-dynamic-v1's (every 3rd clip definition) from seeds the benchmark
  never uses (7,000,000 + index), rendered with 16 frames at time strides 1, 3 and 6 (frames 1/12, 3/12 and
  6/12 s apart): the median over clips of log(fx / fx_true) (the bias) and of |fx / fx_true - 1|.

A focal length that is read from the image should not move with the frame spacing. Writes JSON and prints it.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from d4rt.cli.demo import TUM_FX, tum_frames_dir
from d4rt.evaluation.synthetic_benchmark import clip_specs
from d4rt.io.frames import load_frames
from d4rt.model import D4RT
from d4rt.synthetic import render_clip

HELD_OUT_SEED = 7_000_000
STRIDES = (1, 3, 6)


def per_frame_fx(model: D4RT, rgb: np.ndarray) -> np.ndarray:
    """(T,) estimated fx of each frame, pixels."""
    return model.reconstruct(rgb).cameras().intrinsics[:, 0, 0]


def tum_probe(model: D4RT, rgb: np.ndarray) -> dict:
    variants = {"all": rgb, "every 2nd": rgb[::2], "every 3rd": rgb[::3], "each twice": np.repeat(rgb, 2, 0)[:24],
                "first 9": rgb[:9], "last 9": rgb[8:]}
    return {name: float(np.median(per_frame_fx(model, v))) / TUM_FX - 1.0 for name, v in variants.items()}


def synthetic_probe(model: D4RT, clips: dict) -> dict:
    out = {}
    for stride, rendered in clips.items():
        logs = np.array([np.median(np.log(per_frame_fx(model, c.rgb) / c.intrinsics[:, 0, 0])) for c in rendered])
        out[str(stride)] = {"median_log_ratio": float(np.median(logs)),
                            "median_abs_error": float(np.median(np.abs(np.exp(logs) - 1.0)))}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", help="model directories")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write")
    args = parser.parse_args()
    tum = load_frames(tum_frames_dir()).rgb
    specs = [replace(s, seed=HELD_OUT_SEED + s.index) for s in clip_specs()[::3]]
    clips = {stride: [render_clip(s.seed, 16, s.height, s.width, **(vars(s.options) | {"time_stride": stride}))
                      for s in specs] for stride in STRIDES}
    result = {"tum_relative_fx_error": {}, "synthetic_by_time_stride": {}}
    for checkpoint in args.checkpoints:
        model = D4RT.from_pretrained(checkpoint)
        result["tum_relative_fx_error"][checkpoint] = tum_probe(model, tum)
        result["synthetic_by_time_stride"][checkpoint] = synthetic_probe(model, clips)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
