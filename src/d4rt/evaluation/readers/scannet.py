"""ScanNet (v2), as exported from the .sens files by ScanNet's SensReader.

Layout (one folder per scene)::

    ROOT/<scene>/color/<i>.jpg                    colour frames (1296 x 968)
    ROOT/<scene>/depth/<i>.png                    16-bit depth, millimetres, 0 = missing (640 x 480)
    ROOT/<scene>/pose/<i>.txt                     4x4 camera-to-world (OpenCV axes); -inf where unknown
    ROOT/<scene>/intrinsic/intrinsic_depth.txt    4x4, the depth camera's intrinsics

Frames are numbered 0, 1, ... Colour is resized to the depth resolution and the depth camera's
intrinsics are used for both, as the published ScanNet video-depth and pose evaluations do (ScanNet's
colour and depth cameras are close but not identical, so this is an approximation the field accepts).
The MonST3R / CUT3R ScanNet protocol takes every third frame, 90 frames (``stride=3, max_frames=90``).
Frames whose pose is not finite are dropped after that selection and listed in the sequence's notes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers._files import read_rgb, read_text_matrix, read_uint16_png, sorted_files
from d4rt.evaluation.sequence import EvalSequence

DEPTH_UNITS_PER_METRE = 1000.0


def list_sequences(root: Path) -> list[str]:
    names = sorted(p.name for p in root.iterdir() if (p / "pose").is_dir() and (p / "depth").is_dir())
    if not names:
        raise UserError(f"{root} holds no ScanNet scene folders (<scene>/depth/ and <scene>/pose/)")
    return names


def read_sequence(root: Path, name: str, stride: int = 1, max_frames: int | None = None) -> EvalSequence:
    """Frames, metric depth, depth-camera intrinsics and camera-to-world poses of one scene."""
    if stride < 1 or (max_frames is not None and max_frames < 1):
        raise UserError(f"stride and max_frames must be positive, got {stride} and {max_frames}")
    base = root / name
    ids = [int(p.stem) for p in sorted_files(base / "depth", "*.png")]
    ids = sorted(ids)[::stride][:max_frames]
    poses = np.stack([read_text_matrix(base / "pose" / f"{i}.txt", (4, 4), "ScanNet pose") for i in ids])
    finite = np.isfinite(poses).all((1, 2))
    notes = []
    if not finite.all():
        notes.append(f"dropped frames without a ground-truth pose: {[i for i, ok in zip(ids, finite) if not ok]}")
    ids = [i for i, ok in zip(ids, finite) if ok]
    if not ids:
        raise UserError(f"ScanNet {name}: no selected frame has a finite ground-truth pose")
    depth = np.stack([read_uint16_png(base / "depth" / f"{i}.png") for i in ids]) / DEPTH_UNITS_PER_METRE
    rgb = np.stack([read_rgb(base / "color" / f"{i}.jpg", size=depth.shape[1:]) for i in ids])
    k = read_text_matrix(base / "intrinsic" / "intrinsic_depth.txt", (4, 4), "ScanNet intrinsic matrix")[:3, :3]
    return EvalSequence(name, rgb, depth, np.repeat(k[None], len(ids), 0), poses[finite],
                        frame_names=[str(i) for i in ids], notes=notes)

