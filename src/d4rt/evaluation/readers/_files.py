"""File helpers shared by the benchmark readers: image decoding, frame selection, clear errors."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from d4rt.errors import UserError


def read_rgb(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """An image file as (H, W, 3) uint8; resized (bilinear, antialiased) to size = (H, W) if given."""
    try:
        with Image.open(path) as image:
            image = image.convert("RGB")
            if size is not None and image.size != (size[1], size[0]):
                image = image.resize((size[1], size[0]), Image.Resampling.BILINEAR, reducing_gap=None)
            return np.asarray(image, dtype=np.uint8)
    except (OSError, UnidentifiedImageError) as err:
        raise UserError(f"cannot read image {path}: {err}") from None


def read_uint16_png(path: Path) -> np.ndarray:
    """A 16-bit single-channel PNG (depth maps) as (H, W) int64 raw values."""
    try:
        with Image.open(path) as image:
            raw = np.asarray(image)
    except (OSError, UnidentifiedImageError) as err:
        raise UserError(f"cannot read depth image {path}: {err}") from None
    if raw.ndim != 2 or raw.dtype not in (np.uint16, np.int32, np.int64, np.uint8):
        raise UserError(f"{path} is not a single-channel 16-bit depth PNG (got {raw.dtype}, shape {raw.shape})")
    return raw.astype(np.int64)


def read_text_matrix(path: Path, shape: tuple[int, int], what: str) -> np.ndarray:
    """A matrix written as whitespace-separated numbers (row major), e.g. KITTI intrinsics, ScanNet poses."""
    try:
        values = np.array(path.read_text().split(), dtype=np.float64)
    except (OSError, ValueError) as err:
        raise UserError(f"cannot read {what} {path}: {err}") from None
    if values.size != shape[0] * shape[1]:
        raise UserError(f"{path}: expected a {shape[0]}x{shape[1]} {what} ({shape[0] * shape[1]} numbers), "
                        f"got {values.size}")
    return values.reshape(shape)


def natural_key(path: Path) -> list:
    """Sort key that orders frame_2 before frame_10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def sorted_files(directory: Path, pattern: str) -> list[Path]:
    """Files in ``directory`` matching ``pattern``, in natural order; an error if there are none."""
    if not directory.is_dir():
        raise UserError(f"expected a directory at {directory}")
    files = sorted((p for p in directory.glob(pattern) if p.is_file()), key=natural_key)
    if not files:
        raise UserError(f"no {pattern} files in {directory}")
    return files


def select_frames(items: list, frames: slice | None, what: str) -> list:
    """``items[frames]``, refusing a selection that is empty (never silently evaluates nothing)."""
    chosen = items if frames is None else items[frames]
    if not chosen:
        raise UserError(f"the frame selection {frames} leaves no frames of {what} ({len(items)} available)")
    return chosen


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float, frames: int) -> np.ndarray:
    """(frames, 3, 3) pinhole matrices from pixel focal lengths and principal point."""
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return np.repeat(k[None], frames, axis=0)
