"""Building blocks shared by the encoder and decoder: attention, MLP, transformer block, encodings.

All attention goes through ``F.scaled_dot_product_attention`` so PyTorch picks the flash or
memory-efficient kernel on GPU and its fused CPU kernel elsewhere.

Parameter names follow the VideoMAE v2 layout (``qkv`` weight without bias plus separate ``q_bias`` and
``v_bias``; ``norm1``/``attn``/``norm2``/``mlp.fc1``/``mlp.fc2``) so its checkpoints map one to one.
Keys get no bias: softmax is invariant to it, so it would never receive a gradient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint


def split_heads(x: torch.Tensor, heads: int) -> torch.Tensor:
    """(B, L, heads * d) -> (B, heads, L, d)."""
    b, length, width = x.shape
    return x.view(b, length, heads, width // heads).transpose(1, 2)


def merge_heads(x: torch.Tensor) -> torch.Tensor:
    """(B, heads, L, d) -> (B, L, heads * d)."""
    b, heads, length, d = x.shape
    return x.transpose(1, 2).reshape(b, length, heads * d)


class SelfAttention(nn.Module):
    """Multi-head self-attention over ``x: (B, L, dim)`` -> ``(B, L, dim)``."""

    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim, bias=False)
        self.q_bias = nn.Parameter(torch.zeros(dim))
        self.v_bias = nn.Parameter(torch.zeros(dim))
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        bias = torch.cat([self.q_bias, torch.zeros_like(self.q_bias), self.v_bias])
        q, k, v = F.linear(x, self.qkv.weight, bias).chunk(3, dim=-1)
        out = F.scaled_dot_product_attention(
            split_heads(q, self.heads), split_heads(k, self.heads), split_heads(v, self.heads))
        return self.proj(merge_heads(out))


class CrossAttention(nn.Module):
    """Multi-head attention from queries ``(B, N, dim)`` to context tokens ``(B, M, context_dim)``.

    Keys and values depend only on the context, so :meth:`project_context` computes them once and
    :meth:`forward` can reuse them for any number of query batches. Each query row attends on its own:
    no query sees another, so outputs never depend on which other queries share the batch.
    """

    def __init__(self, dim: int, context_dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(context_dim, 2 * dim, bias=False)
        self.v_bias = nn.Parameter(torch.zeros(dim))
        self.proj = nn.Linear(dim, dim)

    def project_context(self, context: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``context: (B, M, context_dim)`` -> keys, values, each ``(B, heads, M, dim / heads)``."""
        bias = torch.cat([torch.zeros_like(self.v_bias), self.v_bias])
        k, v = F.linear(context, self.kv.weight, bias).chunk(2, dim=-1)
        # Contiguous per head: attention kernels then read them without a copy on every reuse.
        return split_heads(k, self.heads).contiguous(), split_heads(v, self.heads).contiguous()

    def forward(self, x: torch.Tensor, keys: torch.Tensor, values: torch.Tensor,
                frame: FrameRestriction | None = None) -> torch.Tensor:
        """``x: (B, N, dim)``, keys/values from :meth:`project_context` (batch 1 broadcasts) -> ``(B, N, dim)``.
        With ``frame`` its first ``frame.heads`` heads attend only to the tokens of each query's own time step."""
        q = split_heads(self.q(x), self.heads)
        if keys.shape[0] != q.shape[0]:
            keys, values = keys.expand(q.shape[0], -1, -1, -1), values.expand(q.shape[0], -1, -1, -1)
        if frame is None or frame.heads == 0:
            return self.proj(merge_heads(F.scaled_dot_product_attention(q, keys, values)))
        k = frame.heads
        within = frame.attend(q[:, :k], keys[:, :k], values[:, :k])
        if k == self.heads:
            return self.proj(merge_heads(within))
        rest = F.scaled_dot_product_attention(q[:, k:], keys[:, k:], values[:, k:])
        return self.proj(merge_heads(torch.cat([within, rest], dim=1)))

    def attention_log_probs(self, x: torch.Tensor, keys: torch.Tensor, head: int = 0,
                            frame: FrameRestriction | None = None) -> torch.Tensor:
        """The log of head ``head``'s attention weights: ``x: (B, N, dim)``, keys from :meth:`project_context`
        -> ``(B, N, M)`` float32, each row a log-distribution over the M context tokens (what :meth:`forward`'s
        scaled dot-product attention weighs the values with; -inf outside the query's time step for a head that
        ``frame`` restricts). For training losses on where a query looks."""
        q = split_heads(self.q(x), self.heads)[:, head].float()
        k = keys[:, head].float()
        logits = q @ k.transpose(-1, -2) / q.shape[-1] ** 0.5
        if frame is not None and head < frame.heads:
            logits = logits.masked_fill(~frame.mask(logits.shape[-1]), float("-inf"))
        return torch.log_softmax(logits, dim=-1)


@dataclass(frozen=True)
class FrameRestriction:
    """Which scene tokens a query's frame-restricted heads see: the ``tokens_per_step`` tokens of its time step.

    ``steps: (B, N)`` long, each query's tubelet time step (t_tgt // config step_frames); ``tokens_per_step``: tubelet
    tokens per time step (rows x columns); ``heads``: how many heads, the first ones, are restricted. The context
    tokens are in (time step, row, column) order, any further tokens (the aspect-ratio token) after them.
    """

    steps: torch.Tensor
    tokens_per_step: int
    heads: int

    def attend(self, q: torch.Tensor, keys: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """Attention of ``q: (B, h, N, d)`` over each query's step of ``keys``, ``values: (B, h, M, d)`` ->
        ``(B, h, N, d)``. The queries are grouped by step, so each group runs one scaled dot-product attention
        over that step's tokens (memory stays that of plain attention; flash kernels still apply)."""
        out = q.new_empty(q.shape[:-1] + (values.shape[-1],))
        r = self.tokens_per_step
        for b in range(q.shape[0]):
            for step in self.steps[b].unique().tolist():
                rows = (self.steps[b] == step).nonzero().squeeze(1)
                part = slice(step * r, (step + 1) * r)
                out[b, :, rows] = F.scaled_dot_product_attention(q[b, :, rows], keys[b, :, part], values[b, :, part])
        return out

    def mask(self, num_tokens: int) -> torch.Tensor:
        """``(B, N, num_tokens)`` bool: True on the tokens each query's restricted heads see."""
        # The aspect-ratio token's index is steps x tokens_per_step: a step no query has.
        token_step = torch.arange(num_tokens, device=self.steps.device) // self.tokens_per_step
        return token_step[None, None] == self.steps[..., None]


class MLP(nn.Module):
    """Two linear layers with GELU between: ``(..., dim) -> (..., dim)``."""

    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


class SelfAttentionBlock(nn.Module):
    """Pre-norm transformer block: ``x + attn(norm1(x))`` then ``x + mlp(norm2(x))``; ``(B, L, dim)``."""

    def __init__(self, dim: int, heads: int, mlp_dim: int, eps: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = SelfAttention(dim, heads)
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = MLP(dim, mlp_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


def run_block(block: nn.Module, *inputs: torch.Tensor, recompute: bool) -> torch.Tensor:
    """``block(*inputs)``; with ``recompute`` (and gradients on) its activations are not stored but
    recomputed in the backward pass (activation checkpointing: memory for compute)."""
    if recompute and torch.is_grad_enabled():
        return checkpoint(block, *inputs, use_reentrant=False)
    return block(*inputs)


def sincos_1d(positions: torch.Tensor, dim: int, base: float = 10000.0) -> torch.Tensor:
    """Transformer sine-cosine encoding of 1-D ``positions: (L,)`` -> ``(L, dim)`` (an odd last channel is 0)."""
    half = dim // 2
    freqs = base ** (-torch.arange(half, dtype=torch.float32, device=positions.device) / max(half, 1))
    angles = positions.float()[:, None] * freqs[None, :]
    out = torch.cat([angles.sin(), angles.cos()], dim=-1)
    return F.pad(out, (0, dim - 2 * half))


def sincos_2d(size: int, dim: int) -> torch.Tensor:
    """2-D sine-cosine encoding of a ``size x size`` grid -> ``(size, size, dim)``: half the channels
    encode the row, half the column. ``dim`` must be a multiple of 4; otherwise the last channels are 0."""
    quarter = dim // 4
    pos = torch.arange(size, dtype=torch.float32)
    rows = sincos_1d(pos, 2 * quarter)[:, None, :].expand(size, size, -1)
    cols = sincos_1d(pos, 2 * quarter)[None, :, :].expand(size, size, -1)
    out = torch.zeros(size, size, dim)
    out[..., : 4 * quarter] = torch.cat([rows, cols], dim=-1)
    return out


def fourier_frequencies(count: int, max_frequency: float) -> torch.Tensor:
    """``count`` frequencies in cycles per unit, log-spaced from 1 to ``max_frequency``: ``(count,)``."""
    if count == 1:
        return torch.ones(1)
    return torch.logspace(0.0, math.log10(max_frequency), count)


def fourier_features(coords: torch.Tensor, frequencies: torch.Tensor) -> torch.Tensor:
    """Fourier features of ``coords: (..., D)`` in [0, 1] -> ``(..., D + 2 * D * F)``.

    Returns the coordinates themselves followed by ``sin(2 pi f x)`` and ``cos(2 pi f x)`` for every
    frequency ``f`` (cycles per unit). Computed in float32 even under autocast: the phase of a high
    frequency needs the precision.
    """
    with torch.autocast(device_type=coords.device.type, enabled=False):
        x = coords.float()
        angles = 2 * math.pi * x[..., :, None] * frequencies.to(x.device, torch.float32)
        angles = angles.flatten(-2)
        return torch.cat([x, angles.sin(), angles.cos()], dim=-1)
