"""Bonn RGB-D Dynamic dataset (TUM RGB-D file formats).

Layout (one folder per sequence, as downloaded)::

    ROOT/rgbd_bonn_<name>/rgb/<timestamp>.png     640 x 480 colour
    ROOT/rgbd_bonn_<name>/depth/<timestamp>.png   16-bit depth, 5000 units per metre, 0 = missing
    ROOT/rgbd_bonn_<name>/groundtruth.txt         "timestamp tx ty tz qx qy qz qw" per line

Video-depth evaluations (MonST3R, CUT3R, pi3) use frames 30..139 of the sorted colour and depth lists,
pairing the two lists by sorted index (``frames=slice(30, 140)``). Intrinsics are the dataset's published
calibration (fx 542.822841, fy 542.576870, cx 315.593520, cy 237.756098; a small radial distortion is
ignored, as in those evaluations). Poses: each frame takes the ground-truth line nearest in time (at
most 20 ms apart), read as camera-to-world exactly as the file gives them. Whether they are the optical
centre's poses (rather than the motion-capture body's) has not been checked here; the published
protocols use Bonn for depth only, and so does the ``bonn`` benchmark.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers._files import intrinsics_matrix, read_rgb, read_uint16_png, select_frames, sorted_files
from d4rt.evaluation.sequence import EvalSequence
from d4rt.io.trajectory import nearest_poses, read_tum_trajectory

DEPTH_UNITS_PER_METRE = 5000.0
INTRINSICS = (542.822841, 542.576870, 315.593520, 237.756098)
PREFIX = "rgbd_bonn_"


def list_sequences(root: Path) -> list[str]:
    names = sorted(p.name[len(PREFIX):] for p in root.iterdir() if p.is_dir() and p.name.startswith(PREFIX))
    if not names:
        raise UserError(f"{root} holds no rgbd_bonn_<name>/ sequence folders")
    return names


def read_sequence(root: Path, name: str, frames: slice | None = None) -> EvalSequence:
    """Frames, metric depth, intrinsics and ground-truth poses of sequence rgbd_bonn_<name>."""
    base = root / f"{PREFIX}{name}"
    rgb_files = sorted_files(base / "rgb", "*.png")
    depth_files = sorted_files(base / "depth", "*.png")
    if len(rgb_files) != len(depth_files):
        raise UserError(f"Bonn {name}: {len(rgb_files)} colour but {len(depth_files)} depth images")
    pairs = select_frames(list(zip(rgb_files, depth_files)), frames, f"Bonn {name}")
    rgb = np.stack([read_rgb(r) for r, _ in pairs])
    depth = np.stack([read_uint16_png(d) for _, d in pairs]) / DEPTH_UNITS_PER_METRE
    cam_to_world = None
    if (base / "groundtruth.txt").is_file():
        cam_to_world = nearest_poses(read_tum_trajectory(base / "groundtruth.txt"),
                                     np.array([float(r.stem) for r, _ in pairs]))
    return EvalSequence(name, rgb, depth, intrinsics_matrix(*INTRINSICS, len(pairs)), cam_to_world,
                        frame_names=[r.stem for r, _ in pairs])
