"""Reading the frames of a video from whatever the user has: a video file, a folder of images, or an
.npy / .npz array. Every way a source can be unusable (missing, empty, corrupt, unsupported, no images,
mixed sizes, too few frames) raises a one-line :class:`UserError` naming the file.
"""

from __future__ import annotations

import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError
from d4rt.progress import progress_bar

from d4rt.errors import UserError
from d4rt.io.video import read_video

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".webm", ".mkv", ".m4v")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
ARRAY_SUFFIXES = (".npy", ".npz")
ARRAY_KEYS = ("rgb", "video", "frames")  # npz keys tried in order (``rgb``: d4rt clip files)
MIN_FRAMES = 2  # cameras and tracks need at least two frames


@dataclass(frozen=True)
class FrameRange:
    """Which frames of a source to use: indices start, start + stride, ... below ``end`` (exclusive;
    None = to the end), at most ``max_frames`` of them (None = all)."""

    start: int = 0
    end: int | None = None
    stride: int = 1
    max_frames: int | None = None

    def __post_init__(self) -> None:
        if self.start < 0:
            raise UserError(f"the start frame must be >= 0, got {self.start}")
        if self.end is not None and self.end <= self.start:
            raise UserError(f"the end frame ({self.end}, exclusive) must be after the start frame ({self.start})")
        if self.stride < 1:
            raise UserError(f"the frame stride must be >= 1, got {self.stride}")
        if self.max_frames is not None and self.max_frames < 1:
            raise UserError(f"the maximum number of frames must be >= 1, got {self.max_frames}")

    def keeps(self, index: int) -> bool:
        """Whether source frame ``index`` is used (ignoring max_frames: see ``done``)."""
        in_range = index >= self.start and (self.end is None or index < self.end)
        return in_range and (index - self.start) % self.stride == 0

    def done(self, index: int, kept: int) -> bool:
        """Whether no frame from ``index`` on is needed, ``kept`` frames having been kept before it."""
        return (self.end is not None and index >= self.end) or (self.max_frames is not None and kept >= self.max_frames)

    def select(self, count: int) -> np.ndarray:
        """The used indices of a source of ``count`` frames."""
        picked = [i for i in range(min(count, self.end or count)) if self.keeps(i)]
        return np.array(picked[: self.max_frames], dtype=np.int64)

    def describe(self) -> str:
        parts = [f"start {self.start}", f"end {self.end if self.end is not None else 'last'}", f"stride {self.stride}"]
        if self.max_frames is not None:
            parts.append(f"at most {self.max_frames} frames")
        return ", ".join(parts)


@dataclass
class Frames:
    """The frames to reconstruct.

    rgb: (T, H, W, 3) uint8; indices: (T,) their indices in the source; timestamps: (T,) seconds when
    the source has a clock (video files, image folders named by time stamps as in TUM RGB-D), else the
    source frame indices; fps: frames per second of the selection (None when unknown); source: the path.
    """

    rgb: np.ndarray
    indices: np.ndarray
    timestamps: np.ndarray
    fps: float | None
    source: str

    @property
    def has_clock(self) -> bool:
        return self.fps is not None


def check_input(path: str | Path) -> Path:
    """The checks of an input path that need no decoding (it exists, a known kind, not empty): cheap
    enough to run before anything else."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"{path} does not exist")
    if not path.is_dir():
        suffix = path.suffix.lower()
        if suffix not in VIDEO_SUFFIXES + ARRAY_SUFFIXES:
            raise UserError(f"{path}: unsupported input type {suffix or '(no extension)'!r}; expected a video "
                            f"({' '.join(VIDEO_SUFFIXES)}), a folder of images, or an .npy / .npz array")
        if path.stat().st_size == 0:
            raise UserError(f"{path} is empty (0 bytes)")
    return path


def load_frames(path: str | Path, frames: FrameRange = FrameRange(), progress: bool = False) -> Frames:
    """Read the selected frames of a video file, an image folder, or an .npy / .npz array.

    Arrays must be (T, H, W, 3), uint8 or float in [0, 1] (npz: key ``rgb``, ``video`` or ``frames``, or a
    single array). Image folders are read in natural order (``img2`` before ``img10``); their file names
    are used as time stamps when every name is a number (TUM RGB-D layout).
    """
    path = check_input(path)
    if path.is_dir():
        result = _load_folder(path, frames, progress)
    else:
        suffix = path.suffix.lower()
        result = _load_video(path, frames, progress) if suffix in VIDEO_SUFFIXES else _load_array(path, frames)
    if len(result.rgb) < MIN_FRAMES:
        raise UserError(f"{path} gives {len(result.rgb)} frame(s) ({frames.describe()}); "
                        f"at least {MIN_FRAMES} are needed")
    return result


def _load_video(path: Path, selection: FrameRange, progress: bool) -> Frames:
    rgb, times, fps = read_video(path, selection, progress)
    if not rgb:
        raise UserError(f"{path} has no frames in the selected range ({selection.describe()})")
    index = selection.start + selection.stride * np.arange(len(rgb))
    return Frames(np.stack(rgb), index, np.array(times), fps / selection.stride if fps else None, str(path))


def _natural_key(name: str) -> list:
    return [(0, float(part), "") if part[:1].isdigit() else (1, 0.0, part)
            for part in re.findall(r"\d+(?:\.\d+)?|\D+", name)]


def _load_folder(path: Path, selection: FrameRange, progress: bool) -> Frames:
    files = sorted((p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                   key=lambda p: _natural_key(p.name))
    if not files:
        raise UserError(f"no images ({' '.join(IMAGE_SUFFIXES)}) in folder {path}")
    index = selection.select(len(files))
    sizes = [_image_size(files[i]) for i in index]  # headers only: fails fast, before any decoding
    for i, size in zip(index, sizes):
        if size != sizes[0]:
            raise UserError(f"images in {path} have mixed sizes: {files[i].name} is {size[0]}x{size[1]} "
                            f"but {files[index[0]].name} is {sizes[0][0]}x{sizes[0][1]}")
    rgb = []
    for i in progress_bar(index, desc="decode", unit="frame", disable=not progress):
        try:
            with Image.open(files[i]) as image:
                rgb.append(np.asarray(image.convert("RGB")))
        except OSError as err:
            raise UserError(f"cannot read image {files[i]}: {err}") from err
    stamps = _numeric_stems([files[i] for i in index])
    fps = None
    if stamps is not None and len(stamps) > 1:
        fps = 1.0 / float(np.median(np.diff(stamps)))
    return Frames(np.stack(rgb) if rgb else np.zeros((0, 1, 1, 3), np.uint8), index,
                  stamps if stamps is not None else index.astype(np.float64), fps, str(path))


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the image's header."""
    try:
        with Image.open(path) as image:
            return image.size
    except (UnidentifiedImageError, OSError) as err:
        raise UserError(f"cannot read image {path}: {err}") from err


def _numeric_stems(files: list[Path]) -> np.ndarray | None:
    """The file names as seconds when every name is a number and they increase (TUM RGB-D), else None."""
    try:
        stamps = np.array([float(f.stem) for f in files])
    except ValueError:
        return None
    return stamps if np.all(np.diff(stamps) > 0) else None


def _load_array(path: Path, selection: FrameRange) -> Frames:
    try:
        if path.suffix.lower() == ".npy":
            video = np.load(path, mmap_mode="r", allow_pickle=False)
        else:
            with np.load(path, allow_pickle=False) as npz:
                keys = [k for k in ARRAY_KEYS if k in npz.files] or (npz.files if len(npz.files) == 1 else [])
                if not keys:
                    raise UserError(f"{path} holds arrays {sorted(npz.files)}; expected one of {list(ARRAY_KEYS)} "
                                    "or a single array")
                video = npz[keys[0]]
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as err:
        if isinstance(err, UserError):
            raise
        raise UserError(f"cannot read array file {path}: {err}") from err
    if video.ndim != 4 or video.shape[-1] != 3 or min(video.shape) == 0:
        raise UserError(f"{path} holds an array of shape {video.shape}; expected frames (T, H, W, 3)")
    index = selection.select(video.shape[0])
    rgb = np.asarray(video[index])
    if rgb.dtype != np.uint8:
        if not np.issubdtype(rgb.dtype, np.floating):
            raise UserError(f"{path} has dtype {rgb.dtype}; expected uint8 or float in [0, 1]")
        if not np.isfinite(rgb).all() or rgb.min() < 0 or rgb.max() > 1:
            raise UserError(f"{path} has float values outside [0, 1] (or NaN); expected uint8 or float in [0, 1]")
        rgb = np.round(rgb * 255).astype(np.uint8)
    return Frames(rgb, index, index.astype(np.float64), None, str(path))
