"""Torch datasets that yield (video, queries, targets) training samples from synthetic clips.

Clips are rendered on the fly from seeds (``source="render"``) or read from ``d4rt generate`` output
(``source="files"``: any npz in the clip layout, which is also the "bring your own data" format).
Every sample is a deterministic function of (seed, epoch, index), which makes runs reproducible and
resumable.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from d4rt.data.augment import AugmentConfig, augmented_view_frames, sample_stride, sample_view
from d4rt.data.sampler import QuerySampler, QuerySamplerConfig
from d4rt.errors import UserError
from d4rt.geometry.view import View
from d4rt.synthetic.clip import Clip, load_clip, view_depth
from d4rt.synthetic.generate import render_clip

TARGET_KEYS = ("points", "uv", "visibility", "motion", "normals")


@dataclass
class DatasetConfig:
    """Where clips come from and what a sample looks like.

    frames, size: the sample's clip length and (H, W) (the model's encoder input, usually square).
    frame_choices: when given, each sample's clip length is drawn uniformly from it instead of
    ``frames`` (repeat a value to weight it): short clips are cheap, and the occasional long one keeps
    the time embeddings of long windows trained. Samples of different lengths cannot be stacked, so
    this needs one clip per batch.
    render_pixels: on-the-fly clips are rendered at this many pixels per frame (aspect ratio drawn
    log-uniformly from ``render_aspect``) before cropping. num_clips: dataset length for rendering.
    render_device: where on-the-fly clips are ray-cast: "cpu" (the default), "cuda" or "cuda:N". Why: on a
    GPU machine the CPU renderer, not the model, bounds a run (about 1.5-2 s of one core per 24-frame
    128 x 128 clip); the renderer is torch code and runs on any device. A clip rendered on a GPU may differ
    from the CPU's in the last bits (float rounding), so a run's exact sample stream is per render device.
    Loader workers that render on a GPU are started with "spawn" (CUDA does not survive a fork).
    echo: samples drawn from each clip ("data echoing", Choi et al. 2019): the training stream takes every
    clip ``echo`` times in a row, each time with its own view, queries and photometric augmentation, and a
    loader process renders (or reads) the clip once for them. Why: a run whose loaders cannot keep up with the
    model (GPU training here; CPU training, where the rendering worker takes a core from the model) sees more
    samples per minute for the same rendering. Only the first of a clip's samples is the sample of an
    ``echo: 1`` stream. The clip is reused only when its samples reach the same loader process in a row: with
    at most one loader worker, or with a ``batch_size`` that is a multiple of ``echo`` (workers take whole
    batches); otherwise each sample renders it again (still correct, no faster).
    """

    source: str = "render"
    directory: str | None = None
    num_clips: int = 10000
    seed: int = 0
    frames: int = 16
    frame_choices: tuple[int, ...] = ()
    size: tuple[int, int] = (128, 128)
    render_pixels: int = 144 * 144
    render_aspect: tuple[float, float] = (0.5, 2.0)
    scene_options: dict = field(default_factory=dict)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    sampler: QuerySamplerConfig = field(default_factory=QuerySamplerConfig)
    render_device: str = "cpu"
    echo: int = 1

    def __post_init__(self) -> None:
        if isinstance(self.augment, dict):
            self.augment = AugmentConfig(**self.augment)
        if isinstance(self.sampler, dict):
            self.sampler = QuerySamplerConfig(**self.sampler)
        self.size = tuple(self.size)
        self.frame_choices = tuple(int(f) for f in self.frame_choices)
        if self.source not in ("render", "files"):
            raise UserError(f"dataset source must be 'render' or 'files', got {self.source!r}")
        if min((self.frames, *self.frame_choices)) < 1 or min(self.size) < 1:
            raise UserError(f"frames, frame_choices and size must be positive, got {self.frames}, "
                            f"{self.frame_choices}, {self.size}")

        if isinstance(self.echo, bool) or not isinstance(self.echo, int) or self.echo < 1:
            raise UserError(f"dataset echo must be a positive integer (samples per clip), got {self.echo!r}")
        device = str(self.render_device)
        if not re.fullmatch(r"cpu|cuda(:\d+)?", device):
            raise UserError(f"dataset render_device must be 'cpu', 'cuda' or 'cuda:N', got {self.render_device!r}")

    @property
    def renders_on_gpu(self) -> bool:
        """True when on-the-fly clips are ray-cast on a CUDA device (loader workers must then be spawned)."""
        return self.source == "render" and self.render_device != "cpu"

    @property
    def max_frames(self) -> int:
        """The longest clip a sample can have."""
        return max(self.frame_choices) if self.frame_choices else self.frames


def make_training_sample(clip: Clip, view: View, rng: np.random.Generator, sampler: QuerySampler,
                         augment: AugmentConfig, patch_frames: bool = False) -> dict:
    """One training sample from ``clip`` seen through ``view``.

    Returns torch tensors: ``video (T,H,W,3) float32`` in [0, 1] (augmented), ``queries (N,5) float32``
    in the view's coordinates, targets ``points (N,3)``, ``uv (N,2)``, ``visibility (N,)``,
    ``motion (N,3)``, ``normals (N,3)`` (zeros where undefined), masks ``valid (N,)`` and
    ``uv_valid (N,)`` (bool), ``aspect_ratio ()`` (the crop's width / height in source pixels), the
    view's ``intrinsics (T,3,3)`` and ``cam_to_world (T,4,4)`` (float32), ``object_id (N,) int64``, the rigid body
    each query's point lies on (0 = the static environment; for ``loss.weight_body_relative_depth``), and
    ``depth (T,H,W) float32``, the
    true z-depth of every sample pixel (0 where unknown; for ``loss.weight_dense_depth``). With ``patch_frames``
    also ``patch_video (T, h_crop, w_crop, 3) uint8``, the view's crop at the clip's own resolution, augmented
    alike, and ``patch_size (2,)`` long = (h_crop, w_crop): what a model with ``rgb_patch_source="original"`` cuts
    its query patches from (:func:`d4rt.data.augment.augmented_view_frames`). With the sampler's
    ``camera_pair_twins`` also ``twin (N,) int64`` (:meth:`d4rt.data.sampler.QuerySampler.sample`).
    """
    drawn = sampler.sample(clip, rng, view)
    answers = clip.oracle.query(drawn["source_queries"])  # exact: queries sit where the source is exact
    uv = view.uv_from_source(answers["uv"])
    inside = (uv >= 0).all(1) & (uv <= 1).all(1)
    valid, uv_valid = answers["valid"], answers["uv_valid"]
    targets = {
        "points": answers["points"],
        "uv": uv,
        "visibility": answers["visibility"] * inside.to(answers["visibility"].dtype),
        "motion": answers["motion"],
        "normals": answers["normals"],
    }
    frames = list(view.frames)
    x0, y0, w, h = view.crop
    video, patch_video = augmented_view_frames(clip.rgb, view, rng, augment, original=patch_frames)
    sample = {k: torch.nan_to_num(v, nan=0.0).float() for k, v in targets.items()}
    sample.update(
        video=video,
        queries=torch.from_numpy(drawn["queries"]).float(),
        valid=valid,
        uv_valid=uv_valid,
        object_id=answers["object_id"].long(),
        aspect_ratio=torch.tensor(w / h, dtype=torch.float32),
        intrinsics=torch.from_numpy(view.intrinsics(clip.intrinsics)).float(),
        cam_to_world=torch.from_numpy(clip.cam_to_world[frames]).float(),
        depth=torch.from_numpy(view_depth(clip.depth, view)),
    )
    if "twin" in drawn:  # the sampler's camera_pair_twins
        sample["twin"] = torch.from_numpy(drawn["twin"])
    if patch_video is not None:
        sample.update(patch_video=patch_video, patch_size=torch.tensor(patch_video.shape[1:3]))
    return sample


class ClipQueryDataset(torch.utils.data.Dataset):
    """Map-style dataset of training samples; ``set_epoch`` changes the random draws per epoch."""

    def __init__(self, config: DatasetConfig, patch_frames: bool = False):
        self.config = config
        self.patch_frames = patch_frames  # also yield original-resolution frames (make_training_sample)
        config.augment.validate()
        if config.renders_on_gpu:  # checked here, not in the config: a GPU config may be read on any machine
            index = int(config.render_device.partition(":")[2] or 0)
            if not torch.cuda.is_available() or index >= torch.cuda.device_count():
                raise UserError(f"dataset render_device {config.render_device!r} asked for, but this machine has "
                                f"no such CUDA device ({torch.cuda.device_count()} visible); use render_device: cpu")
        self.sampler = QuerySampler(config.sampler)
        self.epoch = 0
        self._last: tuple[tuple[int, int], Clip] | None = None  # the clip echoed samples share (see ``echo``)
        if config.source == "files":
            if not config.directory:
                raise UserError("dataset source 'files' needs a directory of .npz clips")
            self.files = sorted(Path(config.directory).glob("*.npz"))
            if not self.files:
                raise UserError(f"no .npz clips found in {config.directory}")
        else:
            self.files = []

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.files) if self.files else self.config.num_clips

    def __getitem__(self, index: int) -> dict:
        return self.sample(index)

    def sample(self, index: int, repeat: int = 0) -> dict:
        """Sample ``repeat`` (0 <= repeat < echo) of clip ``index``: repeat 0 is ``dataset[index]``; the others see
        the same clip with their own view, queries and augmentation (see ``echo``)."""
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} samples")
        cfg = self.config
        if not 0 <= repeat < cfg.echo:
            raise IndexError(f"repeat {repeat} out of range for echo {cfg.echo}")
        rng = np.random.default_rng([cfg.seed, self.epoch, index])
        # Drawn only when there is a choice, so fixed-length runs keep their exact sample stream.
        frames = int(cfg.frame_choices[rng.integers(len(cfg.frame_choices))]) if cfg.frame_choices else cfg.frames
        if self.files:
            clip = self._clip((self.epoch, index), lambda: load_clip(self.files[index]))
            stride = None
        else:
            stride = sample_stride(rng, frames * cfg.augment.max_stride, frames, cfg.augment.max_stride) \
                if cfg.augment.enabled else 1
            aspect = math.exp(rng.uniform(*np.log(cfg.render_aspect)))
            height = max(8, int(round(math.sqrt(cfg.render_pixels / aspect))))
            width = max(8, int(round(math.sqrt(cfg.render_pixels * aspect))))
            clip_seed = int(rng.integers(0, 2**31 - 1))
            clip = self._clip((self.epoch, index), lambda: render_clip(
                clip_seed, frames, height, width, device=cfg.render_device, time_stride=stride, **cfg.scene_options))
            stride = 1  # the stride is already in the rendered frame times
        if repeat:  # an echo: the clip's own draws above, then a generator of its own for everything else
            rng = np.random.default_rng([cfg.seed, self.epoch, index, repeat])
        view = sample_view(rng, clip.num_frames, (clip.height, clip.width), frames, cfg.size, cfg.augment,
                           stride=stride)
        return make_training_sample(clip, view, rng, self.sampler, cfg.augment, self.patch_frames)

    def _clip(self, key: tuple[int, int], make) -> Clip:
        """``make()``, or the clip it made for ``key`` last time when echoing (one clip kept per process)."""
        if self.config.echo == 1:
            return make()
        if self._last is None or self._last[0] != key:
            self._last = (key, make())
        return self._last[1]
