"""Whatever answers queries, seen as a source of windows.

The recipes only need ``query(queries (N, 5)) -> dict`` over a run of frames. A *source* hands out
one answerer per window of frames, so that long videos are processed window by window with memory
bounded by a few windows (dense tracking keeps them all for its run): the model encodes each window
when it is needed; the synthetic oracle answers any window directly.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import contextmanager
from typing import Protocol

import numpy as np

from d4rt.reconstruction.flip_average import flip_averaged


class Answerer(Protocol):
    """Anything that answers D4RT queries: an encoded scene, a ground-truth oracle."""

    num_frames: int

    def query(self, queries) -> dict: ...


class Source(Protocol):
    num_frames: int
    max_window: int | None  # longest window one answerer can take (None: any)
    encoder_size: tuple[int, int] | None  # (H, W) of the encoder input, if there is one

    def window(self, start: int, stop: int) -> Answerer: ...


class AnswererSource:
    """One answerer for the whole clip (an encoded scene, an oracle). Smaller windows, if asked for,
    are frame ranges of it: this is how stitching is tested against exact ground truth."""

    def __init__(self, answerer: Answerer, encoder_size: tuple[int, int] | None = None,
                 max_window: int | None = None):
        self.answerer = answerer
        self.num_frames = answerer.num_frames
        self.max_window = max_window
        self.encoder_size = encoder_size

    def window(self, start: int, stop: int) -> Answerer:
        if (start, stop) == (0, self.num_frames):
            return self.answerer
        return _FrameRange(self.answerer, start, stop)


# Encoded windows kept beyond the two most recent while they fit in this many bytes: a long video's
# recipes (alignment, depth, cameras, tracks) each sweep the windows, and a window re-encoded costs an
# encoder pass, while a kept one costs its tokens and keys/values (about 6 MB for the tiny preset, whose
# encoder pass takes about 0.1 s on one CPU core). A fixed budget, so that memory does not grow with the
# video's length (issue 19; 1 GiB before): a video of a few windows is still encoded once per window.
DEFAULT_CACHE_BYTES = 32 << 20


def encoded_bytes(answerer) -> int:
    """Bytes an encoded window holds in tensors (scene tokens, patch video, cached keys/values; of both
    encodings when it is flip-averaged)."""
    if hasattr(answerer, "parts"):
        return sum(encoded_bytes(part) for part in answerer.parts)
    tensors = [getattr(answerer, "tokens", None), getattr(answerer, "patch_video", None)]
    tensors += [t for pair in (getattr(answerer, "_kv", None) or []) for t in pair]
    return sum(t.numel() * t.element_size() for t in tensors if t is not None)


class ModelSource:
    """A D4RT model over a video: each window is encoded when it is first asked for. Encoded windows are
    kept, least recently used released first, while they fit in ``cache_bytes`` (default
    DEFAULT_CACHE_BYTES), and the ``cache_windows`` most recent always (2 by default: window alignment
    works on consecutive pairs), so memory is bounded by the budget, not the video; inside
    :meth:`keeping` (dense tracking) a given number are kept whatever their size. ``encodes`` counts the
    windows encoded so far; ``on_encode``, if given, is called with no argument after each encode (a
    progress bar's update, say). ``flip_average`` (default: the model's ``config.flip_average``) answers every
    query on each window and on its mirror, averaged (:mod:`d4rt.reconstruction.flip_average`)."""

    def __init__(self, model, video, max_window: int | None = None, cache_windows: int = 2,
                 on_encode: Callable[[], object] | None = None, cache_bytes: int = DEFAULT_CACHE_BYTES,
                 flip_average: bool | None = None):
        self.model, self.video, self.on_encode = model, video, on_encode
        self.encode = flipped_encode(model, flip_average)
        self.num_frames = int(video.shape[0])
        self.max_window = max_window or model.config.max_frames
        size = model.config.image_size
        self.encoder_size = (size, size)
        self.cache_windows = max(1, cache_windows)
        self.cache_bytes = cache_bytes
        self._cache: dict[tuple[int, int], Answerer] = {}  # insertion order = recency
        self.encodes = 0

    def window(self, start: int, stop: int) -> Answerer:
        key = (start, stop)
        if key in self._cache:
            self._cache[key] = self._cache.pop(key)  # most recent last
            return self._cache[key]
        self._release(room_for=1)
        self._cache[key] = self.encode(self.video[start:stop])
        self.encodes += 1
        if self.on_encode is not None:
            self.on_encode()
        return self._cache[key]

    def _release(self, room_for: int = 0) -> None:
        """Release least recently used windows beyond the ``cache_windows`` newest while the cache is
        over its byte budget (making ``room_for`` more windows count against the newest: a window about
        to be encoded is budgeted as the largest kept one)."""
        def total() -> int:
            sizes = [encoded_bytes(a) for a in self._cache.values()]
            return sum(sizes) + room_for * max(sizes, default=0)

        while len(self._cache) + room_for > self.cache_windows and total() > self.cache_bytes:
            self._cache.pop(next(iter(self._cache)))

    @contextmanager
    def keeping(self, count: int):
        """Keep up to ``count`` encoded windows while inside (recipes that sweep every window many times,
        such as dense tracking, would otherwise re-encode them on every sweep); back to the usual
        number, releasing the oldest, on leaving."""
        usual = self.cache_windows
        self.cache_windows = max(usual, count)
        try:
            yield self
        finally:
            self.cache_windows = usual
            self._release()


def flipped_encode(model, flip_average: bool | None = None) -> Callable:
    """``model.encode``, flip-averaged when ``flip_average`` is true (None: as the model's ``config.flip_average``
    says), so that every path that encodes answers alike."""
    if flip_average is None:
        flip_average = model.config.flip_average
    if not isinstance(flip_average, bool):
        raise TypeError(f"flip_average must be true or false, got {flip_average!r}")
    return flip_averaged(model.encode) if flip_average else model.encode


class _FrameRange:
    """Frames [start, stop) of an answerer, re-indexed from 0."""

    def __init__(self, answerer: Answerer, start: int, stop: int):
        self.answerer, self.start = answerer, start
        self.num_frames = stop - start

    def query(self, queries) -> dict:
        q = np.array(queries, dtype=np.float64, copy=True)
        q[:, 2:] += self.start
        return self.answerer.query(q)


def as_source(answerer) -> Source:
    """Wrap an answerer (or pass a source through)."""
    if hasattr(answerer, "window"):
        return answerer
    encoder_size = None
    model = getattr(answerer, "model", None)  # an EncodedScene knows its model
    if model is not None and hasattr(model, "config"):
        encoder_size = (model.config.image_size, model.config.image_size)
    return AnswererSource(answerer, encoder_size)
