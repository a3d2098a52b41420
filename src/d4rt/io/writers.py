"""One writer per output format, each from the same decoded arrays (units and conventions of every
file: docs/outputs.md), all into one atomic staging folder (:mod:`d4rt.io.staging`)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
from PIL import Image

from d4rt.io.colmap_export import write_colmap
from d4rt.io.depth_png import write_depth_pngs
from d4rt.io.formats import check_output_dir, parse_formats
from d4rt.io.glb import write_glb
from d4rt.io.npz_stream import write_npz
from d4rt.io.outputs import ReconstructionOutputs
from d4rt.io.ply import write_ply
from d4rt.io.staging import staged_folder
from d4rt.io.trajectory import write_tum
from d4rt.io.video import write_video
from d4rt.progress import progress_bar
from d4rt.viz.depth_video import iter_depth_video_frames
from d4rt.viz.frusta import frustum_segments
from d4rt.viz.html_viewer import MAX_POINTS, even_subset, write_html
from d4rt.viz.overlay import iter_drawn_tracks, project_tracks, track_colors
from d4rt.viz.rerun_recording import write_rrd


def write_outputs(out: ReconstructionOutputs, directory: str | Path, formats, *, overwrite: bool = False,
                  progress: bool = False, title: str | None = None) -> list[Path]:
    """Write already-decoded outputs (atomically: see the module docstring)."""
    names = parse_formats(formats)
    directory = check_output_dir(directory, overwrite)
    title = title or directory.name
    written = []
    with staged_folder(directory) as stage:
        for name in progress_bar(names, desc="write", unit="file", disable=not progress):
            written.append(_WRITERS[name](out, stage, title))
    return [directory / p.relative_to(stage) for p in written]


def _write_npz(out: ReconstructionOutputs, stage: Path, title: str) -> Path:
    arrays = {f.name: getattr(out, f.name) for f in fields(out)
              if f.name not in ("rgb", "fps", "min_confidence", "dense", "motion", "colmap", "point_offsets")}
    arrays.update(fps=np.float64(out.fps), video_size=np.array(out.rgb.shape[1:3]),
                  min_confidence=np.float64(np.nan if out.min_confidence is None else out.min_confidence))
    return write_npz(stage / "reconstruction.npz", {k: v for k, v in arrays.items() if v is not None})


def _write_depth(out, stage, title):
    write_depth_pngs(stage / "depth", out.depth, out.depth_valid)
    return stage / "depth"


def _write_depth_video(out, stage, title):
    return write_video(stage / "depth.mp4", iter_depth_video_frames(out.rgb, out.depth, out.depth_valid), fps=out.fps)


def _write_ply(out, stage, title):
    return write_ply(stage / "points.ply", out.points, out.point_colors, out.point_confidence, out.point_frames)


def _write_glb(out, stage, title):
    keep = even_subset(len(out.points), GLB_MAX_POINTS)
    return write_glb(stage / "scene.glb", out.points[keep], out.point_colors[keep], frusta(out))


def _write_colmap(out, stage, title):
    c = out.colmap
    return write_colmap(stage / "colmap", out.rgb, out.video_intrinsics, out.cam_to_world, c["xyz"], c["colors"],
                        c["obs_point"], c["obs_frame"], c["obs_xy"], c["error"])


def _write_tum(out, stage, title):
    return write_tum(stage / "trajectory_tum.txt", out.timestamps, out.cam_to_world)


def _write_tracks_video(out, stage, title):
    xy, visible = track_pixels(out)
    return write_video(stage / "tracks.mp4", iter_drawn_tracks(out.rgb, xy, visible, colors_of_tracks(out)),
                       fps=out.fps)


def _write_rerun(out, stage, title):
    return write_rrd(stage / "reconstruction.rrd", out.rgb, out.depth, out.video_intrinsics, out.cam_to_world,
                     out.points, out.point_colors, out.point_frames, out.tracks, track_pixels(out)[1],
                     colors_of_tracks(out), out.timestamps, point_offsets=out.point_offsets)


def _write_html(out, stage, title):
    return write_html(stage / "viewer.html", out.points, out.point_colors, out.point_frames, out.cam_to_world,
                      frusta(out), out.tracks, track_pixels(out)[1], colors_of_tracks(out), out.fps, out.timestamps,
                      title=title)


def _write_dense(out, stage, title):
    path = stage / "dense_tracks.npz"
    np.savez_compressed(path, **out.dense)
    return path


def _write_motion(out, stage, title):
    folder = stage / "motion"
    folder.mkdir()
    for k, mask in enumerate(out.motion["dynamic"]):
        Image.fromarray(np.where(mask, 255, 0).astype(np.uint8)).save(folder / f"{k:06d}.png")
    np.savez_compressed(folder / "motion.npz", **out.motion)
    return folder


# scene.glb holds at most this many points, evenly spaced through the cloud (points.ply holds them all):
# viewers of GLB files slow down long before, and a long video's cloud is not gathered in memory for it.
GLB_MAX_POINTS = 1_000_000


_WRITERS = {"npz": _write_npz, "depth": _write_depth, "depth-video": _write_depth_video, "ply": _write_ply,
            "glb": _write_glb, "colmap": _write_colmap, "tum": _write_tum, "tracks-video": _write_tracks_video,
            "rerun": _write_rerun, "html": _write_html, "dense-tracks": _write_dense,
            "motion-masks": _write_motion}


def track_pixels(out: ReconstructionOutputs) -> tuple[np.ndarray, np.ndarray]:
    """The 3D tracks projected into each frame's camera: pixels (N, T, 2) of the input frames and
    visible (N, T) bool (visibility > 0.5, in front of the camera, finite)."""
    xy, z = project_tracks(out.tracks, out.video_intrinsics, out.cam_to_world)
    visible = (out.track_visibility > 0.5) & (z > 0) & np.isfinite(xy).all(-1)
    return xy, visible


def colors_of_tracks(out: ReconstructionOutputs) -> np.ndarray:
    return track_colors(out.track_queries[:, 1:], out.rgb.shape[2])


def frusta(out: ReconstructionOutputs) -> np.ndarray:
    """(T, 8, 2, 3) camera frusta, 8% of the median camera-to-point distance deep."""
    centres = out.cam_to_world[:, :3, 3]
    if out.points is not None and len(out.points):
        keep = even_subset(len(out.points), MAX_POINTS)  # the median of an even subset: the cloud may be on disk
        reach = float(np.median(np.linalg.norm(out.points[keep] - centres[out.point_frames[keep]], axis=1)))
    else:
        reach = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum()) or 1.0
    h, w = out.rgb.shape[1:3]
    return frustum_segments(out.video_intrinsics, out.cam_to_world, h, w, 0.08 * reach)
