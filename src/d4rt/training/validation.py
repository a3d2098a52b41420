"""Periodic validation on held-out synthetic clips.

Each held-out clip gives
- the training loss terms on queries drawn by the paper's sampler (no augmentation), logged as
  ``val/loss/<term>`` (mean over clips);
- reconstruction metrics: the model reconstructs the clip through the query recipes
  (``model.reconstruct``: depth maps, cameras, 3D tracks) and the evaluation harness scores them
  against the clip's exact ground truth exactly as ``d4rt eval`` does (depth AbsRel and delta<1.25
  after per-clip scale / scale-and-shift alignment, ATE / RPE after Sim(3) alignment and pose AUC@30,
  TAPVid-3D APD3D / AJ / OA of ``track_points`` oracle tracks), aggregated over the clips with the
  harness's rules and logged as ``val/<metric>`` (e.g. ``val/abs_rel_scale_shift``, ``val/ate``,
  ``val/apd3d``).

A clip the model cannot be reconstructed from (``DegenerateFit``: e.g. a collapsed model puts every
point behind the camera) still gives its loss terms; it is left out of the reconstruction metrics, counted in
``val/reconstruction_failures`` and named in ``Validator.failures``, so a diverged run keeps training and
checkpointing instead of stopping at its validation.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from d4rt.data import AugmentConfig, QuerySampler, QuerySamplerConfig, make_training_sample
from d4rt.errors import DegenerateFit, UserError
from d4rt.evaluation.benchmarks import Benchmark
from d4rt.evaluation.harness import aggregate, evaluate_sequence
from d4rt.evaluation.predictions import ReconstructionPredictor
from d4rt.evaluation.readers.synthetic import sequence_from_clip
from d4rt.geometry.view import View
from d4rt.model import D4RT
from d4rt.reconstruction import Reconstruction
from d4rt.synthetic import Clip, load_clip, render_clip
from d4rt.training.config import ValidationConfig
from d4rt.training.data import model_inputs
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
        self.failures: list[str] = []  # the last run's clips that could not be reconstructed, with why

    @property
    def clips(self) -> list[Clip]:
        if self._clips is None:
            self._clips = held_out_clips(self.config)
        return self._clips

    @torch.no_grad()
    def run(self, model: D4RT, autocast: torch.autocast) -> dict[str, float]:
        """Metrics over the held-out clips, keyed ``val/loss/<term>``, ``val/<metric>`` and
        ``val/reconstruction_failures`` (a metric no clip could be scored on is absent)."""
        was_training = model.training
        model.eval()
        device = next(model.parameters()).device
        size = (model.config.image_size, model.config.image_size)
        benchmark = Benchmark("validation", "held-out synthetic clips", None, tuple(self.config.tasks))
        predictor = ReconstructionPredictor("d4rt", lambda sequence: Reconstruction.from_model(model, sequence.rgb,
                                                                                                progress=False))
        losses: dict[str, list[float]] = {}
        rows = []
        self.failures = []
        for index, clip in enumerate(self.clips):
            view = View((clip.height, clip.width), (0, 0, clip.width, clip.height), size, tuple(range(clip.num_frames)))
            rng = np.random.default_rng([self.config.seed, index])
            sample = make_training_sample(clip, view, rng, self.sampler, AugmentConfig(enabled=False),
                                          patch_frames=model.config.patches_from_original)
            batch = {k: v[None].to(device) for k, v in sample.items()}
            with autocast:
                out = model(batch["video"], batch["queries"], batch["aspect_ratio"],
                            attention_block=self.loss.attention_block, **model_inputs(model.config, batch))
            for key, value in d4rt_loss(out, batch, self.loss)[1].items():
                losses.setdefault(key, []).append(float(value))
            sequence = sequence_from_clip(clip, f"clip_{index}", self.config.track_points, self.config.seed + index)
            try:
                with autocast:
                    prediction = predictor.predict(sequence, set(benchmark.tasks))
            except DegenerateFit as error:
                self.failures.append(f"{sequence.name}: {error}")
                continue
            rows.append(evaluate_sequence(benchmark, sequence, prediction))
        model.train(was_training)
        scalars = {f"val/loss/{key}": float(np.mean(values)) for key, values in losses.items()}
        scalars["val/reconstruction_failures"] = float(len(self.failures))
        scalars.update({f"val/{metric_name(key)}": float(value) for key, value in aggregate(benchmark, rows).items()
                        if value is not None})
        return scalars


def metric_name(column: str) -> str:
    """A harness column as a plain scalar name: ``abs_rel[scale&shift]`` -> ``abs_rel_scale_shift``."""
    return re.sub(r"[^A-Za-z0-9_.]+", "_", column.replace("<", "_")).strip("_")
