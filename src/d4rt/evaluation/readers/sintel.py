"""MPI Sintel (depth and camera training data, plus the frames of the complete training set).

Layout (the "training" folder of MPI-Sintel-depth-training merged with MPI-Sintel-complete's)::

    ROOT/depth/<seq>/frame_0001.dpt        float32 depth maps
    ROOT/camdata_left/<seq>/frame_0001.cam intrinsics and world-to-camera extrinsics
    ROOT/final/<seq>/frame_0001.png        frames ("clean/" is the other render pass)

ROOT may also be the folder that contains ``training/``. Binary formats (Sintel SDK, ``sintel_io``):
``.dpt`` = float32 tag 202021.25, int32 width, int32 height, then height x width float32 depths (row
major); ``.cam`` = float32 tag 202021.25, a 3x3 float64 intrinsic matrix M, then a 3x4 float64
extrinsic matrix N = [R | t] mapping world to camera (row major). Sintel's cameras follow the OpenCV
axes and pixel-centre convention (principal point (511.5, 217.5) on 1024 x 436 frames), so M is used as
it is and the pose is N inverted. Depth is in Sintel's scene units.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers._files import read_rgb, select_frames, sorted_files
from d4rt.evaluation.sequence import EvalSequence
from d4rt.geometry.transforms import invert_rigid

SINTEL_TAG = np.float32(202021.25)


def find_root(root: Path) -> Path:
    for candidate in (root, root / "training"):
        if (candidate / "depth").is_dir():
            return candidate
    raise UserError(f"{root} is not a Sintel training folder: no depth/ (or training/depth/) inside")


def list_sequences(root: Path) -> list[str]:
    return sorted(p.name for p in (find_root(root) / "depth").iterdir() if p.is_dir())


def read_sequence(root: Path, name: str, frames: slice | None = None, render_pass: str = "final") -> EvalSequence:
    """Frames, depth, intrinsics and camera-to-world poses of one Sintel sequence."""
    base = find_root(root)
    depth_files = select_frames(sorted_files(base / "depth" / name, "frame_*.dpt"), frames, f"Sintel {name}")
    stems = [p.stem for p in depth_files]
    cams = [read_cam(base / "camdata_left" / name / f"{s}.cam") for s in stems]
    rgb = np.stack([read_rgb(base / render_pass / name / f"{s}.png") for s in stems])
    depth = np.stack([read_dpt(p) for p in depth_files])
    if depth.shape != rgb.shape[:3]:
        raise UserError(f"Sintel {name}: depth maps {depth.shape[1:]} and frames {rgb.shape[1:3]} differ in size")
    intrinsics = np.stack([k for k, _ in cams])
    world_to_cam = np.zeros((len(cams), 4, 4))
    world_to_cam[:, :3] = np.stack([e for _, e in cams])
    world_to_cam[:, 3, 3] = 1.0
    return EvalSequence(name, rgb, depth, intrinsics, invert_rigid(world_to_cam), frame_names=stems)


def read_dpt(path: Path) -> np.ndarray:
    """A Sintel .dpt depth map as (H, W) float32."""
    data = _read_bytes(path)
    if len(data) < 12 or np.frombuffer(data, np.float32, 1)[0] != SINTEL_TAG:
        raise UserError(f"{path} is not a Sintel .dpt file (wrong tag)")
    width, height = (int(v) for v in np.frombuffer(data, np.int32, 2, offset=4))
    if width <= 0 or height <= 0 or len(data) < 12 + 4 * width * height:
        raise UserError(f"{path}: header says {width}x{height} but the file holds {len(data) - 12} data bytes")
    return np.frombuffer(data, np.float32, width * height, offset=12).reshape(height, width).copy()


def read_cam(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A Sintel .cam file as (intrinsics (3, 3), world-to-camera extrinsics (3, 4)), float64."""
    data = _read_bytes(path)
    if len(data) < 4 + 8 * 21 or np.frombuffer(data, np.float32, 1)[0] != SINTEL_TAG:
        raise UserError(f"{path} is not a Sintel .cam file (wrong tag or size)")
    values = np.frombuffer(data, np.float64, 21, offset=4)
    return values[:9].reshape(3, 3).copy(), values[9:].reshape(3, 4).copy()


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as err:
        raise UserError(f"cannot read {path}: {err}") from None
