"""Video files through PyAV (FFmpeg)."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np

from d4rt.errors import UserError


def write_video(path: str | Path, frames, fps: float = 12.0) -> Path:
    """Write RGB frames, (T, H, W, 3) uint8 or an iterable of (H, W, 3) uint8 frames (encoded as they
    come, so a long video need not be held in memory), as an H.264 mp4 (odd sizes are padded by one
    pixel)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    container, stream, size = None, None, None
    try:
        for frame in frames:
            frame = np.asarray(frame)
            if frame.ndim != 3 or frame.shape[-1] != 3 or frame.dtype != np.uint8 or (size and frame.shape != size):
                raise UserError(f"video frames must be (H, W, 3) uint8 of one size, got {frame.shape} {frame.dtype}")
            if container is None:
                size = frame.shape
                container = av.open(str(path), mode="w")
                stream = container.add_stream("libx264", rate=int(round(fps)))
                # yuv420p needs even sizes: pad by edge replication rather than resample.
                stream.width, stream.height = frame.shape[1] + frame.shape[1] % 2, frame.shape[0] + frame.shape[0] % 2
                stream.pix_fmt = "yuv420p"
                # The quality is set by crf; "veryfast" only spends less time searching (measured: 1.6-2x
                # faster, files no larger than "medium"'s on 48 frames of 128x128).
                stream.options = {"crf": "18", "preset": "veryfast"}
            if frame.shape[0] % 2 or frame.shape[1] % 2:
                frame = np.pad(frame, ((0, frame.shape[0] % 2), (0, frame.shape[1] % 2), (0, 0)), mode="edge")
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
                container.mux(packet)
        if container is None:
            raise UserError("a video needs at least one frame (T, H, W, 3) uint8, got none")
        for packet in stream.encode():
            container.mux(packet)
    finally:
        if container is not None:
            container.close()
    return path


def read_video(path: str | Path, selection, progress: bool = False, frames=None
               ) -> tuple[list[np.ndarray], list[float], float | None]:
    """Decode the frames of a video file that ``selection`` (a :class:`d4rt.io.frames.FrameRange`) keeps,
    stopping as soon as it needs no more.

    Returns (frames: list of (H, W, 3) uint8 RGB, timestamps: list of seconds, fps: the stream's average
    frame rate or None). A file FFmpeg cannot open or decode raises a UserError naming it. ``frames``:
    where to put the frames instead of a new list (anything with ``append`` and ``len``, e.g. a spool
    file on disk).
    """
    from d4rt.progress import progress_bar

    frames, times = ([] if frames is None else frames), []
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise UserError(f"{path} has no video stream")
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            fps = float(stream.average_rate) if stream.average_rate else None
            with progress_bar(total=stream.frames or None, desc="decode", unit="frame", disable=not progress) as bar:
                for index, frame in enumerate(container.decode(stream)):
                    if selection.done(index, len(frames)):
                        break
                    bar.update()
                    if selection.keeps(index):
                        frames.append(frame.to_ndarray(format="rgb24"))
                        times.append(float(frame.time) if frame.time is not None else index / (fps or 1.0))
    except av.error.FFmpegError as err:
        raise UserError(f"cannot decode video {path}: {err.strerror or err}") from err
    return frames, times, fps


def iter_video(source: str, format: str | None = None):
    """Decode frames one at a time as they arrive from anything FFmpeg opens: a file, a URL (rtsp://,
    http://), or a camera device (``format`` names its driver, e.g. ``v4l2`` for /dev/video0,
    ``avfoundation`` on macOS). Yields (frame (H, W, 3) uint8 RGB, time in seconds or None); nothing is
    kept. A source FFmpeg cannot open or decode raises a UserError naming it."""
    try:
        with av.open(source, format=format) as container:
            if not container.streams.video:
                raise UserError(f"{source} has no video stream")
            stream = container.streams.video[0]
            for frame in container.decode(stream):
                yield frame.to_ndarray(format="rgb24"), (float(frame.time) if frame.time is not None else None)
    except av.error.FFmpegError as err:
        raise UserError(f"cannot read video {source}: {err.strerror or err}") from err


def iter_raw_frames(stream, height: int, width: int):
    """Raw RGB frames (rgb24: height * width * 3 bytes each, rows top to bottom) from a binary stream such
    as stdin, as they arrive: yields (H, W, 3) uint8 until the stream ends. A trailing partial frame is a
    UserError (the size given does not match what was sent)."""
    size = height * width * 3
    while True:
        data = stream.read(size)
        if not data:
            return
        while len(data) < size:  # a pipe may hand a frame over in pieces
            more = stream.read(size - len(data))
            if not more:
                raise UserError(f"the input ended inside a frame ({len(data)} of {size} bytes): are the frames "
                                f"{width}x{height} rgb24?")
            data += more
        yield np.frombuffer(data, dtype=np.uint8).reshape(height, width, 3)
