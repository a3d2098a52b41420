"""Training: the paper's losses, the trainer (one CPU process to many GPUs), checkpoints, validation.

- ``d4rt_loss(pred, batch, LossConfig()) -> (total, terms)``: the losses of App. A, masked.
- ``TrainConfig.load("configs/tiny-cpu.yaml")``: a typed run config; ``train(config, out, resume)`` runs it
  (also ``d4rt train --config FILE --out DIR [--max-steps N] [--resume]``, or under ``torchrun``).
- Checkpoints: ``latest_checkpoint(dir)``, ``read_checkpoint(path)`` (safetensors + JSON, atomic).

See docs/training.md.
"""

from d4rt.training.checkpoint import latest_checkpoint, read_checkpoint, write_checkpoint
from d4rt.training.config import (
    DataSpec,
    ModelSpec,
    OptimConfig,
    RunConfig,
    TrainConfig,
    ValidationConfig,
)
from d4rt.training.losses import LossConfig, d4rt_loss, log_compress, mean_depth, point_loss
from d4rt.training.optimization import build_optimizer, learning_rate
from d4rt.training.trainer import Trainer, TrainResult, train

__all__ = [
    "DataSpec",
    "LossConfig",
    "ModelSpec",
    "OptimConfig",
    "RunConfig",
    "TrainConfig",
    "TrainResult",
    "Trainer",
    "ValidationConfig",
    "build_optimizer",
    "d4rt_loss",
    "latest_checkpoint",
    "learning_rate",
    "log_compress",
    "mean_depth",
    "point_loss",
    "read_checkpoint",
    "train",
    "write_checkpoint",
]
