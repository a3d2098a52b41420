"""The paper's augmentations (App. A), applied consistently with the geometry.

Geometric ones are a ``View`` (crop / zoom-in / temporal stride): they change the intrinsics and the
query coordinates and frame indices exactly, so targets from the oracle stay exact. Photometric ones
(colour jitter with one set of parameters for the whole clip, colour drop, Gaussian blur) change only
the pixels. Ranges the paper does not give are documented choices here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from d4rt.errors import UserError
from d4rt.geometry.view import View
from d4rt.synthetic.clip import view_rgb


CROP_POLICIES = ("paper", "centered", "none")


@dataclass
class AugmentConfig:
    """Augmentation knobs. Paper: colour drop p 0.2, blur p 0.4, crop 0.3-1.0 of the frame with a
    log-uniform aspect ratio, zoom-in p 0.05, random temporal stride; the rest are our choices."""

    enabled: bool = True
    crop_scale: tuple[float, float] = (0.3, 1.0)  # fraction of the frame's area
    crop_aspect: tuple[float, float] = (0.5, 2.0)  # log-uniform range of the crop's width / height
    zoom_prob: float = 0.05
    zoom_scale: tuple[float, float] = (0.05, 0.3)  # a zoom-in is a crop this small, upsampled
    max_stride: int = 3
    # Where crops sit. "paper": anywhere in the frame (the principal point of the crop can land far
    # off-centre); "centered": the crop's centre within ``center_jitter`` (a fraction of the frame's
    # width / height) of the frame's centre, so the principal point stays near the image centre as in
    # ordinary video; "none": the whole frame (no crop, no zoom-in), only resized.
    crop_policy: str = "paper"
    center_jitter: float = 0.05
    jitter_prob: float = 0.8
    brightness: float = 0.3
    contrast: float = 0.3
    saturation: float = 0.3
    hue: float = 0.05
    color_drop_prob: float = 0.2
    blur_prob: float = 0.4
    blur_sigma: tuple[float, float] = (0.1, 1.5)  # pixels of the output video

    def validate(self) -> None:
        lo, hi = self.crop_scale
        if not 0 < lo <= hi <= 1:
            raise UserError(f"crop_scale must satisfy 0 < low <= high <= 1, got {self.crop_scale}")
        if not 0 < self.crop_aspect[0] <= self.crop_aspect[1]:
            raise UserError(f"crop_aspect must be a positive (low, high) range, got {self.crop_aspect}")
        if self.crop_policy not in CROP_POLICIES:
            raise UserError(f"crop_policy must be one of {', '.join(CROP_POLICIES)}, got {self.crop_policy!r}")
        if not 0 <= self.center_jitter <= 0.5:
            raise UserError(f"center_jitter must be in [0, 0.5], got {self.center_jitter}")
        if self.max_stride < 1:
            raise UserError(f"max_stride must be >= 1, got {self.max_stride}")


def sample_stride(rng: np.random.Generator, source_frames: int, frames: int, max_stride: int) -> int:
    """A random temporal stride that still fits ``frames`` frames in ``source_frames``."""
    if source_frames < frames:
        raise UserError(f"clip has {source_frames} frames, fewer than the {frames} asked for")
    fit = (source_frames - 1) // max(frames - 1, 1) if frames > 1 else max_stride
    return int(rng.integers(1, max(1, min(max_stride, fit)) + 1))


def sample_view(rng: np.random.Generator, source_frames: int, source_size: tuple[int, int], frames: int,
                size: tuple[int, int], config: AugmentConfig, stride: int | None = None) -> View:
    """A random crop (or zoom-in) of a random strided run of frames, resized to ``size`` (H, W)."""
    hs, ws = source_size
    if not config.enabled:
        return View(source_size, (0, 0, ws, hs), size, tuple(range(frames)))
    if stride is None:
        stride = sample_stride(rng, source_frames, frames, config.max_stride)
    start = int(rng.integers(0, source_frames - stride * (frames - 1)))
    frame_ids = tuple(start + stride * k for k in range(frames))
    if config.crop_policy == "none":
        return View(source_size, (0, 0, ws, hs), size, frame_ids)
    scale = config.zoom_scale if rng.uniform() < config.zoom_prob else config.crop_scale
    area = hs * ws
    for _ in range(10):  # like torchvision's RandomResizedCrop: retry, then fall back to the full frame
        target = rng.uniform(*scale) * area
        aspect = math.exp(rng.uniform(math.log(config.crop_aspect[0]), math.log(config.crop_aspect[1])))
        w = int(round(math.sqrt(target * aspect)))
        h = int(round(math.sqrt(target / aspect)))
        if 1 <= w <= ws and 1 <= h <= hs:
            if config.crop_policy == "centered":
                x0 = _centered_start(rng, ws, w, config.center_jitter)
                y0 = _centered_start(rng, hs, h, config.center_jitter)
            else:
                x0 = int(rng.integers(0, ws - w + 1))
                y0 = int(rng.integers(0, hs - h + 1))
            return View(source_size, (x0, y0, w, h), size, frame_ids)
    return View(source_size, (0, 0, ws, hs), size, frame_ids)


def _centered_start(rng: np.random.Generator, full: int, length: int, jitter: float) -> int:
    """First pixel of a ``length``-pixel crop whose centre lies within ``jitter * full`` pixels of the
    frame's centre (as far as the frame allows)."""
    offset = rng.uniform(-jitter, jitter) * full
    return int(np.clip(round((full - length) / 2 + offset), 0, full - length))


@dataclass(frozen=True)
class PhotometricDraw:
    """One clip's photometric augmentation, drawn once so that it can be applied alike to several copies of the
    clip's frames (the encoder's frames and the original-resolution ones RGB patches are cut from).

    jitter: the colour-jitter operations in the order applied, as (op, factor): 0 brightness (a factor),
    1 contrast (a factor), 2 saturation (a factor), 3 hue (a fraction of a turn); empty for none.
    color_drop: turn the clip grey. blur_sigma: the Gaussian blur's sigma in pixels of the view's output size,
    or None for no blur."""

    jitter: tuple[tuple[int, float], ...]
    color_drop: bool
    blur_sigma: float | None


def draw_photometric(rng: np.random.Generator, config: AugmentConfig) -> PhotometricDraw | None:
    """The random draws of :func:`photometric_augment` (in its order), or None when augmentation is off."""
    if not config.enabled:
        return None
    jitter = []
    if rng.uniform() < config.jitter_prob:
        spreads = (config.brightness, config.contrast, config.saturation)
        for op in rng.permutation(4):
            op = int(op)
            factor = rng.uniform(1 - spreads[op], 1 + spreads[op]) if op < 3 else rng.uniform(-config.hue, config.hue)
            jitter.append((op, float(factor)))
    color_drop = bool(rng.uniform() < config.color_drop_prob)
    blur_sigma = float(rng.uniform(*config.blur_sigma)) if rng.uniform() < config.blur_prob else None
    return PhotometricDraw(tuple(jitter), color_drop, blur_sigma)


def apply_photometric(video: torch.Tensor, draw: PhotometricDraw | None,
                      pixel_scale: tuple[float, float] = (1.0, 1.0)) -> torch.Tensor:
    """``video (T, H, W, 3)`` float in [0, 1] -> the same shape in [0, 1], augmented by ``draw`` (None: unchanged).

    pixel_scale: (rows, columns) of ``video`` per pixel of the view's output size; the blur's sigma is scaled
    by it, so frames of another resolution (the original-resolution crop) are blurred by the same amount of
    the scene."""
    if draw is None:
        return video
    x = video.permute(0, 3, 1, 2)  # (T, 3, H, W)
    for op, factor in draw.jitter:
        if op == 0:
            x = x * factor
        elif op == 1:
            mean = _gray(x).mean()  # one mean over the whole clip keeps frames consistent
            x = (x - mean) * factor + mean
        elif op == 2:
            g = _gray(x)
            x = (x - g) * factor + g
        else:
            x = _rotate_hue(x, factor)
        x = x.clamp(0.0, 1.0)
    if draw.color_drop:
        x = _gray(x).expand_as(x)
    if draw.blur_sigma is not None:
        x = _gaussian_blur(x, draw.blur_sigma * pixel_scale[0], draw.blur_sigma * pixel_scale[1])
    return x.clamp(0.0, 1.0).permute(0, 2, 3, 1).contiguous()


def photometric_augment(video: torch.Tensor, rng: np.random.Generator, config: AugmentConfig) -> torch.Tensor:
    """Colour jitter (one draw for the whole clip), colour drop and Gaussian blur.

    video: (T, H, W, 3) float in [0, 1] -> same shape, in [0, 1].
    """
    return apply_photometric(video, draw_photometric(rng, config))


def augmented_view_frames(rgb: np.ndarray, view: View, rng: np.random.Generator, config: AugmentConfig,
                          original: bool = False) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The frames of ``view`` for training, photometrically augmented.

    rgb: ``(T, H, W, 3)`` uint8 source frames. Returns ``video (T_view, h, w, 3)`` float in [0, 1] (cropped and
    resized to the view's size) and, with ``original``, ``patch_video (T_view, h_crop, w_crop, 3)`` uint8: the same
    crop at the source resolution, not resized, with the same augmentation (one draw; the blur's sigma scaled to its
    pixels), rounded back to 0..255 (a quarter of float32's memory for frames of any size; the patch sampler reads
    uint8); else None. Why: a model with ``rgb_patch_source="original"`` cuts its query patches from the input
    video's own pixels at inference, so training must give it those pixels.
    """
    draw = draw_photometric(rng, config)
    video = apply_photometric(torch.from_numpy(view_rgb(rgb, view)).float() / 255.0, draw)
    if not original:
        return video, None
    x0, y0, w, h = view.crop
    native = torch.from_numpy(np.ascontiguousarray(rgb[list(view.frames), y0:y0 + h, x0:x0 + w])).float() / 255.0
    patch_video = apply_photometric(native, draw, (h / view.size[0], w / view.size[1]))
    return video, (patch_video * 255.0).round().to(torch.uint8)


def _gray(x: torch.Tensor) -> torch.Tensor:
    return (0.299 * x[:, 0:1] + 0.587 * x[:, 1:2] + 0.114 * x[:, 2:3])


def _rotate_hue(x: torch.Tensor, fraction: float) -> torch.Tensor:
    """Rotate hue by ``fraction`` of a turn: a rotation about the grey axis of RGB space."""
    angle = 2 * math.pi * fraction
    c, s = math.cos(angle), math.sin(angle)
    k = 1.0 / 3.0
    sq = math.sqrt(k)
    m = torch.tensor([
        [c + (1 - c) * k, k * (1 - c) - sq * s, k * (1 - c) + sq * s],
        [k * (1 - c) + sq * s, c + k * (1 - c), k * (1 - c) - sq * s],
        [k * (1 - c) - sq * s, k * (1 - c) + sq * s, c + k * (1 - c)],
    ], dtype=x.dtype, device=x.device)
    return torch.einsum("ij,tjhw->tihw", m, x)


def _gaussian_kernel(sigma: float) -> list[float]:
    """Normalised Gaussian weights over a radius of ceil(3 sigma) (at least 1) pixels."""
    radius = max(1, int(math.ceil(3 * sigma)))
    k = torch.exp(-(torch.arange(-radius, radius + 1, dtype=torch.float64) ** 2) / (2 * sigma**2))
    return (k / k.sum()).tolist()


def _gaussian_blur(x: torch.Tensor, sigma_rows: float, sigma_columns: float) -> torch.Tensor:
    """Separable Gaussian blur of (T, C, H, W); ``sigma_rows`` spreads vertically (across rows), ``sigma_columns``
    horizontally, both in pixels; borders replicate."""
    t, c, h, w = x.shape
    # Weighted sums of shifted slices, one axis at a time: a one-channel conv2d was 5-10x slower on a
    # loader's single thread.
    k = _gaussian_kernel(sigma_columns)
    radius = len(k) // 2
    y = F.pad(x.reshape(t * c, 1, h, w), (radius, radius, 0, 0), mode="replicate")[:, 0]
    y = sum(weight * y[:, :, i:i + w] for i, weight in enumerate(k))
    k = _gaussian_kernel(sigma_rows)
    radius = len(k) // 2
    y = F.pad(y[:, None], (0, 0, radius, radius), mode="replicate")[:, 0]
    y = sum(weight * y[:, i:i + h] for i, weight in enumerate(k))
    return y.reshape(t, c, h, w)
