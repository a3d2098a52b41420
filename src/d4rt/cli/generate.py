"""``d4rt generate``: render synthetic clips with full ground truth to compressed npz files."""

from __future__ import annotations

import json
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from d4rt.progress import progress_bar

from d4rt.errors import UserError
from d4rt.synthetic.sampling import CAMERA_MOTIONS
from d4rt.cli import COMMANDS, parse_size


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "generate", help=COMMANDS["generate"],
        description="Render N synthetic clips; clip i uses seed SEED + i and is written to "
                    "OUT/clip_<i>.npz (same arguments, same files, bit for bit).")
    p.add_argument("-o", "--out", required=True, help="output directory (clips of the same names are replaced)")
    p.add_argument("--num-clips", type=int, required=True, help="how many clips to render")
    p.add_argument("--frames", type=int, default=16, help="frames per clip (default 16)")
    p.add_argument("--size", metavar="WxH", default=None,
                   help="frame size, WIDTHxHEIGHT or N for N x N (default 128x128); or --height and --width")
    p.add_argument("--height", type=int, default=None, help="frame height in pixels (default 128)")
    p.add_argument("--width", type=int, default=None, help="frame width in pixels (default 128)")
    p.add_argument("--seed", type=int, default=0, help="seed of clip 0; clip i uses SEED + i (default 0)")
    p.add_argument("--environment", choices=["room", "outdoor"], default=None,
                   help="scene kind (default: random per clip)")
    p.add_argument("--camera-motion", choices=CAMERA_MOTIONS, default=None,
                   help="how the camera moves (default: random per clip)")
    p.add_argument("--num-objects", type=int, default=None, help="rigid objects in the scene (default: 3 to 8 "
                   "per clip)")
    p.add_argument("--fov", type=float, nargs=2, metavar=("LOW", "HIGH"), default=None,
                   help="field-of-view range in degrees across the longer side (default 35 90)")
    p.add_argument("--aspect", type=float, nargs=2, metavar=("LOW", "HIGH"), default=None,
                   help="draw each clip's width / height log-uniformly from this range, keeping about "
                        "height x width pixels (default: every clip height x width)")
    p.add_argument("--time-stride", type=int, default=1, help="frame k shows time k * stride / fps")
    p.add_argument("--aa-samples", type=int, default=2, help="n x n supersampling of edge pixels (1 = off)")
    p.add_argument("--device", default="cpu", help="torch device to ray-cast on")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (CPU)")
    p.set_defaults(func=run)


def _render_one(job: dict) -> str:
    import torch

    from d4rt.synthetic import render_clip

    torch.set_num_threads(job.pop("threads"))
    path = job.pop("path")
    render_clip(**job).save(path)
    return path


def clip_size(seed: int, height: int, width: int, aspect: tuple[float, float] | None) -> tuple[int, int]:
    """(height, width) of clip ``seed``: as given, or about height x width pixels at a width / height drawn
    log-uniformly from ``aspect`` (a function of the seed, so the same arguments give the same files)."""
    if aspect is None:
        return height, width
    ratio = math.exp(np.random.default_rng([seed, 0xA5]).uniform(math.log(aspect[0]), math.log(aspect[1])))
    pixels = height * width
    return max(8, int(round(math.sqrt(pixels / ratio)))), max(8, int(round(math.sqrt(pixels * ratio))))


def run(args) -> int:
    if args.size is not None and (args.height is not None or args.width is not None):
        raise UserError("give either --size or --height/--width, not both")
    if args.size is not None:
        args.height, args.width = parse_size(args.size, "--size")
    args.height, args.width = args.height or 128, args.width or 128
    if args.num_clips < 1:
        raise UserError(f"--num-clips must be at least 1, got {args.num_clips}")
    if args.frames < 1:
        raise UserError(f"--frames must be at least 1, got {args.frames}")
    if not (8 <= args.height <= 4096 and 8 <= args.width <= 4096):
        raise UserError(f"--height and --width must be between 8 and 4096, got {args.height}x{args.width}")
    if args.seed < 0:
        raise UserError(f"--seed must be non-negative, got {args.seed}")
    if args.aspect is not None and not 0 < args.aspect[0] <= args.aspect[1]:
        raise UserError(f"--aspect must be a positive LOW HIGH range, got {args.aspect[0]} {args.aspect[1]}")
    if args.workers < 1:
        raise UserError(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    options = {k: v for k, v in {"environment": args.environment, "camera_motion": args.camera_motion,
                                 "num_objects": args.num_objects, "time_stride": args.time_stride,
                                 "fov_degrees": tuple(args.fov) if args.fov else None}.items()
               if v is not None}
    from d4rt.synthetic.sampling import SceneOptions

    SceneOptions(**options).validate()  # fail before any work
    width = max(5, len(str(args.num_clips - 1)))
    threads = 1 if args.workers > 1 else max(1, os.cpu_count() or 1)
    sizes = [clip_size(args.seed + i, args.height, args.width, args.aspect) for i in range(args.num_clips)]
    jobs = [dict(seed=args.seed + i, frames=args.frames, height=h, width=w, device=args.device,
                 aa_samples=args.aa_samples, threads=threads, path=str(out / f"clip_{i:0{width}d}.npz"), **options)
            for i, (h, w) in enumerate(sizes)]
    manifest = {"seeds": [j["seed"] for j in jobs], "files": [Path(j["path"]).name for j in jobs],
                "frames": args.frames, "height": args.height, "width": args.width,
                "aspect": list(args.aspect) if args.aspect else None, "sizes": [list(s) for s in sizes],
                "scene_options": {k: list(v) if isinstance(v, tuple) else v for k, v in options.items()},
                "aa_samples": args.aa_samples}
    bar = progress_bar(total=len(jobs), desc="generate", unit="clip")
    if args.workers == 1:
        for job in jobs:
            _render_one(job)
            bar.update()
    else:
        with ProcessPoolExecutor(args.workers) as pool:
            for _ in pool.map(_render_one, jobs):
                bar.update()
    bar.close()
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    print(f"wrote {len(jobs)} clips to {out}")
    return 0
