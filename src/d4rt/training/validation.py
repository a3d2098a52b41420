"""Periodic validation on held-out synthetic clips.

Each held-out clip gives the training loss terms on queries drawn by the paper's sampler (no
augmentation) and reconstruction metrics computed like the benchmarks compute them (see
:func:`reconstruction_metrics`). Numbers are averaged over the clips and logged as ``val/...``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from d4rt.data import AugmentConfig, QuerySampler, QuerySamplerConfig, make_training_sample
from d4rt.errors import UserError
from d4rt.geometry.view import View
from d4rt.model import D4RT
from d4rt.synthetic import Clip, load_clip, render_clip
from d4rt.training.config import ValidationConfig
from d4rt.training.losses import LossConfig, d4rt_loss


def held_out_clips(config: ValidationConfig) -> list[Clip]:
    """The validation clips: rendered from ``seed + i`` or read from ``directory`` (first ``frames``)."""
    if config.directory is None:
        return [render_clip(config.seed + i, config.frames, config.height, config.width, **config.scene_options)
                for i in range(config.num_clips)]
    files = sorted(Path(config.directory).glob("*.npz"))[:config.num_clips]
    if not files:
        raise UserError(f"validation.directory {config.directory} holds no .npz clips")
    clips = []
    for path in files:
        clip = load_clip(path)
        if clip.num_frames < config.frames:
            raise UserError(f"validation clip {path} has {clip.num_frames} frames, fewer than validation.frames "
                            f"{config.frames}")
        clips.append(clip.subsample(range(config.frames)) if clip.num_frames > config.frames else clip)
    return clips


class Validator:
    """Validation of a model on held-out clips; clips are prepared once, on first use."""

    def __init__(self, config: ValidationConfig, loss: LossConfig, sampler: QuerySamplerConfig):
        self.config = config
        self.loss = loss
        self.sampler = QuerySampler(QuerySamplerConfig(**{**vars(sampler), "num_queries": config.num_queries}))
        self._clips: list[Clip] | None = None

    @property
    def clips(self) -> list[Clip]:
        if self._clips is None:
            self._clips = held_out_clips(self.config)
        return self._clips

    @torch.no_grad()
    def run(self, model: D4RT, autocast: torch.autocast) -> dict[str, float]:
        """Metrics averaged over the held-out clips, keyed ``val/loss/<term>`` and ``val/<metric>``."""
        was_training = model.training
        model.eval()
        device = next(model.parameters()).device
        size = (model.config.image_size, model.config.image_size)
        totals: dict[str, list[float]] = {}
        for index, clip in enumerate(self.clips):
            view = View((clip.height, clip.width), (0, 0, clip.width, clip.height), size, tuple(range(clip.num_frames)))
            rng = np.random.default_rng([self.config.seed, index])
            sample = make_training_sample(clip, view, rng, self.sampler, AugmentConfig(enabled=False))
            batch = {k: v[None].to(device) for k, v in sample.items()}
            with autocast:
                out = model(batch["video"], batch["queries"], batch["aspect_ratio"])
            _, terms = d4rt_loss(out, batch, self.loss)
            metrics = {f"val/loss/{k}": float(v) for k, v in terms.items()}
            with autocast:
                metrics.update(reconstruction_metrics(model, clip, self.config, rng))
            for key, value in metrics.items():
                totals.setdefault(key, []).append(value)
        model.train(was_training)
        return {key: float(np.mean(values)) for key, values in totals.items()}


def reconstruction_metrics(model: D4RT, clip: Clip, config: ValidationConfig, rng: np.random.Generator) -> dict[str, float]:
    """Depth, camera and track metrics of ``model`` on ``clip`` through the reconstruction layer.

    Needs ``d4rt.reconstruction`` and ``d4rt.evaluation.metrics``; returns ``{}`` until they are
    installed in this package.
    """
    return {}
