"""``d4rt demo``: every output of ``d4rt reconstruct`` on the bundled samples, with no arguments.

Samples: a synthetic dynamic clip rendered from a fixed seed (its ground truth is exact) and 17 real
frames of TUM RGB-D fr3/long_office_household (CC BY 4.0, ``d4rt/assets/``). With the bundled model the
demo reconstructs both, writes every output, and prints the synthetic clip's errors against ground truth
and the real frames' focal-length error against the published calibration. Until a trained model ships,
it says so, answers the synthetic clip's queries with the exact ground-truth oracle (the errors then
check the whole pipeline, recipes and files, not a model), and skips the real frames: without a model
nothing can reconstruct real footage, and no numbers are made up for it.
"""

from __future__ import annotations

import time
from importlib.resources import files
from pathlib import Path

import numpy as np
from d4rt.cli import COMMANDS

SEED = 8
SYNTHETIC = dict(frames=24, height=120, width=160, environment="room", camera_motion="orbit", articulated=True,
                 num_objects=6)
POINT_STRIDE = 2  # point clouds from every other pixel: files of a few MB
TUM_FOLDER = "tum-fr3-long-office-household"
TUM_FX = 535.4  # published colour-camera focal length of the fr3 sequences, pixels (asset README)


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help=COMMANDS["demo"],
                              description="Reconstruct the bundled samples (a synthetic clip with exact ground "
                                          "truth, and 17 real TUM RGB-D frames), write every output and print "
                                          "their accuracy.")
    p.add_argument("-o", "--out", default="d4rt-demo",
                   help="output directory (default: ./d4rt-demo; an earlier demo's output there is replaced)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty output directory that is not an "
                                                            "earlier demo's output")
    p.set_defaults(func=run)


def bundled_model():
    """The bundled trained model, or None (with a notice) while none ships."""
    from d4rt.cli.reconstruct import has_bundled_model
    from d4rt.model import D4RT

    if has_bundled_model():
        print("d4rt demo: the bundled model d4rt-tiny, trained on synthetic clips only (its measured accuracy, and "
              "what it is not good at: MODEL_CARD.md)")
        return D4RT.from_pretrained()
    print("d4rt demo: no trained model ships with this version of d4rt yet, so the synthetic clip's queries are "
          "answered by its exact ground-truth oracle:\n  the errors below check the recipes and the written files, "
          "not a model.")
    return None


def tum_frames_dir() -> Path:
    return Path(str(files("d4rt") / "assets" / TUM_FOLDER / "rgb"))


def run(args) -> int:
    from d4rt.io.formats import check_output_dir

    out = check_output_dir(args.out, args.overwrite or is_demo_output(Path(args.out)))
    model = bundled_model()
    run_synthetic(model, out / "synthetic")
    run_real(model, out / "tum")
    print(f"look at them: open {out / 'synthetic' / 'viewer.html'} (or {out / 'tum' / 'viewer.html'}) in a browser "
          "(orbit, play, tracks, cameras); depth.mp4 and tracks.mp4 beside it; every file: docs/outputs.md")
    return 0


def is_demo_output(folder: Path) -> bool:
    """An earlier demo's output (only its two sample folders): re-running the demo replaces it."""
    return folder.is_dir() and {p.name for p in folder.iterdir()} <= {"synthetic", "tum"}


def run_synthetic(model, out: Path) -> None:
    from d4rt.io.exports import export_reconstruction
    from d4rt.reconstruction import Reconstruction
    from d4rt.synthetic import render_clip

    start = time.perf_counter()
    clip = render_clip(SEED, **SYNTHETIC)
    info = clip.scene.info
    print(f"synthetic clip: {clip.num_frames} frames of {clip.width}x{clip.height} rendered in "
          f"{time.perf_counter() - start:.1f} s ({info['environment']}, camera {info['camera_motion']}, "
          f"{clip.num_bodies - 1} rigid bodies)")
    rec = Reconstruction.from_model(model, clip.rgb) if model is not None else Reconstruction.from_clip(clip)
    fps = info["options"]["fps"] / info["options"]["time_stride"]
    paths = export_reconstruction(rec, out, timestamps=np.asarray(info["times"]), fps=fps, point_stride=POINT_STRIDE,
                                  overwrite=True, progress=True)
    print(f"wrote {out}/: {', '.join(p.name for p in paths)}")
    with np.load(out / "reconstruction.npz") as saved:
        saved = dict(saved)
    for line in accuracy_report(clip, saved):
        print("  " + line)
    write_plots(out, saved, clip.rgb, clip)


def run_real(model, out: Path, resolution=(120, 160), point_stride: int = 2) -> None:
    """The real frames (depth maps at ``resolution``, a quarter of the input size by default: the bundled
    model sees 64x64 frames, so finer maps would only interpolate, and the queries stay few on a CPU)."""
    from d4rt.io.exports import export_reconstruction
    from d4rt.io.frames import load_frames
    from d4rt.reconstruction import Reconstruction

    frames_dir = tum_frames_dir()
    if model is None:
        print(f"real footage ({TUM_FOLDER}, 17 frames): skipped. Without a trained model nothing can "
              "reconstruct real video yet (the oracle exists only for synthetic clips).")
        return
    frames = load_frames(frames_dir, progress=True)
    rec = Reconstruction.from_model(model, frames.rgb)
    paths = export_reconstruction(rec, out, timestamps=frames.timestamps, fps=frames.fps, resolution=resolution,
                                  point_stride=point_stride, overwrite=True, progress=True)
    print(f"wrote {out}/: {', '.join(p.name for p in paths)}")
    with np.load(out / "reconstruction.npz") as saved:
        saved = dict(saved)
    write_plots(out, saved, frames.rgb)
    shared = float(np.median(saved["video_intrinsics"][:, 0, 0]))
    fx = float(np.median(rec.cameras().intrinsics[:, 0, 0]))  # the paper's per-frame recipe, as MODEL_CARD.md
    print(f"  real frames: focal length {fx:.1f} px vs the published fx = {TUM_FX} px "
          f"({100 * (fx / TUM_FX - 1):+.1f}%; median of the per-frame estimates; the files' shared camera: "
          f"f = {shared:.1f} px)")


def write_plots(out: Path, saved: dict, rgb: np.ndarray, clip=None) -> None:
    """trajectory.png (top and side views; with a clip, its true path beside the estimate aligned to it by
    Sim(3)) and depth.png (the middle frame's depth and confidence; with a clip, its relative error after
    one scale for the clip), when matplotlib is installed."""
    from d4rt.viz.plots import depth_figure, plots_available, trajectory_figure

    if not plots_available():
        print("  plots skipped (trajectory.png, depth.png): they need matplotlib, pip install 'd4rt[viewer]'")
        return
    poses, reference, true_depth = saved["cam_to_world"], None, None
    k = len(poses) // 2
    depth = saved["depth"][k]
    if clip is not None:
        from d4rt.evaluation.metrics.pose import align_trajectory, sim3_alignment
        from d4rt.geometry.transforms import invert_rigid

        reference = invert_rigid(clip.cam_to_world[0]) @ clip.cam_to_world
        poses = align_trajectory(sim3_alignment(poses, reference), poses)
        if saved["depth"].shape == clip.depth.shape:
            ok = np.isfinite(saved["depth"]) & (saved["depth"] > 0) & (clip.depth > 0)
            depth = depth * float(np.median(clip.depth[ok] / saved["depth"][ok]))  # one scale for the clip
            true_depth = clip.depth[k]
    trajectory_figure(out / "trajectory.png", poses, reference,
                      "camera path (estimate aligned to the truth by Sim(3))" if clip is not None else "camera path")
    depth_figure(out / "depth.png", rgb[k], depth, saved["confidence"][k], true_depth, f"frame {k}")
    print(f"  plots: {out / 'trajectory.png'}, {out / 'depth.png'}")


def accuracy_report(clip, saved: dict) -> list[str]:
    """Errors of a saved reconstruction (the arrays of reconstruction.npz) against a synthetic clip's
    ground truth, with the project's evaluation metrics: video depth with one median scale per clip,
    camera trajectory after Sim(3) alignment (ATE, RPE, as evo), focal length, and world-frame 3D tracks
    (APD3D and L1 after median scaling, D4RT Tab. 4)."""
    from d4rt.evaluation.metrics import depth_metrics, pose_metrics, world_track_metrics
    from d4rt.geometry.transforms import apply_transform, invert_rigid
    from d4rt.reconstruction import Reconstruction

    lines = []
    if saved["depth"].shape == clip.depth.shape:
        depth = depth_metrics(saved["depth"], clip.depth, align="median")
        lines.append(f"depth: AbsRel {depth['abs_rel']:.3g} (mean |error| / true depth, after one scale for the clip; "
                     f"0 is exact), delta<1.25 {depth['delta_1_25']:.1%} (pixels within 25% of the truth)")

    gt_poses = invert_rigid(clip.cam_to_world[0]) @ clip.cam_to_world  # world = camera 0, as saved
    pose = pose_metrics(saved["cam_to_world"], gt_poses)
    travelled = float(np.linalg.norm(np.diff(gt_poses[:, :3, 3], axis=0), axis=1).sum())
    focal = float(np.mean(np.abs(saved["video_intrinsics"][:, 0, 0] / clip.intrinsics[:, 0, 0] - 1)))
    lines.append(f"cameras: ATE {pose['ate']:.3g} m (camera-position error after aligning the path, which is "
                 f"{travelled:.2f} m long), RPE {pose['rpe_trans']:.3g} m / {pose['rpe_rot']:.3g} deg (frame-to-frame "
                 f"drift), focal length error {focal:.3g} ({focal:.1%} of the true focal length)")

    truth = Reconstruction.from_clip(clip).tracks(saved["track_queries"], frame="world")
    gt_tracks = np.swapaxes(truth.points, 0, 1)  # (T, N, 3)
    gt_depth = apply_transform(invert_rigid(gt_poses)[:, None], gt_tracks)[..., 2]  # each frame's own camera
    k = clip.intrinsics
    world = world_track_metrics(np.swapaxes(saved["tracks"], 0, 1), gt_tracks, truth.visibility.T > 0.5, gt_depth,
                                np.stack([k[:, 0, 0], k[:, 1, 1], k[:, 0, 2], k[:, 1, 2]], 1),
                                (clip.height, clip.width))
    lines.append(f"3D tracks ({len(truth.points)} points x {clip.num_frames} frames, after one scale): APD3D "
                 f"{world['apd3d']:.1%} (points within a depth-scaled distance of the truth; 100% is exact), "
                 f"L1 {world['l1']:.3g} m (mean distance)")
    return lines
