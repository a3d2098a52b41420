"""What ``d4rt bench`` measures and on what: the options, checked, and the model and clip they give.

The model has random weights (speed does not depend on them). Its config is the preset's; when more
frames are asked for than the preset takes, only ``max_frames`` (the size of the time-embedding
tables) is raised so that the clip is one window, as in the paper's 48-frame timings.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass

import torch

from d4rt import devices
from d4rt.config import D4RTConfig
from d4rt.errors import UserError

DTYPES = ("fp32", "bf16")
TARGET_FPS = (60, 24, 10, 1)
VIDEO_SOURCES = ("random", "synthetic")


@dataclass
class BenchOptions:
    """Every setting of one benchmark run (``d4rt bench --help`` describes each).

    frames, height, width: the clip (None: the preset's max_frames and a square of its image_size);
    the encoder always sees it resized to the preset's square input.
    queries: random queries per decoder measurement. chunks: chunk sizes of the decoder table (256,
    where the KV-cache speed-up is reported, is always included). repeats: timed runs per figure (the
    best is kept). tolerance: relative precision of the largest track count at each target FPS.
    dense_size: side of the dense-tracking grid (None: the benchmark clip's own resolution).
    dense_clips: clips of synthetic-dynamic-v1 tracked densely (from clip_00).
    pose_grid: points per side of the camera recipe's grid (None: ``Reconstruction``'s default).
    """

    preset: str = "tiny"
    device: str = "auto"
    dtype: str = "fp32"
    frames: int | None = None
    height: int | None = None
    width: int | None = None
    queries: int = 100_000
    chunks: tuple[int, ...] = (256, 1024, 4096)
    repeats: int = 3
    compile: bool = False
    threads: int | None = None
    video: str = "random"
    compare_colmap: bool = False
    fps_targets: tuple[int, ...] = TARGET_FPS
    tolerance: float = 0.02
    max_trials: int = 16
    dense_size: int | None = None
    dense_clips: int = 1
    pose_grid: int | None = None
    seed: int = 0
    quick: bool = False
    progress: bool = True

    @classmethod
    def quick_options(cls, **overrides) -> "BenchOptions":
        """A run small enough for CI (seconds on a CPU): 2 frames at 32x32, 2,048 queries, chunks 256
        and 1,024, one repeat, a 16x16 dense grid, track counts to 10%."""
        base = dict(frames=2, height=32, width=32, queries=2048, chunks=(256, 1024), repeats=1, tolerance=0.1,
                    max_trials=8, dense_size=16, quick=True)
        base.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**base)

    def checked(self) -> "BenchOptions":
        """These options with defaults filled in, or a :class:`UserError` naming the first bad one."""
        preset = D4RTConfig.preset(self.preset)  # unknown names raise UserError
        if self.dtype not in DTYPES:
            raise UserError(f"dtype must be one of {', '.join(DTYPES)}, got {self.dtype!r}")
        if self.video not in VIDEO_SOURCES:
            raise UserError(f"video must be one of {', '.join(VIDEO_SOURCES)}, got {self.video!r}")
        frames = preset.max_frames if self.frames is None else self.frames
        height = preset.image_size if self.height is None else self.height
        width = preset.image_size if self.width is None else self.width
        for name, value, low in (("frames", frames, 1), ("height", height, 2), ("width", width, 2),
                                 ("queries", self.queries, 1), ("repeats", self.repeats, 1),
                                 ("max_trials", self.max_trials, 2), ("dense_clips", self.dense_clips, 1)):
            if not isinstance(value, int) or value < low:
                raise UserError(f"{name} must be an integer >= {low}, got {value!r}")
        if self.dense_size is not None and self.dense_size < 2:
            raise UserError(f"dense size must be at least 2, got {self.dense_size}")
        if self.pose_grid is not None and self.pose_grid < 2:
            raise UserError(f"pose grid must be at least 2, got {self.pose_grid}")
        if self.dense_clips > 48:
            raise UserError(f"synthetic-dynamic-v1 has 48 clips, got dense clips {self.dense_clips}")
        if not self.chunks or any(not isinstance(c, int) or c < 1 for c in self.chunks):
            raise UserError(f"chunk sizes must be positive integers, got {list(self.chunks)}")
        if not self.fps_targets or any(not f > 0 for f in self.fps_targets):
            raise UserError(f"target FPS must be positive, got {list(self.fps_targets)}")
        if not 0 < self.tolerance < 1:
            raise UserError(f"tolerance must be in (0, 1), got {self.tolerance}")
        if self.threads is not None and self.threads < 1:
            raise UserError(f"threads must be >= 1, got {self.threads}")
        chunks = tuple(sorted({256, *self.chunks}))
        video = "synthetic" if self.compare_colmap else self.video
        return dataclasses.replace(self, frames=frames, height=height, width=width, chunks=chunks, video=video,
                                   device=str(resolve_device(self.device)))

    def config(self) -> D4RTConfig:
        """The preset, with max_frames raised to the clip's length if needed."""
        preset = D4RTConfig.preset(self.preset)
        return preset.replace(max_frames=max(preset.max_frames, self.frames))

    def autocast(self) -> contextlib.AbstractContextManager:
        """bf16 autocast on the device for ``dtype="bf16"`` (parameters stay float32), else nothing."""
        if self.dtype == "bf16":
            return torch.autocast(torch.device(self.device).type, dtype=torch.bfloat16)
        return contextlib.nullcontext()


def resolve_device(name: str) -> torch.device:
    """:func:`d4rt.devices.resolve_device`, limited to the devices the benchmark times (CPU and CUDA)."""
    device = devices.resolve_device(name, "--device")
    if device.type not in ("cpu", "cuda"):
        raise UserError(f"--device {name!r} is not supported by the benchmark; use cpu or cuda")
    return device


def make_model(options: BenchOptions):
    """A random-weight D4RT of the options' config on their device, in eval mode (compiled if asked)."""
    from d4rt.model import D4RT

    torch.manual_seed(options.seed)
    device = torch.device(options.device)
    with device:
        model = D4RT(options.config())
    model.eval()
    if options.compile:
        # In place (parameter names unchanged); dynamic shapes: the number of queries per chunk varies.
        model.encoder.compile()
        model.decoder.compile(dynamic=True)
    return model


def make_video(options: BenchOptions) -> torch.Tensor:
    """The clip, ``(T, H, W, 3)`` uint8 on the CPU (where a user's decoded video starts): uniform noise,
    or a rendered synthetic scene (``video="synthetic"``, which COLMAP needs to find features)."""
    if options.video == "synthetic":
        from d4rt.synthetic import render_clip

        clip = render_clip(options.seed, options.frames, options.height, options.width, environment="room",
                           camera_motion="orbit", num_objects=5)
        return torch.from_numpy(clip.rgb)
    g = torch.Generator().manual_seed(options.seed)
    return torch.randint(0, 256, (options.frames, options.height, options.width, 3), generator=g, dtype=torch.uint8)
