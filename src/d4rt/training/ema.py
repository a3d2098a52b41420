"""An exponential moving average (EMA) of the trained weights (``optim.ema_decay``; not in paper).

Why: on this project's CPU runs the held-out camera moves by up to 0.03 ATE between checkpoints a few
hundred steps apart, even at a low learning rate; an average over the last ~1 / (1 - decay) steps is a
smoother estimate of the same weights. With EMA on, validation scores the averaged weights, and every
checkpoint holds them in its ``ema/`` directory (a model directory: ``D4RT.from_pretrained`` opens it).

After every applied optimiser step: ``ema = d * ema + (1 - d) * w`` with ``d = min(decay, (1 + n) / (10 + n))``
and ``n`` the updates so far (the usual warm-up, so that the average does not stay anchored at the initial
weights while few steps have been made). Only trainable parameters are averaged; buffers are the model's.
The average is kept per local parameter (the shard under FSDP) in the parameter's dtype, and is swapped into
the model (:meth:`WeightAverage.swapped_in`) to be validated or gathered into a checkpoint, so the same code
serves plain, DDP- and FSDP-wrapped models.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import torch
from torch import nn


class WeightAverage:
    """The EMA of ``model``'s trainable parameters, starting from their current values.

    decay: per-update decay in (0, 1); updates: how many updates the average already holds (resuming).
    """

    def __init__(self, model: nn.Module, decay: float, updates: int = 0):
        if not 0.0 < decay < 1.0:
            raise ValueError(f"EMA decay must lie in (0, 1), got {decay}")
        self.decay = decay
        self.updates = updates
        self._params = [p for p in model.parameters() if p.requires_grad]
        with torch.no_grad():
            self._average = [p.detach().clone() for p in self._params]

    def current_decay(self) -> float:
        """The decay the next update uses (warm-up: ``(1 + n) / (10 + n)`` while that is smaller)."""
        return min(self.decay, (1 + self.updates) / (10 + self.updates))

    @torch.no_grad()
    def update(self) -> None:
        """Move the average towards the model's current parameters (call after an applied optimiser step)."""
        weight = 1.0 - self.current_decay()
        for average, param in zip(self._average, self._params):
            average.lerp_(param.detach(), weight)
        self.updates += 1

    @contextmanager
    def swapped_in(self) -> Iterator[None]:
        """Inside the block the model's parameters hold the average; afterwards, exactly their own values."""
        with torch.no_grad():
            own = [p.detach().clone() for p in self._params]
            for param, average in zip(self._params, self._average):
                param.detach().copy_(average)
        try:
            yield
        finally:
            with torch.no_grad():
                for param, value in zip(self._params, own):
                    param.detach().copy_(value)
