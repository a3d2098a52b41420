"""Reconstruction of a stream: frames arrive one at a time and the long-video window recipe runs online.

Windows are those :func:`d4rt.reconstruction.windows.plan_windows` gives the finished video: each window
is encoded as soon as its last frame arrives, aligned to the previous one by the same Sim(3) recipe, and
its own frames' cameras (and depth maps, if asked for) are decoded and handed out; at the end of the
stream the frames after the last full window make a last window of the final ``window`` frames, as
offline. So a stream gives the same cameras as :class:`d4rt.reconstruction.Reconstruction` on the same
frames. Memory holds at most one window of frames and two encoded windows, whatever the stream's length.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from d4rt.config import check_pose_pairs
from d4rt.errors import UserError
from d4rt.geometry.camera import cell_centres_uv, pixel_grid, pixel_to_uv
from d4rt.geometry.transforms import invert_rigid
from d4rt.geometry.umeyama import Similarity
from d4rt.reconstruction.cameras import intrinsics_from_points
from d4rt.reconstruction.reconstruction import DEFAULT_GRID, ask_in_chunks
from d4rt.reconstruction.sources import flipped_encode
from d4rt.reconstruction.windows import (align_pair, identity_similarity, window_camera_grid, window_depth,
                                         window_overlap)


@dataclass
class WindowResult:
    """What one window adds: its own frames (those no earlier window answered).

    frames: (F,) global frame indices; cam_to_world: (F, 4, 4), the world being camera 0; intrinsics:
    (F, 3, 3) in pixels (per frame, the paper's pinhole-median recipe); depth, confidence: (F, h, w) float32
    when depth maps were asked for, else None; window: [start, stop) frames of the window; seconds: the
    wall time from its last frame's arrival to this result (encode + decode).
    """

    frames: np.ndarray
    cam_to_world: np.ndarray
    intrinsics: np.ndarray
    depth: np.ndarray | None
    confidence: np.ndarray | None
    window: tuple[int, int]
    seconds: float


class StreamingReconstruction:
    """Push frames, get window results.

    encode: frames (K, H, W, 3) uint8 -> an answerer of those K frames (``model.encode``); max_window: the
    longest window it takes (a model's ``config.max_frames``). window / overlap: as for
    ``Reconstruction`` (default: max_window, a quarter of it). depth_size: (h, w) of depth maps to decode
    per frame, or None for cameras only. grid / align_fraction / chunk_size / pose_pairs: as for
    ``Reconstruction``. :meth:`from_model` takes these from a model, as ``Reconstruction.from_model`` does.
    """

    def __init__(self, encode: Callable[[np.ndarray], object], max_window: int, *, window: int | None = None,
                 overlap: int | None = None, depth_size: tuple[int, int] | None = None, grid: int = DEFAULT_GRID,
                 align_fraction: float = 0.85, chunk_size: int = 1 << 16, pose_pairs: str = "first"):
        self.encode = encode
        self.window = window or max_window
        if self.window > max_window:
            raise UserError(f"window must be at most the model's {max_window} frames, got {self.window}")
        self.overlap = window_overlap(self.window, overlap)  # as offline: the same windows
        self.depth_size, self.grid, self.align_fraction, self.chunk_size = depth_size, grid, align_fraction, chunk_size
        self.pose_pairs = check_pose_pairs(pose_pairs)
        self.frames: list[np.ndarray] = []  # the frames from self.start on (less than one window)
        self.start = 0  # global index of self.frames[0]
        self.count = 0  # frames pushed so far
        self.size: tuple[int, int] | None = None
        # The last full window: its [start, stop), frames, answerer and Sim(3) to the world (the next window
        # is aligned to it; the final window may start inside it).
        self.previous: tuple[tuple[int, int], np.ndarray, object, Similarity] | None = None
        self.answered = 0  # frames handed out so far
        self.world_from_first: np.ndarray | None = None  # inverse pose of frame 0 (the world is camera 0)
        self.arrived = 0.0

    @classmethod
    def from_model(cls, model, **options) -> "StreamingReconstruction":
        """A stream over a D4RT model (``encode`` and ``config``): its longest window, and ``pose_pairs`` and
        ``flip_average`` (or None) defaulting to the model's own (``config.pose_pairs``, ``config.flip_average``),
        so that the answers are its offline ones."""
        if options.get("pose_pairs") is None:
            options["pose_pairs"] = model.config.pose_pairs
        return cls(flipped_encode(model, options.pop("flip_average", None)), model.config.max_frames, **options)

    def push(self, frame) -> list[WindowResult]:
        """Add the next frame (H, W, 3) uint8; returns the result of the window it completes, if any."""
        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[-1] != 3 or frame.dtype != np.uint8:
            raise UserError(f"stream frames must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
        if self.size is None:
            self.size = frame.shape[:2]
        elif frame.shape[:2] != self.size:
            raise UserError(f"frame {self.count} is {frame.shape[1]}x{frame.shape[0]}, the stream's first was "
                            f"{self.size[1]}x{self.size[0]}")
        self.frames.append(frame)
        self.count += 1
        self.arrived = time.perf_counter()
        if self.count - self.start < self.window:
            return []
        result = self._run(self.start, np.stack(self.frames))
        step = self.window - self.overlap
        self.frames = self.frames[step:]
        self.start += step
        return [result]

    def finish(self) -> list[WindowResult]:
        """The end of the stream: the frames no full window covered, as a last window of the final
        ``window`` frames (all frames, for a stream shorter than one window), as offline."""
        if self.answered >= self.count:
            return []
        if self.count < 2:
            raise UserError(f"the stream ended after {self.count} frame(s); at least 2 are needed")
        first = max(0, self.count - self.window)
        frames = list(self.frames)
        if first < self.start:  # the final window starts inside the last full one
            (a, _), previous_frames, _, _ = self.previous
            frames = list(previous_frames[first - a:self.start - a]) + frames
        self.arrived = time.perf_counter()
        return [self._run(first, np.stack(frames))]

    # ------------------------------------------------------------------------------------------------
    def _ask(self, answerer, start: int, queries: np.ndarray) -> dict:
        q = np.array(queries, dtype=np.float64, copy=True)
        q[:, 2:] -= start  # global frame indices -> the window's own
        return ask_in_chunks(answerer, q, self.chunk_size)

    def _run(self, start: int, frames: np.ndarray) -> WindowResult:
        """Encode the window of ``frames`` (K, H, W, 3) starting at global frame ``start``, align it, and
        decode the cameras (and depth) of the frames it is the first to cover."""
        stop = start + len(frames)
        answerer = self.encode(frames)
        ask = lambda q: self._ask(answerer, start, q)  # noqa: E731
        uv = cell_centres_uv(self.grid)
        if self.previous is None:
            sim = identity_similarity()
        else:
            (a, b), _, previous_answerer, previous_sim = self.previous
            sim = align_pair(lambda q: self._ask(previous_answerer, a, q), ask, (a, b), (start, stop), previous_sim,
                             uv, self.align_fraction)
        own = np.arange(self.answered, stop)
        points, confidence, c2w = window_camera_grid(ask, start, own, uv, sim, self.pose_pairs)
        if self.world_from_first is None:
            self.world_from_first = invert_rigid(c2w[0])
        height, width = self.size
        intrinsics = np.stack([intrinsics_from_points(p, uv, c, height, width, "median", False)
                               for p, c in zip(points, confidence)])
        depth = depth_confidence = None
        if self.depth_size is not None:
            h, w = self.depth_size
            depth, depth_confidence = window_depth(ask, own, pixel_to_uv(pixel_grid(h, w), h, w), float(sim.scale), h,
                                                   w)
        self.previous = ((start, stop), frames, answerer, sim)
        self.answered = stop
        return WindowResult(own, self.world_from_first @ c2w, intrinsics, depth, depth_confidence, (start, stop),
                            time.perf_counter() - self.arrived)
