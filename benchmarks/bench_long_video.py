"""Peak memory of `d4rt reconstruct` on a video and on one 4x longer of the same frame size (issue 19:
frames read lazily, window by window, and the outputs that grow with the video written a block at a time,
so peak memory does not grow with the video's length; target: the longer video's peak within 15%).

    python benchmarks/bench_long_video.py [--frames 48] [--size 320x240] [--old TREE] [--out results.json]

The video: a rendered clip of ``--frames`` frames written as an H.264 .mp4 (what users have), and the same
clip played forward, backward, forward, backward (4x as long, no shot cuts). Each is reconstructed by a
fresh `python -m d4rt reconstruct` process with every default output (the bundled model, the default
resolution); its peak memory is the process's maximum resident set (wait4's ru_maxrss) and its time the
wall time. ``--old TREE`` also runs an older tree (e.g. a git worktree of the commit before) the same way.
Prints a table and writes JSON (--out).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_reconstruct import HERE, cpu_name, run_tree  # noqa: E402  (a sibling script)

TARGET = 1.15  # the longer video's peak memory over the shorter one's


def make_videos(folder: Path, frames: int, height: int, width: int) -> tuple[Path, Path]:
    from d4rt.io.video import write_video
    from d4rt.synthetic import render_clip

    clip = render_clip(19, frames, height, width, environment="room", num_objects=5, camera_motion="orbit")
    short = write_video(folder / f"short-{frames}.mp4", clip.rgb, fps=12)
    back_and_forth = np.concatenate([clip.rgb, clip.rgb[::-1], clip.rgb, clip.rgb[::-1]])
    return short, write_video(folder / f"long-{4 * frames}.mp4", back_and_forth, fps=12)


def output_mib(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=48, help="frames of the shorter video (default: 48)")
    parser.add_argument("--size", default="320x240", help="WIDTHxHEIGHT of the frames (default: 320x240)")
    parser.add_argument("--old", type=Path, default=None, help="also run this older tree (its src/ on PYTHONPATH)")
    parser.add_argument("--out", type=Path, default=None, help="JSON file to write")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    sys.path.insert(0, str(HERE / "src"))  # this tree's d4rt, installed or not
    trees = {"new": HERE} | ({"old": args.old.resolve()} if args.old else {})
    print(f"CPU: {cpu_name()}", flush=True)
    work = Path(tempfile.mkdtemp(prefix="d4rt-long-video-"))
    try:
        videos = make_videos(work, args.frames, height, width)
        checkpoint = HERE / "src" / "d4rt" / "assets" / "d4rt-tiny"
        rows = []
        for name, tree in trees.items():
            for video, frames in zip(videos, (args.frames, 4 * args.frames)):
                out = work / f"out-{name}-{frames}"
                run = run_tree(tree, video, out, checkpoint, [])
                run.update(tree=name, frames=frames, outputs_mib=output_mib(out))
                rows.append(run)
                shutil.rmtree(out)
                print(f"{name} code, {frames} frames of {width}x{height}: peak {run['peak_mib']:.0f} MiB, "
                      f"{run['seconds']:.0f} s, outputs {run['outputs_mib']:.0f} MiB", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    result = {"cpu": cpu_name(), "size": [width, height], "frames": [args.frames, 4 * args.frames], "runs": rows,
              "target_ratio": TARGET}
    print(f"\n| code | {args.frames} frames: peak MiB | {4 * args.frames} frames: peak MiB | ratio |")
    print("|---|---|---|---|")
    for name in trees:
        short, long = (r for r in rows if r["tree"] == name)
        ratio = long["peak_mib"] / short["peak_mib"]
        result[f"{name}_ratio"] = ratio
        print(f"| {name} | {short['peak_mib']:.0f} | {long['peak_mib']:.0f} | {ratio:.2f}x |")
    verdict = "met" if result["new_ratio"] <= TARGET else "missed"
    print(f"\ntarget: the {4 * args.frames}-frame peak within {TARGET - 1:.0%} of the {args.frames}-frame one: {verdict}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
