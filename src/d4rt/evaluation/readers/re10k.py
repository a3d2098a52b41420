"""RealEstate10K (camera poses only: the paper's Re10K pose AUC@30).

Layout: the released camera files, plus the frames of each sequence extracted by you from its video (the dataset
ships no images; its first line names the YouTube video)::

    ROOT/<seq>.txt                       the released camera file (ROOT may also be its test/ or train/ folder)
    ROOT/<seq>/<timestamp>.png|.jpg      the frames, named by the timestamp (microseconds) of their camera line

Camera file (RealEstate10K's README): the video's URL on the first line, then one line per frame:
``timestamp fx fy cx cy k1 k2 p00 p01 p02 p03 p10 ... p23``, the intrinsics normalised by the image width (fx, cx)
and height (fy, cy) and the 3x4 world-to-camera matrix [R | t], row major, in OpenCV axes (x right, y down,
z forward; as pixelSplat and the other readers of the dataset use it). Normalised coordinates put the image's edge
at 0 and 1, so in OpenCV pixel centres cx_px = cx W - 0.5. Lines whose frame was not extracted are skipped and
listed in the sequence's notes. There is no depth.

The paper does not say which frames of a sequence its Re10K evaluation takes; this reader takes every extracted
frame, evenly thinned to at most ``max_frames`` (the benchmark: 24, one window of the bundled model).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.evaluation.readers._files import read_rgb
from d4rt.evaluation.sequence import EvalSequence
from d4rt.geometry.transforms import invert_rigid

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def sequence_folder(root: Path) -> Path | None:
    """ROOT, or its test/ (then train/) folder, whichever holds camera files with frame folders; None if none does."""
    for candidate in (root, root / "test", root / "train"):
        if candidate.is_dir() and any((candidate / p.stem).is_dir() for p in candidate.glob("*.txt")):
            return candidate
    return None


def find_root(root: Path) -> Path:
    """:func:`sequence_folder`, or a one-line error naming the expected layout."""
    base = sequence_folder(root)
    if base is None:
        raise UserError(f"{root} holds no RealEstate10K sequence (<seq>.txt beside a <seq>/ folder of frames)")
    return base


def list_sequences(root: Path) -> list[str]:
    base = find_root(root)
    return sorted(p.stem for p in base.glob("*.txt") if (base / p.stem).is_dir())


def read_cameras(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera file -> timestamps (N,) int64 (microseconds), normalised intrinsics (N, 4) [fx, fy, cx, cy] and
    world-to-camera matrices (N, 4, 4)."""
    try:
        lines = path.read_text().splitlines()[1:]  # the first line is the video's URL
        rows = np.array([line.split() for line in lines if line.strip()], dtype=np.float64)
    except (OSError, ValueError) as err:
        raise UserError(f"cannot read RealEstate10K camera file {path}: {err}") from None
    if rows.ndim != 2 or rows.shape[1] != 19 or not len(rows):
        raise UserError(f"{path}: RealEstate10K camera lines need 19 numbers (timestamp, fx fy cx cy, two distortion "
                        "terms, a 3x4 world-to-camera matrix)")
    world_to_camera = np.tile(np.eye(4), (len(rows), 1, 1))
    world_to_camera[:, :3, :] = rows[:, 7:].reshape(-1, 3, 4)
    return rows[:, 0].astype(np.int64), rows[:, 1:5], world_to_camera


def read_sequence(root: Path, name: str, max_frames: int | None = None) -> EvalSequence:
    """Frames, intrinsics (pixels) and camera-to-world poses of one sequence; no depth."""
    if max_frames is not None and max_frames < 2:
        raise UserError(f"max_frames must be at least 2 (poses are compared in pairs), got {max_frames}")
    base = find_root(root)
    if not (base / name).is_dir():
        raise UserError(f"RealEstate10K {name}: no folder of extracted frames {base / name} beside its camera file")
    stamps, normalised, world_to_camera = read_cameras(base / f"{name}.txt")
    images = {p.stem: p for p in (base / name).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
    present = [i for i, s in enumerate(stamps) if str(s) in images]
    notes = [f"skipped {len(stamps) - len(present)} camera lines without an extracted frame"] if len(present) < len(
        stamps) else []
    if len(present) < 2:
        raise UserError(f"RealEstate10K {name}: {len(present)} of its {len(stamps)} frames are in {base / name} "
                        "(named <timestamp>.png or .jpg); at least 2 are needed")
    if max_frames is not None and len(present) > max_frames:
        present = [present[int(k)] for k in np.round(np.linspace(0, len(present) - 1, max_frames))]
    frames = [read_rgb(images[str(stamps[i])]) for i in present]
    for i, frame in zip(present, frames):
        if frame.shape != frames[0].shape:
            raise UserError(f"RealEstate10K {name}: frame {images[str(stamps[i])].name} is {frame.shape[1]}x"
                            f"{frame.shape[0]}, the first {frames[0].shape[1]}x{frames[0].shape[0]}: extract every "
                            "frame at one size")
    rgb = np.stack(frames)
    h, w = rgb.shape[1:3]
    fx, fy, cx, cy = normalised[present].T
    intrinsics = np.zeros((len(present), 3, 3))
    intrinsics[:, 0, 0], intrinsics[:, 1, 1] = fx * w, fy * h
    intrinsics[:, 0, 2], intrinsics[:, 1, 2], intrinsics[:, 2, 2] = cx * w - 0.5, cy * h - 0.5, 1.0
    return EvalSequence(name, rgb, None, intrinsics, invert_rigid(world_to_camera[present]),
                        frame_names=[str(stamps[i]) for i in present], notes=notes)
