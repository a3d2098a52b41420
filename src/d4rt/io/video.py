"""Video files through PyAV (FFmpeg)."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np

from d4rt.errors import UserError


def write_video(path: str | Path, frames: np.ndarray, fps: float = 12.0) -> Path:
    """Write (T, H, W, 3) uint8 RGB frames as an H.264 mp4 (odd sizes are padded by one pixel)."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise UserError(f"video frames must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    # yuv420p needs even sizes: pad by edge replication rather than resample.
    pad_h, pad_w = frames.shape[1] % 2, frames.shape[2] % 2
    if pad_h or pad_w:
        frames = np.pad(frames, ((0, 0), (0, pad_h), (0, pad_w), (0, 0)), mode="edge")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), mode="w") as container:
        stream = container.add_stream("libx264", rate=int(round(fps)))
        stream.width, stream.height = frames.shape[2], frames.shape[1]
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": "18"}
        for frame in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path



def read_video(path: str | Path, selection, progress: bool = False
               ) -> tuple[list[np.ndarray], list[float], float | None]:
    """Decode the frames of a video file that ``selection`` (a :class:`d4rt.io.frames.FrameRange`) keeps,
    stopping as soon as it needs no more.

    Returns (frames: list of (H, W, 3) uint8 RGB, timestamps: list of seconds, fps: the stream's average
    frame rate or None). A file FFmpeg cannot open or decode raises a UserError naming it.
    """
    from d4rt.progress import progress_bar

    frames, times = [], []
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
