"""Input checks and video preparation. Bad input raises :class:`UserError` naming the problem;
nothing is clamped or dropped silently.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from d4rt.errors import UserError

TIME_COLUMNS = {2: "t_src", 3: "t_tgt", 4: "t_cam"}


def as_tensor(value: Any, what: str) -> torch.Tensor:
    if isinstance(value, torch.Tensor):
        return value
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(value))
    raise UserError(f"{what} must be a torch.Tensor or numpy array, got {type(value).__name__}")


def check_video(video: Any, max_frames: int, batched: bool = False) -> torch.Tensor:
    """Check a video and return it as a tensor in its own dtype.

    ``video``: ``(T, H, W, 3)`` (``(B, T, H, W, 3)`` when ``batched``), uint8 or float in [0, 1], with
    1 <= T <= ``max_frames``.
    """
    video = as_tensor(video, "video")
    layout = "(B, T, H, W, 3)" if batched else "(T, H, W, 3)"
    ndim = 5 if batched else 4
    if video.ndim != ndim or video.shape[-1] != 3:
        raise UserError(f"video must have shape {layout} with 3 RGB channels, got {tuple(video.shape)}")
    if min(video.shape) == 0:
        raise UserError(f"video is empty: shape {tuple(video.shape)}")
    if video.dtype != torch.uint8 and not video.dtype.is_floating_point:
        raise UserError(f"video dtype must be uint8 (0..255) or float in [0, 1], got {video.dtype}")
    if video.dtype.is_floating_point:
        if not bool(torch.isfinite(video).all()):
            raise UserError("video contains NaN or infinite values")
        low, high = float(video.min()), float(video.max())
        if low < 0.0 or high > 1.0:
            raise UserError(f"float video values must lie in [0, 1], found [{low:.4g}, {high:.4g}] "
                            "(pass uint8 for 0..255 pixels)")
    frames = video.shape[-4]
    if frames > max_frames:
        raise UserError(f"video has {frames} frames but this model takes at most {max_frames}; "
                        "cut it into windows of at most that many frames")
    return video


def to_unit_float(video: torch.Tensor) -> torch.Tensor:
    """uint8 0..255 or float [0, 1] -> float32 [0, 1], same shape."""
    if video.dtype == torch.uint8:
        return video.float() / 255.0
    return video.float()


def resize_frames(video: torch.Tensor, size: int) -> torch.Tensor:
    """``(T, H, W, 3)`` float -> ``(T, size, size, 3)``: bilinear with antialiasing (no overshoot, so
    values stay in [0, 1]). The aspect ratio is not kept: it reaches the encoder through its own token."""
    if video.shape[1:3] == (size, size):
        return video
    x = video.permute(0, 3, 1, 2)
    x = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False, antialias=True)
    return x.permute(0, 2, 3, 1).contiguous()


def encoder_frames(video: torch.Tensor, size: int, device: torch.device, frames_per_step: int = 8) -> torch.Tensor:
    """``(T, H, W, 3)`` uint8 or float -> ``(T, size, size, 3)`` float32 in [0, 1] on ``device``, a few frames
    at a time, so a long high-resolution clip never exists as a full float copy (nor, when it lives on
    the CPU, as a full copy on the device)."""
    return torch.cat([resize_frames(to_unit_float(video[i:i + frames_per_step].to(device)), size)
                      for i in range(0, video.shape[0], frames_per_step)])


def pad_to_tubelets(video: torch.Tensor, tubelet_frames: int) -> torch.Tensor:
    """Pad the time axis (dim -4) to a multiple of ``tubelet_frames`` by repeating the last frame.

    No frame is dropped; the repeated frames are never queryable (time indices are checked against the
    real frame count).
    """
    frames = video.shape[-4]
    missing = -frames % tubelet_frames
    if missing == 0:
        return video
    last = video.narrow(-4, frames - 1, 1)
    repeat = [1] * video.ndim
    repeat[-4] = missing
    return torch.cat([video, last.repeat(*repeat)], dim=-4)


def check_queries(queries: Any, num_frames: int, batched: bool = False) -> torch.Tensor:
    """Check queries and return them as a float tensor (float64 input stays float64).

    ``queries``: ``(N, 5)`` (``(B, N, 5)`` when ``batched``) = [u, v, t_src, t_tgt, t_cam] with u, v in
    [0, 1] and every time an integer frame index in [0, num_frames).
    """
    queries = as_tensor(queries, "queries")
    layout = "(B, N, 5)" if batched else "(N, 5)"
    if queries.ndim != (3 if batched else 2) or queries.shape[-1] != 5:
        raise UserError(f"queries must have shape {layout} = [u, v, t_src, t_tgt, t_cam], got {tuple(queries.shape)}")
    if not queries.dtype.is_floating_point:
        raise UserError(f"queries must be a float tensor (u, v are continuous), got {queries.dtype}")
    if queries.numel() == 0:
        return queries
    if not bool(torch.isfinite(queries).all()):
        where = _first((~torch.isfinite(queries)).any(-1))
        raise UserError(f"query {_fmt(where)} contains NaN or infinite values")
    uv = queries[..., :2]
    bad_uv = ((uv < 0) | (uv > 1)).any(-1)
    if bool(bad_uv.any()):
        where = _first(bad_uv)
        u, v = (float(x) for x in queries[where][:2])
        raise UserError(f"query {_fmt(where)} has (u, v) = ({u:.6g}, {v:.6g}) outside [0, 1] "
                        f"({int(bad_uv.sum())} queries out of range)")
    for column, name in TIME_COLUMNS.items():
        t = queries[..., column]
        not_integer = t != t.round()
        if bool(not_integer.any()):
            where = _first(not_integer)
            raise UserError(f"query {_fmt(where)} has non-integer {name} = {float(t[where]):.6g}; "
                            "times are integer frame indices")
        out_of_range = (t < 0) | (t >= num_frames)
        if bool(out_of_range.any()):
            where = _first(out_of_range)
            raise UserError(f"query {_fmt(where)} has {name} = {int(t[where])} but the clip has {num_frames} "
                            f"frames (valid 0..{num_frames - 1})")
    return queries


def check_aspect_ratio(aspect_ratio: Any, batch: int) -> torch.Tensor:
    """``(B,)`` original W / H of each clip, finite and positive."""
    aspect_ratio = as_tensor(aspect_ratio, "aspect_ratio")
    if aspect_ratio.shape != (batch,):
        raise UserError(f"aspect_ratio must have shape ({batch},), one W / H per clip, got {tuple(aspect_ratio.shape)}")
    if not bool((torch.isfinite(aspect_ratio) & (aspect_ratio > 0)).all()):
        raise UserError("aspect_ratio must be finite and positive (original width / height)")
    return aspect_ratio


def _first(mask: torch.Tensor) -> tuple[int, ...]:
    return tuple(int(i) for i in mask.nonzero()[0])


def _fmt(where: tuple[int, ...]) -> str:
    return str(where[0]) if len(where) == 1 else str(where)
