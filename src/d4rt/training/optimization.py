"""AdamW with the paper's learning-rate schedule: linear warm-up, then cosine decay.

The schedule is a pure function of the step (:func:`learning_rate`), set on the optimiser before every
step, so resuming needs nothing but the step number and is exact.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from fnmatch import fnmatchcase

import torch
from torch import nn

from d4rt.errors import UserError
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


def plain_name(name: str) -> str:
    """A parameter's name as the bare model names it: without DDP's ``module.`` or torch.compile's ``_orig_mod.``."""
    while name.startswith(("module.", "_orig_mod.")):
        name = name.partition(".")[2]
    return name


def _refuse_unmatched(option: str, unmatched: list[str]) -> None:
    """One line naming the patterns of ``option`` that match no parameter (a typo would otherwise do nothing)."""
    if unmatched:
        raise UserError(f"{option} pattern(s) {', '.join(map(repr, unmatched))} match no parameter of the model "
                        f"(names as in D4RT.named_parameters(), e.g. 'encoder.blocks.2.*' or 'encoder.*')")


def freeze_parameters(model: nn.Module, patterns: Sequence[str]) -> int:
    """Turn off the gradient of every parameter whose name matches one of ``patterns`` (:mod:`fnmatch`, names as the
    bare model gives them) -> how many parameters (elements) were frozen. :func:`build_optimizer` then leaves them
    out. Call it before wrapping the model for DDP or FSDP, which read ``requires_grad`` when they wrap.

    Raises :class:`UserError` if a pattern matches no parameter or every parameter is matched.
    """
    if not patterns:
        return 0
    used, frozen, total = set(), 0, 0
    for name, param in model.named_parameters():
        total += param.numel()
        matched = {pattern for pattern in patterns if fnmatchcase(plain_name(name), pattern)}
        if matched:
            used |= matched
            param.requires_grad_(False)
            frozen += param.numel()
    _refuse_unmatched("optim.freeze", [pattern for pattern in patterns if pattern not in used])
    if frozen == total:
        raise UserError(f"optim.freeze {list(patterns)!r} freezes every parameter of the model: nothing would train")
    return frozen


def build_optimizer(model: nn.Module, config: OptimConfig) -> torch.optim.AdamW:
    """AdamW over ``model``'s parameters: decayed weights and the rest (see :func:`no_weight_decay`), each split
    further by ``config.lr_scale`` (a group's ``lr_scale`` multiplies the scheduled rate; without patterns there are
    exactly these two groups, as in every checkpoint written before it). Works on plain, DDP- and FSDP-wrapped
    models (names are looked up on the parameters as the wrapper exposes them).

    Raises :class:`UserError` if a pattern of ``config.lr_scale`` matches no parameter.
    """
    patterns = list(config.lr_scale.items())
    groups: dict[tuple[int, bool], list[nn.Parameter]] = {(-1, True): [], (-1, False): []}
    for name, param in model.named_parameters():
        if not param.requires_grad:
            continue
        which = next((i for i, (pattern, _) in enumerate(patterns) if fnmatchcase(plain_name(name), pattern)), -1)
        groups.setdefault((which, not no_weight_decay(name, param)), []).append(param)
    used = {which for which, _ in groups}
    _refuse_unmatched("optim.lr_scale", [pattern for i, (pattern, _) in enumerate(patterns) if i not in used])
    param_groups = []
    for (which, decayed), params in groups.items():
        group = {"params": params, "weight_decay": config.weight_decay if decayed else 0.0}
        if which >= 0:
            group["lr_scale"] = float(patterns[which][1])
        param_groups.append(group)
    return torch.optim.AdamW(param_groups, lr=config.lr, betas=tuple(config.betas), eps=config.eps)


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    """Every group's rate: ``lr`` times the group's ``lr_scale`` (1 where it has none)."""
    for group in optimizer.param_groups:
        group["lr"] = lr * group.get("lr_scale", 1.0)
