"""Typed training configuration: nested dataclasses, loaded from YAML with every field checked.

A config file has six sections; any field left out keeps its default (the paper's value where the paper
gives one). ``configs/tiny-cpu.yaml``, ``configs/small-gpu.yaml`` and ``configs/paper-giant.yaml`` are
complete examples, and docs/training.md lists every field.

.. code-block:: yaml

    model: {preset: tiny, overrides: {gradient_checkpointing: false}}
    data: {batch_size: 1, workers: 2, dataset: {source: render, frames: 8, size: [64, 64]}}
    loss: {weight_3d: 1.0, weight_confidence: 0.2}
    optim: {lr: 1.0e-4, warmup_steps: 2500}
    run: {max_steps: 1000, seed: 0}
    validation: {every: 500, num_clips: 4}

Unknown keys, wrong types and inconsistent sizes raise :class:`UserError` naming the field
(``optim.lr``), so a typo never trains silently with a default.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from d4rt.config import D4RTConfig
from d4rt.data import ClipQueryDataset, DatasetConfig, TrackDatasetConfig, TrackQueryDataset, build_dataset
from d4rt.errors import UserError
from d4rt.evaluation.benchmarks import TASKS as EVALUATION_TASKS
from d4rt.training.losses import LossConfig

STRATEGIES = ("auto", "single", "ddp", "fsdp")
PRECISIONS = ("auto", "fp32", "bf16")


@dataclass
class ModelSpec:
    """Which model to train.

    preset: a :class:`D4RTConfig` preset name; overrides: any of its fields (e.g. ``max_frames``,
    ``gradient_checkpointing``). init_from: a directory written by ``save_pretrained`` to start from
    (fine-tuning). videomae: a VideoMAE v2 checkpoint to initialise the encoder from (the paper's
    recipe; ``d4rt.model.videomae``).
    """

    preset: str = "tiny"
    overrides: dict = field(default_factory=dict)
    init_from: str | None = None
    videomae: str | None = None

    def build(self) -> D4RTConfig:
        return D4RTConfig.preset(self.preset, **self.overrides)


@dataclass
class DataSpec:
    """Training data: ``dataset`` (a :class:`d4rt.data.DatasetConfig`: synthetic clips rendered on the fly
    or clip files), or ``tracks`` (a :class:`d4rt.data.track_clips.TrackDatasetConfig`: your clips with
    per-point 3D tracks), which replaces ``dataset`` when given; ``batch_size`` clips per process per
    micro-step (the paper: 1 clip per chip); ``workers`` data-loading processes per training process."""

    dataset: DatasetConfig = field(default_factory=DatasetConfig)
    tracks: TrackDatasetConfig | None = None
    batch_size: int = 1
    workers: int = 2

    @property
    def frames(self) -> int:
        """The longest training clip."""
        return self.tracks.frames if self.tracks else self.dataset.max_frames

    @property
    def size(self) -> tuple[int, int]:
        return tuple((self.tracks or self.dataset).size)

    @property
    def num_queries(self) -> int:
        return self.tracks.num_queries if self.tracks else self.dataset.sampler.num_queries

    def build_dataset(self, device: str | None = None, patch_frames: bool = False
                      ) -> ClipQueryDataset | TrackQueryDataset:
        """The training dataset. ``device``: the process's torch device; a ``render_device`` of plain "cuda" becomes
        it, so that under torchrun each rank renders on its own GPU. ``patch_frames``: samples also carry the
        original-resolution frames (for a model whose config ``patches_from_original``)."""
        dataset = self.dataset
        if dataset.render_device == "cuda" and device is not None and device.startswith("cuda"):
            dataset = dataclasses.replace(dataset, render_device=device)
        return build_dataset(dataset, self.tracks, patch_frames)


@dataclass
class OptimConfig:
    """AdamW with linear warm-up to ``lr`` then cosine decay to ``min_lr`` (paper: 2,500 steps to 1e-4,
    down to 1e-6; weight decay 0.03; gradient clipping at L2 norm 10).

    decay_steps: the step at which the cosine reaches ``min_lr``; None means ``run.max_steps``.
    ema_decay: keep an exponential moving average of the weights with this per-step decay (e.g. 0.999:
    about the last 1,000 steps once its warm-up is over, after ~9,000 steps); validation then scores the
    average and checkpoints hold it in ``ema/`` (:mod:`d4rt.training.ema`). None: no average (not in paper).
    betas, eps: AdamW's (not in paper; PyTorch defaults). Weight decay skips biases, LayerNorm
    parameters and position tables (VideoMAE v2's fine-tuning convention; not in paper).
    lr_scale: glob patterns of parameter names (:mod:`fnmatch`, as ``D4RT.named_parameters()`` names them, e.g.
    ``"encoder.blocks.[2367].*"``) mapped to a factor on the scheduled learning rate; the first pattern that
    matches a parameter counts, and a pattern that matches none is an error (not in paper). Why: blocks added to a
    trained model by :func:`d4rt.model.grow.deepen` start as the identity, and at the trained weights' learning
    rate their zeroed output projections grew to a few per cent of the old blocks' norms in 1,332 steps (stage 62).
    freeze: glob patterns of parameter names (as ``lr_scale`` names them, e.g. ``"encoder.*"``) that are not trained:
    they keep the weights the run starts from, get no gradient and no optimiser state; a pattern that matches none
    is an error, and so is freezing every parameter (not in paper). Why: with the whole encoder frozen nothing
    back-propagates through it: on pre-rendered 24-frame 64x64 clips a training step runs 1.8x the clips a second
    (``benchmarks/bench_train.py --pool POOL --freeze 'encoder.*'``: 6.1 against 3.3, bf16, one AMD EPYC thread;
    rendering on the fly is unchanged). Freezing the readout instead saves little, as the step still runs the decoder
    both ways for the encoder's gradient: 1.06x (``--freeze 'query_embedding.*' 'decoder.*'``, same set-up; stage
    153). For fine-tuning the readout on a fixed scene
    representation, e.g. on a user's own clips (stage 152, docs/training.md).
    muon: glob patterns of parameter names (as ``lr_scale`` names them, e.g. ``"encoder.blocks.*"``) whose 2-D
    weights are stepped by Muon (``torch.optim.Muon``: the momentum of the gradient orthogonalised by Newton-Schulz
    steps) instead of AdamW, at AdamW's rate, schedule and weight decay (Moonshot's RMS matching); biases, norms,
    tables and every weight no pattern matches stay with AdamW. Empty: AdamW alone, as the paper. Not with FSDP. Why:
    Muon trains transformers' hidden matrices in fewer steps than AdamW (Jordan et al. 2024; Liu et al., "Muon is
    Scalable for LLM Training", 2025), and steps are this project's budget. Measured here (docs/training.md): from
    the shipped weights it moved the model as AdamW does (stage 156); from scratch, with the blocks at three times
    the rate (``lr_scale``), it reached a lower held-out loss in 1,000 steps than AdamW did on one seed (at AdamW's
    rate, not); on a second seed that rate was unstable for both (AdamW's run collapsed), and at AdamW's own rate
    Muon collapsed where AdamW recovered; with 500 warm-up steps both were stable and equal (no gain).
    """

    lr: float = 1e-4
    min_lr: float = 1e-6
    warmup_steps: int = 2500
    decay_steps: int | None = None
    weight_decay: float = 0.03
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8
    grad_clip: float = 10.0
    ema_decay: float | None = None
    lr_scale: dict = field(default_factory=dict)
    freeze: tuple[str, ...] = ()
    muon: tuple[str, ...] = ()


@dataclass
class RunConfig:
    """How the run is executed.

    max_steps: optimiser steps (``d4rt train --max-steps`` overrides it). grad_accum: micro-batches per
    step. seed: model initialisation, data order and per-rank random streams. device: ``auto`` (the
    local GPU under torchrun, else the first GPU, else CPU), ``cpu``, ``cuda``. precision: ``auto``
    (bf16 autocast where the device computes it natively: GPUs, CPUs with AMX-BF16 or AVX512-BF16; else
    fp32), ``fp32`` or ``bf16``. strategy: ``auto`` (DDP when launched
    with several processes, else single), ``single``, ``ddp`` or ``fsdp`` (``fully_shard`` per encoder
    block, for the large presets). log_every / checkpoint_every: in steps. keep_checkpoints: newest
    checkpoints kept on disk. tensorboard: write TensorBoard event files. progress: show a progress bar.
    """

    max_steps: int = 500_000
    grad_accum: int = 1
    seed: int = 0
    device: str = "auto"
    precision: str = "auto"
    strategy: str = "auto"
    log_every: int = 10
    checkpoint_every: int = 1000
    keep_checkpoints: int = 3
    tensorboard: bool = True
    progress: bool = True


@dataclass
class ValidationConfig:
    """Periodic validation on held-out synthetic clips (``every`` steps; 0 disables it).

    Clips are ``render_clip(seed + i, frames, height, width, **scene_options)`` for i < num_clips, or the
    first ``num_clips`` npz files of ``directory``. Training clips come from another seed stream, so
    these are never trained on. Each clip gives the loss terms on ``num_queries`` sampled queries and
    reconstruction metrics for ``tasks`` (of ``depth``, ``pose``, ``tracks``, ``world_tracks``,
    ``point_cloud``; computed as ``d4rt eval`` does), tracks on ``track_points`` oracle tracks.
    ``keep_best``: a validation metric (its name without ``val/``, e.g. ``ate`` or ``loss/total``); each time
    it reaches a new best (``keep_best_mode`` ``min`` or ``max``) that step is checkpointed and its weights
    are published as ``<run>/best/`` with ``best.json`` (step, value). Why: a checkpoint chosen on these
    held-out clips, by a rule written before the run, never on the benchmark.
    """

    every: int = 0
    num_clips: int = 4
    seed: int = 1_000_000
    directory: str | None = None
    frames: int = 8
    height: int = 64
    width: int = 64
    num_queries: int = 2048
    track_points: int = 256
    tasks: tuple[str, ...] = ("depth", "pose", "tracks")
    scene_options: dict = field(default_factory=dict)
    keep_best: str | None = None
    keep_best_mode: str = "min"


@dataclass
class TrainConfig:
    """A complete training run: model, data, loss, optimiser, execution and validation."""

    model: ModelSpec = field(default_factory=ModelSpec)
    data: DataSpec = field(default_factory=DataSpec)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    run: RunConfig = field(default_factory=RunConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)

    # ------------------------------------------------------------------------------------- checks
    def validate(self) -> D4RTConfig:
        """Check every field and the consistency between sections; return the model config."""
        model = self.model.build()
        run, optim, data, val = self.run, self.optim, self.data, self.validation
        _positive(run=("max_steps", "grad_accum", "log_every", "checkpoint_every", "keep_checkpoints"),
                  data=("batch_size",), validation=("num_clips", "frames", "height", "width", "num_queries",
                                                    "track_points"), config=self)
        if data.workers < 0 or run.seed < 0 or optim.warmup_steps < 0 or val.every < 0:
            raise UserError("data.workers, run.seed, optim.warmup_steps and validation.every must be >= 0")
        if run.strategy not in STRATEGIES:
            raise UserError(f"run.strategy must be one of {STRATEGIES}, got {run.strategy!r}")
        if run.precision not in PRECISIONS:
            raise UserError(f"run.precision must be one of {PRECISIONS}, got {run.precision!r}")
        if not 0 < optim.min_lr <= optim.lr:
            raise UserError(f"optim needs 0 < min_lr <= lr, got min_lr={optim.min_lr}, lr={optim.lr}")
        if optim.decay_steps is not None and optim.decay_steps <= optim.warmup_steps:
            raise UserError(f"optim.decay_steps ({optim.decay_steps}) must exceed warmup_steps ({optim.warmup_steps})")
        if optim.weight_decay < 0 or optim.grad_clip <= 0 or optim.eps <= 0:
            raise UserError("optim.weight_decay must be >= 0, grad_clip and eps > 0")
        if optim.ema_decay is not None and not 0 < optim.ema_decay < 1:
            raise UserError(f"optim.ema_decay must lie in (0, 1) or be null, got {optim.ema_decay}")
        if not all(0 <= b < 1 for b in optim.betas):
            raise UserError(f"optim.betas must lie in [0, 1), got {optim.betas}")
        for pattern, scale in optim.lr_scale.items():
            if not isinstance(pattern, str) or isinstance(scale, bool) or not isinstance(scale, (int, float)) \
                    or not scale > 0:
                raise UserError(f"optim.lr_scale maps parameter-name patterns to positive factors, got "
                                f"{pattern!r}: {scale!r}")
        if not all(optim.freeze):
            raise UserError(f"optim.freeze lists parameter-name patterns (e.g. ['encoder.*']), got {list(optim.freeze)!r}")
        if not all(isinstance(pattern, str) and pattern for pattern in optim.muon):
            raise UserError(f"optim.muon lists parameter-name patterns (e.g. ['encoder.blocks.*']), got "
                            f"{list(optim.muon)!r}")
        self.loss.validate()
        if self.loss.weight_dense_depth > 0 and not model.dense_depth_head:
            raise UserError("loss.weight_dense_depth needs model.overrides.dense_depth_head: true")
        if self.loss.weight_dense_depth > 0 and data.tracks is not None:
            raise UserError("loss.weight_dense_depth needs depth maps, which data.tracks clips do not have")
        twins = data.tracks is None and data.dataset.sampler.camera_pair_twins
        for term in ("weight_camera_pair", "weight_camera_pair_direction", "weight_camera_pair_rotation"):
            if getattr(self.loss, term) > 0 and not twins:
                raise UserError(f"loss.{term} needs data.dataset.sampler.camera_pair_twins: true "
                                "(rendered or file clips, not data.tracks)")
        if self.loss.attention_block is not None and self.loss.attention_block >= model.decoder_depth:
            raise UserError(f"loss.correspondence_block must be below the decoder's {model.decoder_depth} blocks, "
                            f"got {self.loss.attention_block}")
        if data.tracks is not None:
            data.tracks.validate()
        else:
            data.dataset.augment.validate()
        data.dataset.sampler.validate()  # validation samples its queries with it
        source = "data.tracks" if data.tracks is not None else "data.dataset"
        if data.tracks is not None and data.dataset.echo != 1:
            raise UserError(f"data.dataset.echo {data.dataset.echo} applies to data.dataset's clips, not to data.tracks")
        if data.tracks is None and data.dataset.frame_choices and data.batch_size != 1:
            raise UserError(f"data.dataset.frame_choices needs data.batch_size 1 (clips of different lengths "
                            f"cannot be stacked), got {data.batch_size}; use run.grad_accum for larger batches")
        checked = [(source, data.frames)] + ([("validation", val.frames)] if val.every else [])
        for name, frames in checked:
            if frames > model.max_frames:
                raise UserError(f"{name}.frames {frames} exceeds the model's max_frames {model.max_frames}")
        height, width = data.size
        if height % model.patch_size or width % model.patch_size or max(height, width) > model.image_size:
            raise UserError(f"{source}.size {height}x{width} must be multiples of the model's patch_size "
                            f"{model.patch_size} and at most its image_size {model.image_size}")
        if val.keep_best is not None and not val.every:
            raise UserError("validation.keep_best needs validation.every > 0")
        if val.keep_best_mode not in ("min", "max"):
            raise UserError(f"validation.keep_best_mode must be min or max, got {val.keep_best_mode!r}")
        unknown_tasks = sorted(set(val.tasks) - set(EVALUATION_TASKS))
        if unknown_tasks:
            raise UserError(f"validation.tasks: unknown {unknown_tasks}; choose from {list(EVALUATION_TASKS)}")
        return model

    # ------------------------------------------------------------------------------------- (de)serialise
    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "TrainConfig":
        return _build(cls, data, "config")

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dicts and lists (YAML / JSON ready)."""
        return _plain(dataclasses.asdict(self))

    @classmethod
    def load(cls, path: str | Path, overrides: dict[str, Any] | None = None) -> "TrainConfig":
        """Read a YAML file; ``overrides`` maps dotted keys (``run.max_steps``) to values."""
        path = Path(path)
        if not path.is_file():
            raise UserError(f"training config not found: {path}")
        try:
            data = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as err:
            raise UserError(f"{path} is not valid YAML: {' '.join(str(err).split())}") from None
        if not isinstance(data, dict):
            raise UserError(f"{path} must hold a mapping of sections, got {type(data).__name__}")
        for key, value in (overrides or {}).items():
            _set_dotted(data, key, value)
        return cls.from_dict(data)

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


# ----------------------------------------------------------------------------------------- helpers
def _positive(config: TrainConfig, **sections: tuple[str, ...]) -> None:
    for section, names in sections.items():
        for name in names:
            value = getattr(getattr(config, section), name)
            if value < 1:
                raise UserError(f"{section}.{name} must be >= 1, got {value}")


def _set_dotted(data: dict, key: str, value: Any) -> None:
    *parents, leaf = key.split(".")
    node = data
    for part in parents:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise UserError(f"cannot set {key}: {part} is not a section")
        node = child
    node[leaf] = value


def _build(cls: type, data: Any, where: str) -> Any:
    """A dataclass from a mapping, converting nested sections and checking every value's type."""
    if isinstance(data, cls):
        return data
    if not isinstance(data, dict):
        raise UserError(f"{where} must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise UserError(f"unknown field(s) in {where}: {', '.join(unknown)} (known: {', '.join(names)})")
    return cls(**{name: _coerce(hints[name], value, f"{where}.{name}") for name, value in data.items()})


def _coerce(kind: Any, value: Any, where: str) -> Any:
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if dataclasses.is_dataclass(kind):
        return _build(kind, value, where)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(inner[0], value, where)
    if kind is Any:
        return value
    if kind is bool:
        if not isinstance(value, bool):
            raise UserError(f"{where} must be true or false, got {value!r}")
        return value
    if kind is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise UserError(f"{where} must be an integer, got {value!r}")
        return value
    if kind is float:
        if isinstance(value, str):  # YAML 1.1 reads 1e-4 (no dot) as a string
            try:
                return float(value)
            except ValueError:
                pass
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise UserError(f"{where} must be a number, got {value!r}")
        return float(value)
    if kind is str:
        if not isinstance(value, str):
            raise UserError(f"{where} must be a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise UserError(f"{where} must be a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, where) for v in value)
        if len(value) != len(args):
            raise UserError(f"{where} must have {len(args)} entries, got {len(value)}")
        return tuple(_coerce(a, v, where) for a, v in zip(args, value))
    if kind is dict or origin is dict:
        if not isinstance(value, dict):
            raise UserError(f"{where} must be a mapping, got {value!r}")
        return dict(value)
    raise TypeError(f"unsupported config field type {kind!r} at {where}")  # a bug, not user input


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
