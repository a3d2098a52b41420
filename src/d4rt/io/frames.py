"""Reading the frames of a video from whatever the user has: a video file, a folder of images, or an
.npy / .npz array. Every way a source can be unusable (missing, empty, corrupt, unsupported, no images,
mixed sizes, too few frames) raises a one-line :class:`UserError` naming the file.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError
from d4rt.progress import progress_bar

from d4rt.errors import UserError
from d4rt.disk_array import BLOCK_BYTES, DiskArray, frame_blocks
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

    rgb: (T, H, W, 3) uint8 (a numpy array, or with ``load_frames(..., spool=DIR)`` a
    :class:`d4rt.disk_array.DiskArray` read a few frames at a time); indices: (T,) their indices in the
    source; timestamps: (T,) seconds when the source has a clock (video files, image folders named by time
    stamps as in TUM RGB-D), else the source frame indices; fps: frames per second of the selection (None
    when unknown); source: the path.
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


def load_frames(path: str | Path, frames: FrameRange = FrameRange(), progress: bool = False,
                spool: str | Path | None = None) -> Frames:
    """Read the selected frames of a video file, an image folder, or an .npy / .npz array.

    Arrays must be (T, H, W, 3), uint8 or float in [0, 1] (npz: key ``rgb``, ``video`` or ``frames``, or a
    single array). Image folders are read in natural order (``img2`` before ``img10``); their file names
    are used as time stamps when every name is a number (TUM RGB-D layout).

    spool: a folder for the frames on disk. Then ``rgb`` is a DiskArray that is read a few frames at a
    time and memory does not grow with the video's length: videos, image folders and .npz arrays are
    decoded once into a raw file there (3 bytes per pixel and frame); a uint8 .npy file whose selected
    frames are consecutive is read in place. The folder must outlive the frames (a temporary folder).
    """
    path = check_input(path)
    if path.is_dir():
        result = _load_folder(path, frames, progress, spool)
    else:
        suffix = path.suffix.lower()
        result = (_load_video(path, frames, progress, spool) if suffix in VIDEO_SUFFIXES
                  else _load_array(path, frames, spool))
    if len(result.rgb) < MIN_FRAMES:
        raise UserError(f"{path} gives {len(result.rgb)} frame(s) ({frames.describe()}); "
                        f"at least {MIN_FRAMES} are needed")
    return result


class FrameSpool:
    """Frames appended one at a time to a raw file in ``directory``; ``frames()`` is then a DiskArray."""

    def __init__(self, directory: str | Path, source: Path):
        self.directory, self.source, self.array = Path(directory), source, None

    def append(self, frame: np.ndarray) -> None:
        frame = np.asarray(frame)
        if self.array is None:
            handle, name = tempfile.mkstemp(prefix="frames-", suffix=".raw", dir=self.directory)
            os.close(handle)
            self.array = DiskArray.growable(name, frame.shape, np.uint8)
        elif frame.shape != self.array.row_shape:
            raise UserError(f"{self.source}: frame {len(self.array)} is {frame.shape[1]}x{frame.shape[0]}, the "
                            f"first was {self.array.row_shape[1]}x{self.array.row_shape[0]}")
        self.array.append(frame[None])

    def __len__(self) -> int:
        return 0 if self.array is None else len(self.array)

    def frames(self):
        return self.array if self.array is not None else np.zeros((0, 1, 1, 3), np.uint8)


def _collector(spool, source: Path):
    return [] if spool is None else FrameSpool(spool, source)


def _collected(frames) -> np.ndarray | DiskArray:
    if isinstance(frames, FrameSpool):
        return frames.frames()
    return np.stack(frames) if frames else np.zeros((0, 1, 1, 3), np.uint8)


def _load_video(path: Path, selection: FrameRange, progress: bool, spool=None) -> Frames:
    rgb, times, fps = read_video(path, selection, progress, frames=_collector(spool, path))
    if not len(rgb):
        raise UserError(f"{path} has no frames in the selected range ({selection.describe()})")
    index = selection.start + selection.stride * np.arange(len(rgb))
    return Frames(_collected(rgb), index, np.array(times), fps / selection.stride if fps else None, str(path))


def _natural_key(name: str) -> list:
    return [(0, float(part), "") if part[:1].isdigit() else (1, 0.0, part)
            for part in re.findall(r"\d+(?:\.\d+)?|\D+", name)]


def _load_folder(path: Path, selection: FrameRange, progress: bool, spool=None) -> Frames:
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
    rgb = _collector(spool, path)
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
    return Frames(_collected(rgb), index,
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


def _load_array(path: Path, selection: FrameRange, spool=None) -> Frames:
    try:
        if path.suffix.lower() == ".npy":
            video = DiskArray.open_npy(path) if spool is not None else np.load(path, mmap_mode="r", allow_pickle=False)
        else:
            with np.load(path, allow_pickle=False) as npz:
                keys = [k for k in ARRAY_KEYS if k in npz.files] or (npz.files if len(npz.files) == 1 else [])
                if not keys:
                    raise UserError(f"{path} holds arrays {sorted(npz.files)}; expected one of {list(ARRAY_KEYS)} "
                                    "or a single array")
                video = npz[keys[0]] if spool is None else _npz_member(path, keys[0], spool)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as err:
        if isinstance(err, UserError):
            raise
        raise UserError(f"cannot read array file {path}: {err}") from err
    if video.ndim != 4 or video.shape[-1] != 3 or min(video.shape) == 0:
        raise UserError(f"{path} holds an array of shape {video.shape}; expected frames (T, H, W, 3)")
    if video.dtype != np.uint8 and not np.issubdtype(video.dtype, np.floating):
        raise UserError(f"{path} has dtype {video.dtype}; expected uint8 or float in [0, 1]")
    index = selection.select(video.shape[0])
    if spool is None:
        rgb = _as_uint8(np.asarray(video[index]), path)
    elif isinstance(video, DiskArray) and video.dtype == np.uint8 and len(index) and np.all(np.diff(index) == 1):
        rgb = DiskArray(video.path, (len(index), *video.shape[1:]), np.uint8, video.offset + int(index[0]) * video.row_bytes)
    else:
        frames = FrameSpool(spool, path)
        for a, b in frame_blocks(index, frames_per_block=max(1, BLOCK_BYTES // max(video.row_bytes, 1))):
            for frame in _as_uint8(np.asarray(video[index[a:b]]), path):
                frames.append(frame)
        rgb = frames.frames()
    return Frames(rgb, index, index.astype(np.float64), None, str(path))


def _as_uint8(rgb: np.ndarray, path: Path) -> np.ndarray:
    if rgb.dtype == np.uint8:
        return rgb
    if not np.isfinite(rgb).all() or rgb.min() < 0 or rgb.max() > 1:
        raise UserError(f"{path} has float values outside [0, 1] (or NaN); expected uint8 or float in [0, 1]")
    return np.round(rgb * 255).astype(np.uint8)


def _npz_member(path: Path, key: str, spool) -> DiskArray:
    """An .npz member decompressed, a block at a time, into a raw file in the spool folder."""
    with zipfile.ZipFile(path) as archive, archive.open(f"{key}.npy") as member:
        version = np.lib.format.read_magic(member)
        shape, fortran, dtype = (np.lib.format.read_array_header_1_0(member) if version == (1, 0)
                                 else np.lib.format.read_array_header_2_0(member))
        if fortran or dtype.hasobject:
            raise UserError(f"{path}: array {key!r} must be a C-ordered array of numbers")
        handle, name = tempfile.mkstemp(prefix="array-", suffix=".raw", dir=spool)
        with os.fdopen(handle, "wb") as out:
            shutil.copyfileobj(member, out, 16 << 20)
    return DiskArray(name, shape, dtype)
