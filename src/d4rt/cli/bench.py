"""``d4rt bench``: speed and memory of a model preset (random weights) on this machine.

Prints a table and optionally writes every figure as JSON; docs/performance.md says what each means
and how it is measured.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.cli import COMMANDS, parse_size


def _chunks(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"chunk sizes must be comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"chunk sizes must be positive integers, got {text!r}")
    return values


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "bench", help=COMMANDS["bench"],
        description="Measure a model preset with random weights: encoder clips/s, tokens/s, TFLOP/s and MFU; "
                    "decoder queries/s per chunk size with and without the key/value cache; camera-pose FPS; "
                    "the paper's Tab. 3 (most full-video 3D tracks at 60/24/10/1 FPS); dense tracking on "
                    "synthetic-dynamic-v1; peak memory. See docs/performance.md.")
    parser.add_argument("--preset", choices=D4RTConfig.preset_names(), default="tiny", help="model preset (default: tiny)")
    parser.add_argument("--device", default="auto", help="auto (CUDA if available), cpu, cuda or cuda:N")
    parser.add_argument("--dtype", choices=["fp32", "bf16"], default="fp32",
                        help="fp32, or bf16 autocast (parameters stay float32)")
    parser.add_argument("--frames", type=int, help="clip length (default: the preset's max_frames; more raises "
                        "the model's max_frames so the clip stays one window)")
    parser.add_argument("--height", type=int, help="frame height in pixels (default: the preset's input size)")
    parser.add_argument("--width", type=int, help="frame width in pixels (default: the preset's input size)")
    parser.add_argument("--size", metavar="WxH", help="frame size, WIDTHxHEIGHT or N for N x N: --height and --width "
                        "at once")
    parser.add_argument("--queries", type=int, help="random queries per decoder measurement (default 100000)")
    parser.add_argument("--chunks", type=_chunks, help="decoder chunk sizes, comma-separated (default 256,1024,4096; "
                        "256, the preset's default and the memory-derived size are always added)")
    parser.add_argument("--repeats", type=int, help="timed runs per figure, the best kept (default 3)")
    parser.add_argument("--threads", type=int, help="CPU threads for torch (default: torch's choice)")
    parser.add_argument("--compile", action="store_true", help="torch.compile the encoder and decoder")
    parser.add_argument("--video", choices=["random", "synthetic"], help="clip content: uniform noise (default) or a "
                        "rendered scene (implied by --compare-colmap)")
    parser.add_argument("--compare-colmap", action="store_true",
                        help="also run COLMAP SfM (pycolmap, the 'eval' extra) on the same clip at the same size, cold and warm, "
                             "with and without the true intrinsics, each with its ATE and frames registered; a "
                             "run that loses frames is a failure, not a speed-up")
    parser.add_argument("--dense-size", type=int, help="dense-tracking grid side (default: each clip's resolution)")
    parser.add_argument("--pose-grid", type=int, help="points per side of the camera recipe's grid (default: "
                        "the reconstruction default, 12)")
    parser.add_argument("--dense-clips", type=int, help="synthetic-dynamic-v1 clips tracked densely (default 1)")
    parser.add_argument("--tolerance", type=float, help="relative precision of each track count (default 0.02)")
    parser.add_argument("--quick", action="store_true", help="a tiny run for CI: 2 frames of 32x32, 2,048 queries, "
                        "one repeat, a 16x16 dense grid (other options still apply)")
    parser.add_argument("-o", "--out", "--json", dest="json", metavar="PATH",
                        help="write every figure to this JSON file")
    parser.set_defaults(func=run)


def options_from_args(args: argparse.Namespace):
    from d4rt.speed import BenchOptions

    if args.size is not None and (args.height is not None or args.width is not None):
        raise UserError("give either --size or --height/--width, not both")
    height, width = parse_size(args.size, "--size") if args.size is not None else (args.height, args.width)
    values = dict(preset=args.preset, device=args.device, dtype=args.dtype, frames=args.frames, height=height,
                  width=width, queries=args.queries, chunks=args.chunks, repeats=args.repeats, threads=args.threads,
                  compile=args.compile, video=args.video, compare_colmap=args.compare_colmap,
                  dense_size=args.dense_size, dense_clips=args.dense_clips, pose_grid=args.pose_grid,
                  tolerance=args.tolerance,
                  progress=not args.no_progress)
    if args.quick:
        return BenchOptions.quick_options(**values)
    return BenchOptions(**{k: v for k, v in values.items() if v is not None})


def run(args: argparse.Namespace) -> int:
    from d4rt.speed import format_table, run_benchmark, write_json

    options = options_from_args(args)
    if args.json and not Path(args.json).parent.is_dir():  # fail now, not after minutes of measuring
        raise UserError(f"cannot write {args.json}: folder {Path(args.json).parent} does not exist")
    result = run_benchmark(options, log=lambda line: print(line, file=sys.stderr, flush=True))
    print(format_table(result))
    if args.json:
        write_json(args.json, result)
        print(f"wrote {args.json}")
    return 0
