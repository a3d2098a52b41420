"""The video encoder E: a ViT over the tubelets of a whole clip -> the Global Scene Representation F.

Tokens: one per tubelet (``tubelet_frames`` x ``patch_size`` x ``patch_size`` pixels; a tubelet starts every
``step_frames`` frames, so with a ``tubelet_stride`` below ``tubelet_frames`` they overlap in time), plus one
aspect-ratio token (a linear embedding of the original W / H). Blocks alternate between frame-local
attention (the tokens of one tubelet time step attend to each other) and global attention (every token
of the clip, the aspect-ratio token included, attends to every other), as in VGGT. In frame-local
blocks the aspect-ratio token forms a group of its own.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from d4rt.config import D4RTConfig
from d4rt.model.layers import SelfAttentionBlock, run_block, sincos_1d, sincos_2d


class TubeletEmbedding(nn.Module):
    """Cut the clip into tubelets and embed each linearly.

    ``video: (B, T, H, W, 3)`` normalised pixels, T a multiple of ``stride``, H and W multiples of
    ``patch_size`` -> ``(B, T', H', W', dim)`` with T' = T / stride, H' = H / patch_size; tubelet j spans
    frames j * stride to j * stride + tubelet_frames - 1, the last frame repeated past the clip's end
    (``stride`` None: ``tubelet_frames``, tubelets that do not overlap).
    The projection weight ``proj.weight: (dim, 3 * tubelet_frames * patch^2)`` flattens each tubelet in
    (channel, time, row, column) order: exactly a Conv3d kernel ``(dim, 3, t, p, p)`` reshaped, which
    is how VideoMAE v2 stores its patch embedding.
    """

    def __init__(self, tubelet_frames: int, patch_size: int, dim: int, stride: int | None = None):
        super().__init__()
        self.tubelet_frames, self.patch_size = tubelet_frames, patch_size
        self.stride = tubelet_frames if stride is None else stride
        self.proj = nn.Linear(3 * tubelet_frames * patch_size * patch_size, dim)

    def forward(self, video: torch.Tensor) -> torch.Tensor:
        b, t, h, w, c = video.shape
        k, s, p = self.tubelet_frames, self.stride, self.patch_size
        if s < k:  # overlapping tubelets: the last ones reach k - s frames past the clip's end
            video = torch.cat([video, video[:, -1:].expand(b, k - s, h, w, c)], dim=1)
        x = video.unfold(1, k, s)  # (B, T', H, W, C, k): a window of k frames every s frames
        # -> (B, T', H', W', C, k, p, p): each tubelet in (channel, time, row, column) order
        x = x.reshape(b, t // s, h // p, p, w // p, p, c, k).permute(0, 1, 2, 4, 6, 7, 3, 5)
        return self.proj(x.flatten(4).to(self.proj.weight.dtype))  # float32 pixels into a bf16 model too


class SpaceTimePositions(nn.Module):
    """Learned space-time position embedding, factorised as time + space.

    ``time: (max_time_steps, dim)`` and ``space: (grid, grid, dim)`` are initialised with sine-cosine
    values and trained. A clip with fewer time steps uses the first rows (time step i is always row i);
    an input smaller than ``image_size`` (training at lower resolution) bilinearly resizes the spatial
    table to its grid, so positions keep their meaning as fractions of the image.
    """

    def __init__(self, max_time_steps: int, grid: int, dim: int):
        super().__init__()
        self.time = nn.Parameter(sincos_1d(torch.arange(max_time_steps), dim))
        self.space = nn.Parameter(sincos_2d(grid, dim))

    def space_table(self, rows: int, cols: int) -> torch.Tensor:
        """-> ``(rows, cols, dim)``: the spatial table, bilinearly resized when the grid is another size."""
        space = self.space
        if (rows, cols) != tuple(space.shape[:2]):
            space = F.interpolate(space.permute(2, 0, 1)[None], size=(rows, cols), mode="bilinear",
                                  align_corners=False)[0].permute(1, 2, 0)
        return space

    def forward(self, steps: int, rows: int, cols: int) -> torch.Tensor:
        """-> ``(steps, rows, cols, dim)`` to add to the tubelet tokens."""
        return self.time[:steps, None, None, :] + self.space_table(rows, cols)[None]


class VideoEncoder(nn.Module):
    """E(V): normalised video and aspect ratio -> scene tokens.

    ``forward(video: (B, T, H, W, 3), aspect_ratio: (B,)) -> (B, T' * H' * W' + 1, dim)``: tubelet
    tokens in (time, row, column) order followed by the aspect-ratio token, after a final LayerNorm.
    ``video`` is normalised with the config's pixel mean/std; T a multiple of ``step_frames`` and at
    most ``max_frames`` rounded up to it; H, W multiples of ``patch_size`` at most ``image_size``.
    """

    def __init__(self, config: D4RTConfig):
        super().__init__()
        self.config = config
        dim = config.encoder_dim
        self.patch_embed = TubeletEmbedding(config.tubelet_frames, config.patch_size, dim, config.step_frames)
        self.pos_embed = SpaceTimePositions(config.max_time_steps, config.grid_size, dim)
        # W / H as given (the paper's "linear embedding of the aspect ratio").
        self.aspect_embed = nn.Linear(1, dim)
        self.blocks = nn.ModuleList(
            SelfAttentionBlock(dim, config.encoder_heads, config.encoder_mlp_dim, config.layer_norm_eps)
            for _ in range(config.encoder_depth)
        )
        self.norm = nn.LayerNorm(dim, eps=config.layer_norm_eps)

    def is_global(self, index: int) -> bool:
        """Whether block ``index`` attends over the whole clip (else within one time step)."""
        return (index + 1) % self.config.global_attention_every == 0

    def forward(self, video: torch.Tensor, aspect_ratio: torch.Tensor) -> torch.Tensor:
        b = video.shape[0]
        tokens = self.patch_embed(video)  # (B, T', H', W', C)
        _, steps, rows, cols, dim = tokens.shape
        tokens = tokens + self.pos_embed(steps, rows, cols).to(tokens.dtype)
        frames = tokens.reshape(b, steps, rows * cols, dim)
        aspect = self.aspect_embed(aspect_ratio.reshape(b, 1, 1).to(self.aspect_embed.weight.dtype))

        for index, block in enumerate(self.blocks):
            if self.is_global(index):
                x = torch.cat([frames.reshape(b, steps * rows * cols, dim), aspect], dim=1)
                x = self._run(block, x)
                frames, aspect = x[:, :-1].reshape(b, steps, rows * cols, dim), x[:, -1:]
            else:
                frames = self._run(block, frames.reshape(b * steps, rows * cols, dim)).reshape(b, steps, rows * cols, dim)
                aspect = self._run(block, aspect)
        x = torch.cat([frames.reshape(b, steps * rows * cols, dim), aspect], dim=1)
        return self.norm(x)

    def _run(self, block: nn.Module, x: torch.Tensor) -> torch.Tensor:
        return run_block(block, x, recompute=self.config.gradient_checkpointing and self.training)
