"""AdamW with the paper's learning-rate schedule: linear warm-up, then cosine decay.

The schedule is a pure function of the step (:func:`learning_rate`), set on the optimiser before every
step, so resuming needs nothing but the step number and is exact.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from d4rt.training.config import OptimConfig


def learning_rate(step: int, config: OptimConfig, total_steps: int) -> float:
    """Learning rate of optimiser step ``step`` (0-indexed).

    Warm-up: ``lr * (step + 1) / warmup_steps`` for the first ``warmup_steps`` steps, so the first step
    already moves. Then cosine from ``lr`` to ``min_lr`` over the steps up to ``config.decay_steps``
    (default ``total_steps``), and ``min_lr`` after it.
    """
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    end = config.decay_steps if config.decay_steps is not None else total_steps
    span = max(1, end - config.warmup_steps)
    progress = min(1.0, (step - config.warmup_steps) / span)
    return config.min_lr + 0.5 * (config.lr - config.min_lr) * (1.0 + math.cos(math.pi * progress))


def no_weight_decay(name: str, param: nn.Parameter) -> bool:
    """Biases, LayerNorm weights (every parameter of one dimension) and position tables are not decayed."""
    return param.ndim <= 1 or ".pos_embed." in f".{name}"


def build_optimizer(model: nn.Module, config: OptimConfig) -> torch.optim.AdamW:
    """AdamW over ``model``'s parameters in two groups: decayed weights, and the rest (see
    :func:`no_weight_decay`). Works on plain, DDP- and FSDP-wrapped models (names are looked up on the
    parameters as the wrapper exposes them)."""
    decay, keep = [], []
    for name, param in model.named_parameters():
        if param.requires_grad:
            (keep if no_weight_decay(name, param) else decay).append(param)
    groups = [{"params": decay, "weight_decay": config.weight_decay}, {"params": keep, "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=config.lr, betas=tuple(config.betas), eps=config.eps)


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    for group in optimizer.param_groups:
        group["lr"] = lr
