"""AdamW with the paper's learning-rate schedule: linear warm-up, then cosine decay; optionally Muon for the
hidden matrices (``optim.muon``, not in paper).

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


class OptimizerChain:
    """Optimisers over disjoint parameters stepped as one (AdamW and Muon): the trainer sets the rates of
    ``param_groups`` and calls ``step`` and ``zero_grad``; a checkpoint holds the state of each (``optimizers``,
    handed to ``torch.distributed.checkpoint``'s state-dict functions, which merge them by parameter name)."""

    def __init__(self, *optimizers: torch.optim.Optimizer) -> None:
        self.optimizers = tuple(optimizers)

    @property
    def param_groups(self) -> list[dict]:
        return [group for optimizer in self.optimizers for group in optimizer.param_groups]

    def step(self) -> None:
        for optimizer in self.optimizers:
            optimizer.step()

    def zero_grad(self, set_to_none: bool = True) -> None:
        for optimizer in self.optimizers:
            optimizer.zero_grad(set_to_none=set_to_none)


def muon_matrices(model: nn.Module, patterns: Sequence[str]) -> set[str]:
    """Names of the trained 2-D weights that match one of ``patterns`` (:mod:`fnmatch`, bare-model names): the
    parameters Muon steps. Biases, norms and position tables that a pattern also matches stay with AdamW.

    Raises :class:`UserError` if a pattern matches no trained 2-D weight, or the model is sharded (FSDP):
    Muon orthogonalises whole matrices.
    """
    chosen, used = set(), set()
    for name, param in model.named_parameters():
        matched = {pattern for pattern in patterns if fnmatchcase(plain_name(name), pattern)}
        if not matched or not param.requires_grad or param.ndim != 2 or no_weight_decay(name, param):
            continue
        if hasattr(param, "full_tensor"):
            raise UserError("optim.muon needs whole weight matrices on every process: use run.strategy ddp or "
                            "single, not fsdp")
        used |= matched
        chosen.add(name)
    unmatched = [pattern for pattern in patterns if pattern not in used]
    if unmatched:
        raise UserError(f"optim.muon pattern(s) {', '.join(map(repr, unmatched))} match no trained 2-D weight of "
                        f"the model (names as in D4RT.named_parameters(), e.g. 'encoder.blocks.*')")
    return chosen


def build_optimizer(model: nn.Module, config: OptimConfig) -> torch.optim.AdamW | OptimizerChain:
    """AdamW over ``model``'s parameters: decayed weights and the rest (see :func:`no_weight_decay`), each split
    further by ``config.lr_scale`` (a group's ``lr_scale`` multiplies the scheduled rate; without patterns there are
    exactly these two groups, as in every checkpoint written before it). Works on plain, DDP- and FSDP-wrapped
    models (names are looked up on the parameters as the wrapper exposes them).

    With ``config.muon`` patterns, the 2-D weights they match (:func:`muon_matrices`) are stepped by
    ``torch.optim.Muon`` instead, in groups split by ``lr_scale`` the same way, with Moonshot's rate adjustment
    (``match_rms_adamw``: the update's RMS that of AdamW's, so AdamW's rate and weight decay carry over) and
    PyTorch's defaults otherwise (Nesterov momentum 0.95, five Newton-Schulz steps); the two optimisers come back as
    one :class:`OptimizerChain`.

    Raises :class:`UserError` if a pattern of ``config.lr_scale`` matches no parameter.
    """
    patterns = list(config.lr_scale.items())
    muon = muon_matrices(model, config.muon) if config.muon else set()
    groups: dict[tuple[bool, int, bool], list[nn.Parameter]] = {(False, -1, True): [], (False, -1, False): []}
    for name, param in model.named_parameters():
        if not param.requires_grad:
            continue
        which = next((i for i, (pattern, _) in enumerate(patterns) if fnmatchcase(plain_name(name), pattern)), -1)
        groups.setdefault((name in muon, which, not no_weight_decay(name, param)), []).append(param)
    used = {which for _, which, _ in groups}
    _refuse_unmatched("optim.lr_scale", [pattern for i, (pattern, _) in enumerate(patterns) if i not in used])
    adamw_groups, muon_groups = [], []
    for (by_muon, which, decayed), params in groups.items():
        group = {"params": params, "weight_decay": config.weight_decay if decayed else 0.0}
        if which >= 0:
            group["lr_scale"] = float(patterns[which][1])
        (muon_groups if by_muon else adamw_groups).append(group)
    adamw = torch.optim.AdamW(adamw_groups, lr=config.lr, betas=tuple(config.betas), eps=config.eps)
    if not muon_groups:
        return adamw
    return OptimizerChain(adamw, torch.optim.Muon(muon_groups, lr=config.lr, adjust_lr_fn="match_rms_adamw"))


def set_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    """Every group's rate: ``lr`` times the group's ``lr_scale`` (1 where it has none)."""
    for group in optimizer.param_groups:
        group["lr"] = lr * group.get("lr_scale", 1.0)
