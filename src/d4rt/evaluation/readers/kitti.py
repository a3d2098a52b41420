"""KITTI depth (the depth-selection validation set of the KITTI depth benchmark devkit).

Official layout (``depth_selection/val_selection_cropped``; ROOT may be that folder or a parent of it)::

    ROOT/image/<drive>_image_<frame>_image_<cam>.png                  1216 x 352 colour
    ROOT/groundtruth_depth/<drive>_groundtruth_depth_<frame>_image_<cam>.png
    ROOT/intrinsics/<drive>_image_<frame>_image_<cam>.txt             3x3 K, 9 numbers, row major

e.g. ``2011_09_26_drive_0002_sync_image_0000000005_image_02.png``. Video-depth evaluations (MonST3R,
CUT3R, pi3) regroup KITTI's annotated validation depth into sequences ("gathered" folders, the first
110 frames of each drive); that layout is read too::

    ROOT/image_gathered/<drive>_<cam>/<frame>.png
    ROOT/groundtruth_depth_gathered/<drive>_<cam>/<frame>.png

Depth PNGs are 16-bit with 256 units per metre; 0 = no ground truth (LiDAR is sparse). A sequence is one
drive and camera, frames in frame-number order. The gathered layout has no intrinsics (None).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers._files import (
    read_rgb,
    read_text_matrix,
    read_uint16_png,
    select_frames,
    sorted_files,
)
from d4rt.evaluation.sequence import EvalSequence

DEPTH_UNITS_PER_METRE = 256.0
OFFICIAL_NAME = re.compile(r"^(?P<drive>.+)_image_(?P<frame>\d+)_image_(?P<cam>\d+)\.png$")
SELECTION = "val_selection_cropped"


def find_root(root: Path) -> Path:
    for candidate in (root, root / SELECTION, root / "depth_selection" / SELECTION):
        if (candidate / "groundtruth_depth").is_dir() or (candidate / "groundtruth_depth_gathered").is_dir():
            return candidate
    raise UserError(f"{root} is not a KITTI depth-selection folder: no groundtruth_depth/ or "
                    f"groundtruth_depth_gathered/ inside (looked in {SELECTION}/ too)")


def _gathered(base: Path) -> bool:
    return (base / "groundtruth_depth_gathered").is_dir()


def list_sequences(root: Path) -> list[str]:
    base = find_root(root)
    if _gathered(base):
        return sorted(p.name for p in (base / "groundtruth_depth_gathered").iterdir() if p.is_dir())
    return sorted(_official_frames(base))


def read_sequence(root: Path, name: str, frames: slice | None = None) -> EvalSequence:
    """Frames and metric depth (plus intrinsics in the official layout) of one drive and camera."""
    base = find_root(root)
    if _gathered(base):
        depth_files = select_frames(sorted_files(base / "groundtruth_depth_gathered" / name, "*.png"), frames,
                                    f"KITTI {name}")
        image_files = [base / "image_gathered" / name / p.name for p in depth_files]
        intrinsics = None
    else:
        stems = _official_frames(base).get(name)
        if not stems:
            raise UserError(f"KITTI sequence {name} not found in {base}")
        stems = select_frames(stems, frames, f"KITTI {name}")
        image_files = [base / "image" / f"{s}.png" for s in stems]
        depth_files = [base / "groundtruth_depth" / f"{s.replace('_image_', '_groundtruth_depth_', 1)}.png"
                       for s in stems]
        intrinsics = np.stack([read_text_matrix(base / "intrinsics" / f"{s}.txt", (3, 3), "KITTI intrinsic matrix")
                                for s in stems])
    rgb = np.stack([read_rgb(p) for p in image_files])
    depth = np.stack([read_uint16_png(p) for p in depth_files]) / DEPTH_UNITS_PER_METRE
    return EvalSequence(name, rgb, depth, intrinsics, frame_names=[p.stem for p in image_files])


def _official_frames(base: Path) -> dict[str, list[str]]:
    """Sequence name ``<drive>_<cam>`` -> image file stems in frame order."""
    sequences: dict[str, list[tuple[int, str]]] = {}
    for path in (base / "image").glob("*.png"):
        match = OFFICIAL_NAME.match(path.name)
        if match:
            key = f"{match['drive']}_{match['cam']}"
            sequences.setdefault(key, []).append((int(match["frame"]), path.stem))
    if not sequences:
        raise UserError(f"no <drive>_image_<frame>_image_<cam>.png files in {base / 'image'}")
    return {k: [stem for _, stem in sorted(v)] for k, v in sequences.items()}

