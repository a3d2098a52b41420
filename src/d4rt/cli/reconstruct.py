"""``d4rt reconstruct INPUT -o OUT_DIR``: a video (file, image folder or array) to every 4D output; many
videos (d4rt.cli.collection) to one output folder each, sharded across the processes of torchrun.

A thin layer over the Python API: ``load_frames`` -> ``Reconstruction.from_model`` ->
``d4rt.io.exports.export_reconstruction``.
"""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import nullcontext
from pathlib import Path

import numpy as np
from d4rt.progress import progress_bar

from d4rt.config import MOTION_TARGETS, MOTION_THRESHOLD, POSE_PAIRS, check_motion_options
from d4rt.errors import UserError
from d4rt.io.formats import CAMERA_CHOICES, COLMAP_VIEWS, DEFAULT_MAX_POINTS, FORMATS, ON_REQUEST, POINT_SOURCES
from d4rt.io.shots import DEFAULT_THRESHOLD as DEFAULT_CUT_THRESHOLD
from d4rt.cli import COMMANDS, parse_size


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "reconstruct", help=COMMANDS["reconstruct"],
        description="Reconstruct a video in 4D with a D4RT model and write the outputs (units and conventions: "
                    "docs/outputs.md).")
    p.add_argument("input", metavar="INPUT", nargs="+",
                   help="a video file (.mp4 .mov .avi .webm .mkv), a folder of images, or an .npy/.npz array "
                        "(T, H, W, 3); or many videos: several paths, a folder of video files, a quoted glob "
                        "pattern, or a .txt file listing paths (one output folder each, OUT_DIR/summary.jsonl; "
                        "sharded across processes under torchrun; a re-run skips the finished ones)")
    p.add_argument("-o", "--out", required=True, metavar="OUT_DIR",
                   help="output directory (new or empty; see --overwrite); for many videos, the folder that "
                        "holds one output folder per video")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a non-empty OUT_DIR as a whole (atomically, once every new file is written); "
                        "for many videos, reconstruct every one again")
    p.add_argument("--retry-failed", action="store_true",
                   help="for many videos: also retry those an earlier run recorded as failed in summary.jsonl")
    frames = p.add_argument_group("frames")
    frames.add_argument("--start", type=int, default=0, help="first frame, 0-based (default: 0)")
    frames.add_argument("--end", type=int, default=None, help="stop before this frame (default: the last)")
    frames.add_argument("--stride", type=int, default=1, help="use every n-th frame (default: 1)")
    frames.add_argument("--max-frames", type=int, default=None,
                        help="use at most this many frames; videos longer than the model's window are cut into "
                             "overlapping windows and stitched")
    frames.add_argument("--window", type=int, default=None, help="frames per window (default: the model's maximum)")
    frames.add_argument("--overlap", type=int, default=None, help="frames shared by consecutive windows "
                                                                  "(default: a quarter of the window)")
    model = p.add_argument_group("model")
    model.add_argument("--checkpoint", metavar="DIR", default=None,
                       help="a directory written by D4RT.save_pretrained (default: the bundled model)")
    model.add_argument("--device", default="auto",
                       help="torch device: auto (the default: cuda if available), cpu, cuda, cuda:1, ...")
    model.add_argument("--dtype", choices=("auto", "bf16", "fp32"), default="auto",
                       help="auto (the default): bfloat16 autocast where the device computes it natively (GPUs, "
                            "CPUs with AMX-BF16 or AVX512-BF16), else float32 (emulated bf16 is slower)")
    model.add_argument("--bf16", action="store_const", const="bf16", dest="dtype", help="same as --dtype bf16")
    model.add_argument("--threads", type=int, default=None, metavar="N",
                       help="CPU threads for torch (default: torch's choice, one per core; queries are decoded in "
                            "chunks of 4,096, where more threads pay: docs/performance.md)")
    model.add_argument("--chunk-size", type=int, default=None, metavar="N",
                       help="queries the decoder answers at once (default: the model's query_chunk_size, 4,096 for "
                            "the bundled one): lower it to bound memory on a small GPU, raise it on a large one; "
                            "the answers do not depend on it. --window bounds the encoder's memory")
    outputs = p.add_argument_group("outputs")
    outputs.add_argument("--intrinsics", metavar="FX,FY,CX,CY", default=None,
                         help="known intrinsics in pixels of the input frames, OpenCV convention (top-left pixel "
                              "centre at 0,0); they replace the estimated ones")
    frames.add_argument("--cut-threshold", type=float, default=DEFAULT_CUT_THRESHOLD, metavar="D",
                        help="a shot cut is a jump of the colour histogram between frames above D (0-1; default "
                             f"{DEFAULT_CUT_THRESHOLD}) that stands out from its neighbours; each shot is reconstructed "
                             "on its own into OUT_DIR/shot_NNN/ with a summary in shots.json")
    frames.add_argument("--no-cut-detection", action="store_true",
                        help="treat the video as one shot (stitch through cuts)")
    outputs.add_argument("--camera", choices=CAMERA_CHOICES, default="auto",
                         help="estimated intrinsics: 'single' camera for the whole video (what splatting and MVS "
                              "tools expect), one 'per-frame' (the paper's recipe; for zooming shots) or 'auto' (the "
                              "default: single unless the per-frame focal lengths differ by more than 15%%)")
    outputs.add_argument("--pose-pairs", choices=POSE_PAIRS,
                         help="which camera each frame's pose is fitted against: the window's 'first' (the paper's "
                              "recipe) or the previous frame's, the fits chained ('adjacent': every query a "
                              "one-frame gap, but errors add up along the chain) or frames i-1, i-2, i-4, ... solved "
                              "together by least squares ('graph'); default: the model's own choice "
                              "(its config's pose_pairs)")
    outputs.add_argument("--flip-average", action=argparse.BooleanOptionalAction, default=None,
                         help="answer every query on the video and on its left-right mirror and average the "
                              "two (two encoder passes, twice the queries); default: the model's own choice (its "
                              "config's flip_average)")
    outputs.add_argument("--non-square-pixels", action="store_true",
                         help="estimate fx and fy separately (default: square pixels, fx = fy)")
    outputs.add_argument("--resolution", default="auto",
                         help="depth maps at 'auto' (the default: the input's size up to 640x480 pixels' worth, "
                              "larger inputs scaled down at their aspect ratio with a notice), 'original' (the input's "
                              "size, however large: one query per pixel and frame), 'encoder' (about the model's input "
                              "pixel count, at the input's aspect ratio) or WIDTHxHEIGHT")
    outputs.add_argument("--min-confidence", type=float, default=None, metavar="C",
                         help="drop points and depth pixels below this confidence (default: keep all). The scale is "
                              "the model's own: positive, higher is more certain, comparable within one video only "
                              "(the bundled model's lie around 0.2-0.6); reconstruction.npz keeps every value to "
                              "choose from. A threshold that leaves nothing is an error that prints the range")
    outputs.add_argument("--points-from", choices=POINT_SOURCES, default="depth",
                         help="point cloud from the decoded depth maps and cameras (the default: no further "
                              "query) or from 'queries' (the paper's direct recipe: every pixel queried again in "
                              "camera 0; about as many queries again as the depth maps)")
    outputs.add_argument("--point-stride", type=int, default=None, metavar="N",
                         help="point cloud from every n-th pixel (default: as dense as the depth maps)")
    outputs.add_argument("--max-points", type=int, default=DEFAULT_MAX_POINTS, metavar="N",
                         help=f"at most N points in the COLMAP model (default: {DEFAULT_MAX_POINTS:,}): confident pixels "
                              f"spread evenly over the scene, each queried in {COLMAP_VIEWS} frames of its window and kept "
                              "where seen in 2 or more")
    outputs.add_argument("--tracks", type=int, default=16, metavar="N",
                         help="track an N x N grid of points (default: 16; 0: no tracks)")
    outputs.add_argument("--track-frame", type=int, default=0, metavar="F",
                         help="frame the tracked grid starts from (default: 0)")
    outputs.add_argument("--dense-resolution", default=None, metavar="WxH",
                         help="grid of the dense-tracks output: 'encoder' (the default), 'original' (the input's size: "
                              "T*H*W tracks, costly) or WIDTHxHEIGHT")
    outputs.add_argument("--known-poses", default=None, metavar="FILE",
                         help="camera poses of your own (SLAM, motion capture, GPS/IMU, ground truth): a TUM "
                              "trajectory (.txt, matched to the frames by time) or a .npy of (N, 4, 4) camera-to-world "
                              "matrices, one per source frame; every output is carried into their world and units by "
                              "the Sim(3) that maps the estimated cameras onto them (docs/outputs.md)")
    outputs.add_argument("--scale", type=float, default=None, metavar="S",
                         help="multiply every length (depth, points, tracks, camera positions) by S, e.g. a known "
                              "distance over the reconstruction's (the model's units are not metric)")
    outputs.add_argument("--motion-resolution", default=None, metavar="WxH",
                         help="size of the motion-masks output: 'encoder' (the default), 'original' (the input's "
                              f"size; {MOTION_TARGETS + 1} queries per pixel, costly) or WIDTHxHEIGHT")
    outputs.add_argument("--motion-threshold", type=float, default=None, metavar="F",
                         help="motion-masks output: a surface is moving when it travels more than this fraction of "
                              f"its depth between its frame and {MOTION_TARGETS} frames spread over its window "
                              f"(default: the model's own, motion_threshold in its config.json; {MOTION_THRESHOLD} "
                              "where it has none)")
    outputs.add_argument("--outputs", default="all",
                         help=f"comma-separated outputs to write: {', '.join(FORMATS)} (default: all, which leaves "
                              f"out the costly {', '.join(ON_REQUEST)})")
    p.set_defaults(func=run)


def parse_intrinsics(text: str) -> np.ndarray:
    """'fx,fy,cx,cy' (pixels) -> K (3, 3)."""
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"--intrinsics must be four numbers fx,fy,cx,cy, got {text!r}") from None
    if not all(np.isfinite([fx, fy, cx, cy])) or fx <= 0 or fy <= 0:
        raise UserError(f"--intrinsics needs finite values and positive focal lengths, got {text!r}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


# The default output size: the input's, at most this many pixels (VGA's): 4 frames of 12 megapixels would
# otherwise decode some 100M queries unasked; --resolution original asks for every input pixel.
MAX_DEFAULT_PIXELS = 640 * 480


def parse_resolution(text: str, option: str = "--resolution"):
    """'original' -> None, 'encoder' -> 'encoder', 'auto' -> 'auto' (--resolution only), 'WxH' -> (H, W);
    a bad value names ``option``."""
    if text in ("original", "encoder") or (text == "auto" and option == "--resolution"):
        return None if text == "original" else text
    try:
        if "x" not in text.lower():  # a lone N would mean N x N: a square that ignores the video's shape
            raise UserError(text)
        return parse_size(text, option)
    except UserError:
        choices = "'auto', 'original', 'encoder'" if option == "--resolution" else "'original', 'encoder'"
        raise UserError(f"{option} must be {choices} or WIDTHxHEIGHT (e.g. 640x480), got {text!r}") from None


def default_resolution(height: int, width: int, max_pixels: int = MAX_DEFAULT_PIXELS):
    """The 'auto' output size of a height x width input: None (the input's own) up to ``max_pixels``, else
    (h, w) of about ``max_pixels`` at the input's aspect ratio, with a one-line notice."""
    if height * width <= max_pixels:
        return None
    from d4rt.reconstruction.reconstruction import encoder_resolution

    h, w = encoder_resolution(height, width, (max_pixels, 1))
    print(f"d4rt: outputs at {w}x{h}, not the input's {width}x{height} (one query per output pixel and frame); "
          "--resolution original keeps the input's size", file=sys.stderr)
    return h, w


def has_bundled_model() -> bool:
    from d4rt.model.weights import bundled_model_dir

    return (bundled_model_dir() / "model.safetensors").is_file()


def load_model(checkpoint: str | None, device, chunk_size: int | None = None):
    """The model of ``checkpoint`` (None: the bundled one) on ``device``, answering ``chunk_size`` queries at a time
    (None: its config's query_chunk_size)."""
    from d4rt.model import D4RT

    if checkpoint is None and not has_bundled_model():
        raise UserError("no trained model ships with this version of d4rt yet: pass --checkpoint DIR (written by "
                        "D4RT.save_pretrained), or run `d4rt demo` to see every output on a synthetic clip")
    model = D4RT.from_pretrained(checkpoint, device=device)
    if chunk_size is not None:
        model.config = model.config.replace(query_chunk_size=chunk_size)
    return model


LARGE_QUERIES = 20_000_000  # above this many decoded queries, a one-line notice before the work starts


def describe_work(rec, formats, resolution, point_stride: int | None, track_grid: int, max_points: int,
                  points_from: str = "depth") -> str:
    """One line, printed before any decoding: the output sizes and about how many queries they cost
    (the depth maps and the point cloud decode one query per output pixel, tracks one per point and
    frame), with a notice and the cheaper options when that is a lot."""
    from d4rt.io.formats import FORMAT_NEEDS

    needs = set().union(*(FORMAT_NEEDS[f] for f in formats))
    derived = points_from == "depth"
    t = rec.num_frames
    out_h, out_w = rec.output_size(resolution)
    stride = point_stride or max(1, int(min(rec.height / out_h, rec.width / out_w)))
    counts = {"depth": t * out_h * out_w if "depth" in needs or ("points" in needs and derived) else 0,
              "points": t * -(-rec.height // stride) * -(-rec.width // stride) if "points" in needs and not derived
              else 0,
              "tracks": track_grid * track_grid * t if "tracks" in needs else 0,
              "colmap": max_points * min(t, COLMAP_VIEWS) if "colmap-points" in needs else 0}
    total = sum(counts.values())
    parts = []
    if counts["depth"]:
        parts.append(f"depth maps {out_w}x{out_h}")
    if "points" in needs and derived:
        parts.append("point cloud from the depth maps")
    elif counts["points"]:
        parts.append("point cloud from every pixel" if stride == 1 else f"point cloud from 1 pixel in {stride}x{stride}")
    if counts["tracks"]:
        parts.append(f"{track_grid}x{track_grid} tracks")
    if counts["colmap"]:
        parts.append(f"up to {max_points:,} COLMAP points")
    line = f"outputs: {', '.join(parts) or 'cameras only'}: about {total / 1e6:.1f}M queries to decode"
    if total > LARGE_QUERIES:
        line += (" - a lot for this machine; --resolution encoder, --point-stride N or --outputs narrow it, "
                 "--max-frames/--stride shorten the video")
    return line


def run(args) -> int:
    from d4rt.cli.collection import is_collection
    from d4rt.io.formats import check_output_dir, parse_formats
    from d4rt.io.frames import FrameRange, check_input

    # Every option is checked before any work (and before torch loads), so a bad one costs nothing and
    # writes nothing.
    many = is_collection(args.input)
    if not many:
        check_input(args.input[0])
    intrinsics = parse_intrinsics(args.intrinsics) if args.intrinsics else None
    resolution = parse_resolution(args.resolution)
    dense_resolution = (args.dense_resolution if args.dense_resolution in (None, "original")
                        else parse_resolution(args.dense_resolution, "--dense-resolution"))
    motion_resolution = (args.motion_resolution if args.motion_resolution in (None, "original")
                         else parse_resolution(args.motion_resolution, "--motion-resolution"))
    if args.motion_threshold is not None:
        check_motion_options(args.motion_threshold, MOTION_TARGETS)
    if args.known_poses is not None and args.scale is not None:
        raise UserError("give --known-poses or --scale, not both (known poses fix the scale themselves)")
    if args.scale is not None and not (np.isfinite(args.scale) and args.scale > 0):
        raise UserError(f"--scale must be a finite number > 0, got {args.scale}")
    if args.known_poses is not None and not Path(args.known_poses).is_file():
        raise UserError(f"--known-poses {args.known_poses} does not exist")
    formats = parse_formats(args.outputs)
    selection = FrameRange(args.start, args.end, args.stride, args.max_frames)
    if args.threads is not None and args.threads < 1:
        raise UserError(f"--threads must be >= 1, got {args.threads}")
    if args.chunk_size is not None and args.chunk_size < 1:
        raise UserError(f"--chunk-size must be >= 1, got {args.chunk_size}")
    save_options = dict(resolution=resolution, intrinsics=intrinsics, camera=args.camera,
                        square_pixels=not args.non_square_pixels, min_confidence=args.min_confidence,
                        point_stride=args.point_stride, points_from=args.points_from, track_grid=args.tracks,
                        track_frame=args.track_frame, dense_resolution=dense_resolution, max_points=args.max_points,
                        motion_resolution=motion_resolution, motion_threshold=args.motion_threshold, scale=args.scale,
                        progress=True)
    if args.threads is not None:
        import torch

        torch.set_num_threads(args.threads)
    if many:
        return run_many(args, selection, formats, save_options)
    out_dir = check_output_dir(args.out, args.overwrite)

    from d4rt.devices import native_bf16, resolve_device
    from d4rt.io.exports import spool_folder
    from d4rt.io.frames import load_frames

    device = resolve_device(args.device, "--device")
    bf16 = args.dtype == "bf16" or (args.dtype == "auto" and native_bf16(device))
    with spool_folder(out_dir) as spool:  # the frames wait on disk and are read window by window
        frames = load_frames(args.input[0], selection, progress=True, spool=spool)
        model = load_model(args.checkpoint, device, args.chunk_size)
        reconstruct_frames(model, frames, out_dir, args, formats, save_options, bf16, overwrite=args.overwrite)
    return 0


def run_many(args, selection, formats, save_options) -> int:
    """Many inputs (d4rt.cli.collection): this process's share of them, the model loaded once; under
    torchrun every rank runs this with its own share."""
    from d4rt.cli.collection import expand_inputs, run_collection
    from d4rt.devices import native_bf16
    from d4rt.io.exports import spool_folder
    from d4rt.io.frames import load_frames
    from d4rt.training.distributed import DistributedContext

    inputs = expand_inputs(args.input)
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"{out_dir} exists and is not a folder")
    context = DistributedContext.from_environment(args.device)
    try:
        bf16 = args.dtype == "bf16" or (args.dtype == "auto" and native_bf16(context.device))
        model = load_model(args.checkpoint, context.device, args.chunk_size)

        def reconstruct_one(source: Path, target: Path) -> int:
            with spool_folder(target) as spool:
                frames = load_frames(source, selection, progress=True, spool=spool)
                reconstruct_frames(model, frames, target, args, formats, save_options, bf16, overwrite=args.overwrite)
            return len(frames.rgb)

        if context.is_main:
            print(f"d4rt reconstruct: {len(inputs)} videos into {out_dir}/ (one folder each) on "
                  f"{context.world_size} process{'es' if context.distributed else ''}")
        rows = run_collection(inputs, out_dir, reconstruct_one, rank=context.rank, world_size=context.world_size,
                              barrier=context.barrier, overwrite=args.overwrite, retry_failed=args.retry_failed)
    finally:
        context.close()
    return 1 if context.is_main and any(row.status == "failed" for row in rows) else 0


def reconstruct_frames(model, frames, out_dir, args, formats, save_options, bf16: bool, overwrite: bool) -> None:
    """One video's frames (shot by shot when it has cuts) into ``out_dir``."""
    import torch

    from d4rt.io.shots import detect_cuts, shot_ranges

    t, h, w = frames.rgb.shape[:3]
    device = next(model.parameters()).device
    print(f"d4rt reconstruct: {t} frames of {w}x{h} from {frames.source} (source frames {frames.indices[0]}.."
          f"{frames.indices[-1]}, stride {args.stride}) with model '{model.config.name}' on {device}"
          f"{' under bf16 autocast' if bf16 else ''}")
    shots = [(0, t)] if args.no_cut_detection else shot_ranges(t, detect_cuts(frames.rgb, args.cut_threshold))
    usable = [(a, b) for a, b in shots if b - a >= 2]
    if not usable:
        raise UserError(f"every shot found is a single frame ({len(shots)} cuts): nothing to reconstruct; "
                        "--no-cut-detection (or a higher --cut-threshold) keeps the frames together")
    if args.track_frame >= min(b - a for a, b in usable):
        raise UserError(f"--track-frame {args.track_frame} is past the end of a shot (shots: "
                        f"{', '.join(f'{a}..{b - 1}' for a, b in shots)}); it counts from each shot's first frame")
    options = dict(save_options, fps=frames.fps)
    if args.known_poses is not None:  # one pose per frame used, sliced per shot below
        from d4rt.io.trajectory import load_known_poses

        options["known_poses"] = load_known_poses(args.known_poses, frames.indices,
                                                  frames.timestamps if frames.has_clock else None)
    if options["resolution"] == "auto":
        options["resolution"] = default_resolution(h, w)
    stamps = frames.timestamps if frames.has_clock else None
    autocast = torch.autocast(device.type, dtype=torch.bfloat16) if bf16 else nullcontext()
    with autocast:
        if len(shots) == 1:
            paths = reconstruct_clip(model, frames.rgb, stamps, out_dir, args, formats, options, overwrite)
        else:
            print(f"shot cuts before frames {', '.join(str(a) for a, _ in shots[1:])}: {len(shots)} shots, each "
                  "reconstructed on its own into OUT_DIR/shot_NNN/ (--no-cut-detection stitches through them)")
            paths = reconstruct_shots(model, frames, shots, out_dir, args, formats, options)
    print(f"wrote {out_dir}/: {', '.join(p.name + ('/' if p.is_dir() else '') for p in paths)}")


def reconstruct_clip(model, rgb, timestamps, out_dir, args, formats, save_options, overwrite: bool) -> list:
    """One shot: encode (with a progress bar on the encoder), decode and write its outputs."""
    from d4rt.io.exports import export_reconstruction
    from d4rt.reconstruction import Reconstruction

    with progress_bar(desc="encode", unit="window", bar_format="{desc}: {n} window encodings [{elapsed}]") as bar:
        rec = Reconstruction.from_model(model, rgb, window=args.window, overlap=args.overlap, on_encode=bar.update,
                                        pose_pairs=args.pose_pairs, flip_average=args.flip_average,
                                        progress=True)
        print(describe_work(rec, formats, save_options["resolution"], args.point_stride, args.tracks, args.max_points,
                            args.points_from))
        return export_reconstruction(rec, out_dir, formats, overwrite=overwrite, timestamps=timestamps, **save_options)


def reconstruct_shots(model, frames, shots, out_dir, args, formats, save_options) -> list:
    """Each shot into its own folder (shot_000, ...) and a summary, shots.json: the cuts, and per shot its
    frames (of the frames used, and of the source) and folder, or why it was skipped. The whole folder
    appears at once when every shot is written (the exports' staging)."""
    from d4rt.disk_array import row_range
    from d4rt.io.staging import staged_folder

    rows = []
    with staged_folder(out_dir) as stage:
        for k, (a, b) in enumerate(shots):
            row = {"shot": k, "frames": [a, b - 1], "source_frames": [int(frames.indices[a]), int(frames.indices[b - 1])]}
            if b - a < 2:
                row["skipped"] = "a single frame (at least 2 are needed)"
            else:
                print(f"shot {k}: frames {a}..{b - 1}")
                stamps = frames.timestamps[a:b] if frames.has_clock else None
                known = save_options.get("known_poses")
                shot_options = save_options if known is None else dict(save_options, known_poses=known[a:b])
                reconstruct_clip(model, row_range(frames.rgb, a, b), stamps, stage / f"shot_{k:03d}", args, formats,
                                 shot_options, overwrite=False)
                row["folder"] = f"shot_{k:03d}"
            rows.append(row)
        summary = {"cuts_before_frames": [a for a, _ in shots[1:]], "cut_threshold": args.cut_threshold, "shots": rows}
        (stage / "shots.json").write_text(json.dumps(summary, indent=2) + "\n")
    return sorted(out_dir.iterdir())
