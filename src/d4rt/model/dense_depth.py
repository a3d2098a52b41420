"""A dense depth head on the scene tokens: a training aid, not part of the paper's model.

Why (issue 14, stage 67): the decoder learns depth only through the ~1,000 queries a clip is asked per step, and
on held-out outdoor clips every tiny model trained so far puts the sky and a box two metres away at nearly the
same depth (far/near ratio 6-17 whatever the truth, docs/training.md stage 21). This head reads each tubelet
token and answers the log-depth of every pixel of its ``tubelet_frames x patch x patch`` block, so that every
pixel of every frame supervises the encoder each step (``LossConfig.weight_dense_depth``). The queries still
answer every output; inference never calls the head.
"""

from __future__ import annotations

import torch
from torch import nn

from d4rt.config import D4RTConfig


class DenseDepthHead(nn.Module):
    """Per-tubelet MLP: scene tokens -> log-depth of every pixel, up to a per-clip constant.

    ``tokens: (B, M, encoder_dim)`` as :meth:`D4RT.encode_tokens` returns them (the T' x H' x W' tubelet
    tokens in order, then the aspect-ratio token) -> ``(B, T, H, W)`` for a clip of T frames at H x W
    encoder pixels. The output is log-depth in arbitrary units: the loss that trains it is invariant to a
    per-clip shift (a scale of depth), as the scale of a monocular clip is unknown.
    """

    def __init__(self, config: D4RTConfig):
        super().__init__()
        self.tubelet_frames, self.patch_size = config.tubelet_frames, config.patch_size
        dim = config.encoder_dim
        self.mlp = nn.Sequential(nn.Linear(dim, dim), nn.GELU(),
                                 nn.Linear(dim, config.tubelet_frames * config.patch_size ** 2))

    def forward(self, tokens: torch.Tensor, frames: int, height: int, width: int) -> torch.Tensor:
        k, p = self.tubelet_frames, self.patch_size
        steps, rows, cols = -(-frames // k), height // p, width // p
        b, m, _ = tokens.shape
        if m != steps * rows * cols + 1:
            raise ValueError(f"dense depth head: {m} tokens do not fit {frames} frames of {height}x{width} "
                             f"({steps * rows * cols} tubelets + the aspect token)")
        x = self.mlp(tokens[:, :-1]).reshape(b, steps, rows, cols, k, p, p)
        x = x.permute(0, 1, 4, 2, 5, 3, 6).reshape(b, steps * k, rows * p, cols * p)
        return x[:, :frames]  # the frames repeated to fill the last tubelet are not the clip's
