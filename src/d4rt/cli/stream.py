"""``d4rt stream SOURCE -o OUT_DIR``: reconstruct frames as they arrive (d4rt.reconstruction.streaming).

SOURCE is a video file, a URL or a camera device FFmpeg opens (``--format v4l2`` for /dev/video0), or
``-`` for raw rgb24 frames on stdin (``--size WxH``). Each window, once encoded and decoded, is written
to ``OUT_DIR/window_NNN.npz`` (atomically) and appended to ``OUT_DIR/trajectory_tum.txt``; at the end
``OUT_DIR/stream.json`` sums up. Ctrl-C (or SIGTERM) ends the stream after the frame being read: the frames
received so far make the last window, so the files stay consistent; a second one stops at once.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys

from d4rt.cli import COMMANDS, parse_size
from d4rt.config import POSE_PAIRS
from d4rt.errors import UserError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "stream", help=COMMANDS["stream"],
        description="Reconstruct a live video window by window as its frames arrive: cameras (and depth maps "
                    "with --depth-resolution) per window, written as each window is done.")
    p.add_argument("source", metavar="SOURCE",
                   help="a video file, a URL or a camera device FFmpeg opens, or '-' for raw rgb24 frames on stdin "
                        "(with --size)")
    p.add_argument("-o", "--out", required=True, metavar="OUT_DIR", help="output directory (new or empty)")
    p.add_argument("--overwrite", action="store_true", help="empty a non-empty OUT_DIR first")
    p.add_argument("--size", metavar="WxH", default=None, help="frame size of raw frames on stdin (SOURCE '-')")
    p.add_argument("--format", default=None,
                   help="FFmpeg input format for devices (e.g. v4l2 for /dev/video0, avfoundation on macOS)")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate for the trajectory's time stamps when the source has no clock (default: 30 "
                        "for stdin)")
    p.add_argument("--window", type=int, default=None, help="frames per window (default: the model's maximum)")
    p.add_argument("--overlap", type=int, default=None,
                   help="frames shared by consecutive windows (default: a quarter of the window)")
    p.add_argument("--depth-resolution", default=None, metavar="WxH",
                   help="also decode depth maps of every frame at this size, or 'encoder' (default: cameras only)")
    p.add_argument("--pose-pairs", choices=POSE_PAIRS,
                   help="which camera each frame's pose is fitted against: the window's 'first' or the previous "
                        "frame's, the fits chained ('adjacent'), or frames i-1, i-2, i-4, ... solved together ('graph'); "
                        "default: the model's own (its config's pose_pairs)")
    p.add_argument("--flip-average", action=argparse.BooleanOptionalAction, default=None,
                   help="answer every query on the video and on its left-right mirror and average the two (two encoder "
                        "passes, twice the queries); default: the model's own choice (its config's flip_average)")
    p.add_argument("--checkpoint", metavar="DIR", default=None,
                   help="a directory written by D4RT.save_pretrained (default: the bundled model)")
    p.add_argument("--device", default="auto", help="torch device: auto (the default), cpu, cuda, cuda:1, ...")
    p.add_argument("--dtype", choices=("auto", "bf16", "fp32"), default="auto",
                   help="auto (the default): bfloat16 autocast where the device computes it natively, else float32")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from d4rt.io.formats import check_output_dir

    if args.source == "-" and args.size is None:
        raise UserError("raw frames on stdin (SOURCE '-') need --size WIDTHxHEIGHT")
    if args.source != "-" and args.size is not None:
        raise UserError("--size is for raw frames on stdin (SOURCE '-'); a video source knows its size")
    size = parse_size(args.size, "--size") if args.size else None
    depth_option = args.depth_resolution
    if depth_option not in (None, "encoder"):
        depth_option = parse_size(depth_option, "--depth-resolution")
    if args.fps is not None and args.fps <= 0:
        raise UserError(f"--fps must be positive, got {args.fps}")
    out_dir = check_output_dir(args.out, args.overwrite)
    if args.source != "-" and "://" not in args.source and args.format is None and not Path(args.source).exists():
        raise UserError(f"{args.source} does not exist")

    from contextlib import nullcontext

    import torch

    from d4rt.cli.reconstruct import load_model
    from d4rt.devices import native_bf16, resolve_device
    from d4rt.io.video import iter_raw_frames, iter_video

    device = resolve_device(args.device, "--device")
    bf16 = args.dtype == "bf16" or (args.dtype == "auto" and native_bf16(device))
    model = load_model(args.checkpoint, device)
    if size is not None:
        frames = ((frame, None) for frame in iter_raw_frames(sys.stdin.buffer, *size))
    else:
        frames = iter_video(args.source, args.format)
    if out_dir.exists():  # empty, or --overwrite: start afresh
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    autocast = torch.autocast(device.type, dtype=torch.bfloat16) if bf16 else nullcontext()
    with autocast, torch.inference_mode():
        summary = stream_to_folder(model, frames, out_dir, args, depth_option)
    print(f"d4rt stream: {summary['frames']} frames in {summary['windows']} windows; latency per window "
          f"{summary['latency_median_s']:.2f} s median, {summary['latency_max_s']:.2f} s max; wrote {out_dir}/")
    return 0


def stream_to_folder(model, frames, out_dir, args, depth_option) -> dict:
    """Push every frame of ``frames`` ((H, W, 3) uint8, time or None) through a StreamingReconstruction and
    write each window's result as it comes; Ctrl-C or SIGTERM ends the stream early, cleanly (the trainer's
    StopRequest: the first signal sets a flag, a second stops at once)."""
    import numpy as np

    from d4rt.reconstruction.streaming import StreamingReconstruction
    from d4rt.training.stop import StopRequest

    stream = None
    times: list[float] = []
    latencies: list[float] = []
    windows = 0
    fps = args.fps or 30.0

    def write(results) -> None:
        nonlocal windows
        for result in results:
            write_window(out_dir, windows, result, np.asarray([times[i] for i in result.frames]))
            latencies.append(result.seconds)
            print(f"window {windows}: frames {result.frames[0]}..{result.frames[-1]} in {result.seconds:.2f} s",
                  flush=True)
            windows += 1

    with StopRequest() as stop:
        for frame, stamp in frames:
            if stream is None:
                h, w = frame.shape[:2]
                depth_size = None
                if depth_option == "encoder":
                    from d4rt.reconstruction.reconstruction import encoder_resolution

                    size = model.config.image_size
                    depth_size = encoder_resolution(h, w, (size, size))
                elif depth_option is not None:
                    depth_size = depth_option
                stream = StreamingReconstruction.from_model(model, window=args.window, overlap=args.overlap,
                                                            depth_size=depth_size, pose_pairs=args.pose_pairs,
                                                            flip_average=args.flip_average)
            times.append(stamp if stamp is not None else len(times) / fps)
            write(stream.push(frame))
            if stop.requested:
                print(f"d4rt stream: {stop.requested}; the frames received so far make the last window",
                      file=sys.stderr)
                break
    if stream is None:
        raise UserError(f"{args.source} gave no frames")
    write(stream.finish())
    summary = {"frames": stream.count, "windows": windows, "window": stream.window, "overlap": stream.overlap,
               "latency_s": latencies, "latency_median_s": float(np.median(latencies)),
               "latency_max_s": float(np.max(latencies)), "stopped_by": stop.requested}
    (out_dir / "stream.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def write_window(out_dir, index: int, result, timestamps) -> None:
    """``window_NNN.npz`` (atomically: write then rename) and the window's lines of the TUM trajectory."""
    import os

    import numpy as np

    from d4rt.io.trajectory import HEADER, tum_lines

    arrays = {"frames": result.frames, "cam_to_world": result.cam_to_world, "intrinsics": result.intrinsics,
              "window": np.array(result.window), "seconds": np.float64(result.seconds), "timestamps": timestamps}
    if result.depth is not None:
        arrays.update(depth=result.depth, confidence=result.confidence)
    temp = out_dir / f".window_{index:03d}.npz.tmp"
    with open(temp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(temp, out_dir / f"window_{index:03d}.npz")
    trajectory = out_dir / "trajectory_tum.txt"
    with open(trajectory, "a") as fh:
        if index == 0:
            fh.write(HEADER)
        fh.writelines(tum_lines(timestamps, result.cam_to_world))
