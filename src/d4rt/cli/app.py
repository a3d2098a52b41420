"""``d4rt app``: a local web app (gradio) around ``d4rt reconstruct``: drop in a video or a zip of images
(or pick the bundled sample), choose frames, stride, resolution and known intrinsics, and get back an
interactive 3D view (scene.glb), the depth and tracks videos, the camera trajectory plot, and the whole
output folder as a zip.

One model is loaded once; requests are queued and run one at a time; every request works in a folder
of its own (nothing of one leaks into another's), and only the newest KEEP_REQUESTS folders stay on disk;
uploads are size-limited; a bad upload is refused with the same one-line error as the CLI. Binds to
127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from contextlib import nullcontext
from pathlib import Path

from d4rt.cli import COMMANDS, add_server_arguments, check_port

SAMPLE = "TUM RGB-D fr3 office (17 real frames, bundled)"
RESOLUTIONS = {"encoder (fastest: about the model's 64x64 pixels)": "encoder",
               "auto (the input's size, up to 640x480 pixels' worth)": "auto",
               "original (every input pixel: slow on a CPU)": None}
UPLOAD_TYPES = [".mp4", ".mov", ".avi", ".webm", ".mkv", ".m4v", ".zip", ".npy", ".npz"]
DEFAULT_MAX_UPLOAD_MB = 200
OUTPUT_ZIP = "d4rt-output.zip"
KEEP_REQUESTS = 16  # request folders kept on disk (gradio serves its own copies of the results)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "app", help=COMMANDS["app"],
        description="Serve a local web app (gradio) that reconstructs an uploaded video or image zip with the bundled "
                    "model and shows the results. Needs pip install 'd4rt[app]'.")
    add_server_arguments(p, 7860)
    p.add_argument("--checkpoint", metavar="DIR", default=None, help="model directory (default: the bundled model)")
    p.add_argument("--max-upload-mb", type=int, default=DEFAULT_MAX_UPLOAD_MB,
                   help=f"largest upload accepted, in MB (default: {DEFAULT_MAX_UPLOAD_MB})")
    p.add_argument("--work-dir", default=None, metavar="DIR",
                   help="where each request's folder is made (default: a new temporary folder)")
    p.set_defaults(func=run)


def run(args) -> int:
    from d4rt.errors import UserError

    check_port(args.port)
    if args.max_upload_mb < 1:
        raise UserError(f"--max-upload-mb must be >= 1, got {args.max_upload_mb}")
    app = build_app(args.checkpoint, args.work_dir)
    print(f"d4rt app: http://{args.host}:{args.port} (Ctrl-C stops it)", flush=True)
    app.launch(server_name=args.host, server_port=args.port, max_file_size=f"{args.max_upload_mb}mb", quiet=True)
    return 0


def _unzip_images(archive: Path, target: Path) -> Path:
    """The images of a zip, flattened into ``target``; a corrupt zip or one without images is a UserError."""
    from d4rt.errors import UserError
    from d4rt.io.frames import IMAGE_SUFFIXES

    try:
        with zipfile.ZipFile(archive) as z:
            names = [n for n in z.namelist() if not n.endswith("/") and Path(n).suffix.lower() in IMAGE_SUFFIXES
                     and not Path(n).name.startswith(".")]
            if not names:
                raise UserError(f"{archive.name} holds no images ({' '.join(IMAGE_SUFFIXES)})")
            target.mkdir(parents=True)
            for name in names:  # flattened by file name: no path from the archive is ever joined to ours
                with z.open(name) as source, open(target / Path(name).name, "wb") as sink:
                    shutil.copyfileobj(source, sink)
    except zipfile.BadZipFile as err:
        raise UserError(f"{archive.name} is not a readable zip file: {err}") from err
    return target


def prune_requests(work_root: Path, keep: int = KEEP_REQUESTS) -> None:
    """Delete all but the ``keep`` newest request folders, so a long-running app does not fill the disk."""
    folders = sorted((p for p in work_root.glob("request-*") if p.is_dir()), key=lambda p: p.stat().st_mtime)
    for old in folders[:max(0, len(folders) - keep)]:
        shutil.rmtree(old, ignore_errors=True)


def reconstruct_request(model, work_root: Path, upload: str | None, use_sample: bool, max_frames: int, stride: int,
                        resolution_label: str, intrinsics_text: str) -> dict:
    """One request in a folder of its own under ``work_root``: the input read as the CLI reads it, every
    output written, the trajectory plotted and everything zipped. Returns the paths the page shows."""
    import numpy as np
    import torch

    from d4rt.cli.demo import tum_frames_dir
    from d4rt.cli.reconstruct import parse_intrinsics
    from d4rt.devices import native_bf16
    from d4rt.errors import UserError
    from d4rt.io.exports import export_reconstruction
    from d4rt.io.frames import FrameRange, load_frames
    from d4rt.reconstruction import Reconstruction
    from d4rt.viz.plots import plots_available, trajectory_figure

    if not use_sample and not upload:
        raise UserError("upload a video or a zip of images, or tick the bundled sample")
    intrinsics = parse_intrinsics(intrinsics_text) if intrinsics_text and intrinsics_text.strip() else None
    resolution = RESOLUTIONS.get(resolution_label, "encoder")
    folder = Path(tempfile.mkdtemp(prefix="request-", dir=work_root))
    if use_sample:
        source = tum_frames_dir()
    else:
        upload_path = Path(upload)
        if upload_path.suffix.lower() not in UPLOAD_TYPES:
            raise UserError(f"{upload_path.name}: unsupported upload type; expected a video, a .zip of images or an "
                            f".npy/.npz array ({' '.join(UPLOAD_TYPES)})")
        source = folder / ("input" + upload_path.suffix.lower())
        shutil.copyfile(upload_path, source)
        if source.suffix == ".zip":
            source = _unzip_images(source, folder / "input-images")
    try:
        frames = load_frames(source, FrameRange(stride=int(stride), max_frames=int(max_frames)))
    except UserError as err:  # name the user's file, not this request's copy of it
        raise UserError(str(err).replace(str(source), Path(upload).name if upload else source.name)) from None
    if resolution == "auto":
        from d4rt.cli.reconstruct import default_resolution

        resolution = default_resolution(*frames.rgb.shape[1:3])
    device = next(model.parameters()).device
    autocast = torch.autocast(device.type, dtype=torch.bfloat16) if native_bf16(device) else nullcontext()
    out = folder / "output"
    with autocast:
        rec = Reconstruction.from_model(model, frames.rgb)
        export_reconstruction(rec, out, formats=["npz", "depth-video", "ply", "glb", "colmap", "tum", "tracks-video",
                                                 "html"], resolution=resolution, intrinsics=intrinsics,
                              timestamps=frames.timestamps if frames.has_clock else None, fps=frames.fps,
                              progress=True)
    with np.load(out / "reconstruction.npz") as saved:
        poses = saved["cam_to_world"]
    plot = trajectory_figure(out / "trajectory.png", poses) if plots_available() else None
    archive = shutil.make_archive(str(folder / Path(OUTPUT_ZIP).stem), "zip", out)
    return {"folder": folder, "glb": out / "scene.glb", "depth_video": out / "depth.mp4",
            "tracks_video": out / "tracks.mp4", "trajectory": plot, "zip": Path(archive),
            "summary": f"{len(frames.rgb)} frames of {frames.rgb.shape[2]}x{frames.rgb.shape[1]} reconstructed "
                       f"({len(rec.windows)} window{'s' if len(rec.windows) > 1 else ''}); every file is in the zip "
                       "(what each holds: docs/outputs.md)"}


def build_app(checkpoint: str | None = None, work_dir: str | None = None):
    """The gradio Blocks app (not launched). The model is loaded here, once."""
    try:
        import gradio as gr
    except ImportError:
        from d4rt.errors import UserError

        raise UserError("d4rt app needs gradio: pip install 'd4rt[app]'") from None
    from d4rt.cli.reconstruct import load_model
    from d4rt.devices import resolve_device
    from d4rt.errors import UserError

    model = load_model(checkpoint, resolve_device("auto", "--device"))
    work_root = Path(work_dir) if work_dir else Path(tempfile.mkdtemp(prefix="d4rt-app-"))
    work_root.mkdir(parents=True, exist_ok=True)

    def handle(upload, use_sample, max_frames, stride, resolution_label, intrinsics_text,
               progress=gr.Progress(track_tqdm=True)):
        prune_requests(work_root, KEEP_REQUESTS - 1)  # room for this one
        try:
            r = reconstruct_request(model, work_root, upload, bool(use_sample), max_frames, stride, resolution_label,
                                    intrinsics_text or "")
        except UserError as err:  # the CLI's one-line message, shown on the page
            raise gr.Error(str(err)) from None
        return (str(r["glb"]), str(r["depth_video"]), str(r["tracks_video"]),
                str(r["trajectory"]) if r["trajectory"] else None, str(r["zip"]), r["summary"])

    with gr.Blocks(title="d4rt: 4D reconstruction from video") as app:
        gr.Markdown("# d4rt\nA video in, its depth, cameras, 3D points and tracks out (the bundled d4rt-tiny model: "
                    "see MODEL_CARD.md for what it can and cannot do).")
        with gr.Row():
            with gr.Column(scale=1):
                upload = gr.File(label="video (.mp4 .mov .webm ...), zip of images, or .npy/.npz frames",
                                 file_types=UPLOAD_TYPES)
                use_sample = gr.Checkbox(label=f"use the bundled sample instead: {SAMPLE}", value=False)
                max_frames = gr.Slider(2, 96, value=24, step=1, label="frames (at most)")
                stride = gr.Slider(1, 10, value=1, step=1, label="use every n-th frame")
                resolution = gr.Dropdown(list(RESOLUTIONS), value=next(iter(RESOLUTIONS)), label="depth resolution")
                intrinsics = gr.Textbox(label="known intrinsics fx,fy,cx,cy in pixels (optional)", value="")
                button = gr.Button("Reconstruct", variant="primary")
            with gr.Column(scale=2):
                summary = gr.Markdown()
                scene = gr.Model3D(label="3D points and cameras (scene.glb)", height=420)
                with gr.Row():
                    depth_video = gr.Video(label="frame | depth")
                    tracks_video = gr.Video(label="3D tracks on the frames")
                trajectory = gr.Image(label="camera trajectory", type="filepath")
                download = gr.File(label="every output (zip)")
        button.click(handle, [upload, use_sample, max_frames, stride, resolution, intrinsics],
                     [scene, depth_video, tracks_video, trajectory, download, summary], api_name="reconstruct")
    app.queue(default_concurrency_limit=1)  # one model, one request at a time
    app.work_root = work_root
    return app
