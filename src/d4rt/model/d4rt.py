"""The D4RT model: video encoder + query embedding + independent cross-attention decoder.

Two ways in:

- Inference: ``scene = model.encode(video)`` then ``scene.query(queries)`` (see :class:`EncodedScene`).
  ``encode`` takes a video of any size, resizes it to the square encoder input, runs the encoder exactly
  once and keeps what queries need.
- Training: ``model(video, queries, aspect_ratio)`` on batches already at encoder resolution, returning
  ``(B, N, ...)`` tensors including the raw visibility logit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import nn

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model.decoder import QueryDecoder, SceneKV
from d4rt.model.dense_depth import DenseDepthHead
from d4rt.model.encoder import VideoEncoder
from d4rt.model.inputs import (
    as_tensor,
    check_aspect_ratio,
    check_queries,
    check_video,
    encoder_frames,
    pad_to_tubelets,
)
from d4rt.model.layers import FrameRestriction
from d4rt.model.query_embedding import QueryEmbedding
from d4rt.model.encoded_scene import EncodedScene
from d4rt.model.weights import bundled_model_dir, check_state_dict, read_checkpoint, save_checkpoint


class D4RT(nn.Module):
    """D4RT (Zhang et al. 2025): ``D4RT(D4RTConfig.preset("tiny"))``.

    Submodules: ``encoder`` (:class:`VideoEncoder`), ``query_embedding`` (:class:`QueryEmbedding`),
    ``decoder`` (:class:`QueryDecoder`, with its prediction heads), and with ``config.dense_depth_head`` the
    training aid ``dense_depth`` (:class:`DenseDepthHead`).
    """

    def __init__(self, config: D4RTConfig):
        super().__init__()
        if not isinstance(config, D4RTConfig):
            raise UserError(f"D4RT needs a D4RTConfig, got {type(config).__name__}")
        self.config = config
        self.encoder = VideoEncoder(config)
        self.query_embedding = QueryEmbedding(config)
        self.decoder = QueryDecoder(config)
        self.dense_depth = DenseDepthHead(config) if config.dense_depth_head else None
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Truncated-normal linear and embedding weights, zero biases, unit LayerNorms.
        Position tables keep their sine-cosine initialisation."""
        std = self.config.init_std
        for module in self.modules():
            if isinstance(module, (nn.Linear, nn.Embedding)):
                nn.init.trunc_normal_(module.weight, std=std, a=-2 * std, b=2 * std)
                if getattr(module, "bias", None) is not None:
                    nn.init.zeros_(module.bias)
            elif isinstance(module, nn.LayerNorm):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)
        for name, param in self.named_parameters():
            if name.endswith(("q_bias", "v_bias")):
                nn.init.zeros_(param)

    # ------------------------------------------------------------------------------------ core steps
    def encode_tokens(self, video: torch.Tensor, aspect_ratio: torch.Tensor) -> torch.Tensor:
        """``video: (B, T, H, W, 3)`` float in [0, 1] at encoder resolution, ``aspect_ratio: (B,)``
        -> scene tokens ``(B, M, encoder_dim)``. T is padded to whole tubelets by repeating the last frame."""
        mean = video.new_tensor(self.config.pixel_mean)
        std = video.new_tensor(self.config.pixel_std)
        video = pad_to_tubelets((video - mean) / std, self.config.step_frames)
        return self.encoder(video, aspect_ratio.to(video.device))

    def decode(self, queries: torch.Tensor, scene_kv: SceneKV, patch_video: torch.Tensor | None,
               share_sources: bool = False, attention_block: int | None = None,
               tokens_per_step: int | None = None, patch_sizes: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Checked ``queries: (B, N, 5)`` + per-layer scene keys/values -> dict of ``(B, N, ...)``.
        ``patch_sizes``: ``(B, 2)`` each clip's (h, w) in a padded ``patch_video`` (see :meth:`forward`);
        ``share_sources``: embed each run of equal (u, v, t_src) once (see :class:`QueryEmbedding`);
        ``attention_block``: see :meth:`QueryDecoder.forward`; ``tokens_per_step``: tubelet tokens per time step
        of the scene (rows x columns), needed with config ``target_frame_heads``."""
        tokens = self.query_embedding(queries, patch_video, share_sources, patch_sizes)
        same_camera = queries[..., 2].round() == queries[..., 4].round() if self.config.relative_pose_head else None
        frame = None
        if self.config.target_frame_heads:
            if tokens_per_step is None:
                raise ValueError("config target_frame_heads needs tokens_per_step")
            steps = queries[..., 3].round().long() // self.config.step_frames
            frame = FrameRestriction(steps, tokens_per_step, self.config.target_frame_heads)
        out = self.decoder(tokens, scene_kv, same_camera, attention_block, frame)
        if self.config.uv_residual:  # the head answers the displacement (config uv_residual)
            out["uv"] = out["uv"] + queries[..., :2].float()
        return out

    # ------------------------------------------------------------------------------------ training
    def forward(
        self,
        video: torch.Tensor,
        queries: torch.Tensor,
        aspect_ratio: torch.Tensor,
        patch_video: torch.Tensor | None = None,
        check_inputs: bool = True,
        attention_block: int | None = None,
        patch_sizes: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """Batched training forward.

        Args:
            video: ``(B, T, H, W, 3)`` float in [0, 1], already resized to the encoder input (H, W
                multiples of ``patch_size``, at most ``image_size``; normally both equal ``image_size``).
            queries: ``(B, N, 5)`` = [u, v, t_src, t_tgt, t_cam] as in :meth:`EncodedScene.query`.
            aspect_ratio: ``(B,)`` width / height of each clip's original frames.
            patch_video: ``(B, T, h, w, 3)`` frames to cut RGB patches from when
                ``rgb_patch_source == "original"`` (required then); by default ``video`` itself.
            patch_sizes: ``(B, 2)`` integer (h, w) of each clip's frames in ``patch_video`` when the clips differ
                in size and each is padded at the bottom and right to the largest (what
                :func:`d4rt.training.data.collate_samples` builds); None: every clip fills ``patch_video``.
            check_inputs: validate shapes and ranges (one pass over the inputs; False skips it).
            attention_block: also return where the queries look in that decoder block (below).

        Returns:
            dict of ``points (B, N, 3)``, ``uv (B, N, 2)``, ``visibility (B, N)`` (probability),
            ``visibility_logit (B, N)`` (for BCE-with-logits), ``motion (B, N, 3)``,
            ``normals (B, N, 3)`` (unit), ``confidence (B, N)`` (positive); with ``config.dense_depth_head``
            also ``dense_log_depth (B, T, H, W)`` (log-depth of every input pixel up to a per-clip constant);
            with ``attention_block`` also ``attention_log_probs (B, N, M)`` (that block's first head's log
            attention over the M scene tokens: the tubelet tokens in (time step, row, column) order, then the
            aspect-ratio token) and ``token_grid`` (4,) long: time steps, rows, columns, frames per time step.
        """
        if check_inputs:
            video, queries, aspect_ratio, patch_video, patch_sizes = self._check_batch(
                video, queries, aspect_ratio, patch_video, patch_sizes)
        if patch_video is None:
            if self.config.rgb_patch_source == "original" and self.config.rgb_patch_size > 0:
                raise UserError("config rgb_patch_source='original' needs patch_video (the original frames)")
            patch_video = video
        tokens = self.encode_tokens(video, aspect_ratio)
        per_step = (video.shape[2] // self.config.patch_size) * (video.shape[3] // self.config.patch_size)
        out = self.decode(queries, self.decoder.project_scene(tokens), patch_video, attention_block=attention_block,
                          tokens_per_step=per_step, patch_sizes=patch_sizes)
        if attention_block is not None:
            k, p = self.config.step_frames, self.config.patch_size
            out["token_grid"] = torch.tensor([-(-video.shape[1] // k), video.shape[2] // p, video.shape[3] // p, k],
                                             device=tokens.device)
        if self.dense_depth is not None:
            out["dense_log_depth"] = self.dense_depth(tokens, *video.shape[1:4])
        return out

    def _check_batch(self, video, queries, aspect_ratio, patch_video, patch_sizes=None):
        """The training inputs as checked tensors, or a :class:`UserError` naming the problem."""
        cfg = self.config
        device = next(self.parameters()).device
        for name, value in (("video", video), ("queries", queries), ("patch_video", patch_video),
                            ("patch_sizes", patch_sizes)):
            where = None if value is None else as_tensor(value, name).device
            if where is not None and where != device:
                raise UserError(f"{name} is on {where} but the model is on {device}; move the batch first")
        video = check_video(video, cfg.max_frames, batched=True)
        if not video.dtype.is_floating_point:
            raise UserError(f"training video must be float in [0, 1], got {video.dtype}")
        b, t, h, w, _ = video.shape
        if h % cfg.patch_size or w % cfg.patch_size or h > cfg.image_size or w > cfg.image_size:
            raise UserError(f"training video frames must be multiples of patch_size {cfg.patch_size} and at most "
                            f"image_size {cfg.image_size}, got {h}x{w}")
        queries = check_queries(queries, t, batched=True)
        if queries.shape[0] != b:
            raise UserError(f"queries batch {queries.shape[0]} does not match video batch {b}")
        aspect_ratio = check_aspect_ratio(aspect_ratio, b)
        if patch_video is not None:
            patch_video = check_video(patch_video, cfg.max_frames, batched=True)
            if patch_video.shape[:2] != (b, t):
                raise UserError(f"patch_video must have the video's batch and frames {(b, t)}, "
                                f"got {tuple(patch_video.shape[:2])}")
        if patch_sizes is not None:
            if patch_video is None:
                raise UserError("patch_sizes given without patch_video")
            patch_sizes = as_tensor(patch_sizes, "patch_sizes")
            limit, sizes = torch.tensor(patch_video.shape[2:4]), patch_sizes.cpu()
            if (sizes.shape != (b, 2) or sizes.dtype not in (torch.int32, torch.int64)
                    or not bool(((sizes >= 1) & (sizes <= limit)).all())):
                raise UserError(f"patch_sizes must be ({b}, 2) integer (h, w) within patch_video's "
                                f"{tuple(limit.tolist())}, got {sizes.tolist()} ({sizes.dtype})")
        return video, queries, aspect_ratio, patch_video, patch_sizes

    # ------------------------------------------------------------------------------------ inference
    @torch.no_grad()
    def encode(self, video: Any) -> EncodedScene:
        """Encode one clip once; query it with ``scene.query(queries)``.

        Args:
            video: ``(T, H, W, 3)`` uint8 (0..255) or float in [0, 1], torch or numpy, any H and W,
                1 <= T <= ``max_frames``. It is resized (bilinear, antialiased) to the square
                ``image_size`` input; its original W / H goes to the aspect-ratio token, and the original
                frames are kept for RGB patches when ``rgb_patch_source == "original"``.

        Returns:
            :class:`EncodedScene` (no gradients are tracked).
        """
        video = check_video(video, self.config.max_frames)
        frames, height, width, _ = video.shape
        device = next(self.parameters()).device
        resized = encoder_frames(video, self.config.image_size, device)[None]
        aspect = torch.tensor([width / height], device=device)
        tokens = self.encode_tokens(resized, aspect)
        if self.config.rgb_patch_size == 0:
            patch_video = None
        elif self.config.rgb_patch_source == "original":
            # Contiguous once here: patch sampling flattens the frames for every query chunk, which would
            # otherwise copy a permuted or sliced clip again and again.
            patch_video = video.to(device).contiguous()[None]
        else:
            patch_video = resized
        return EncodedScene(self, tokens, frames, height, width, patch_video)

    def reconstruct(self, video: Any, *, window: int | None = None, overlap: int | None = None, **options):
        """Every 4D output of a video through queries: ``Reconstruction.from_model(self, video, ...)``
        (:class:`d4rt.reconstruction.Reconstruction`).

        Videos longer than ``max_frames`` (or ``window``) are encoded window by window (overlapping by
        ``overlap`` frames) and stitched by Sim(3); ``options`` go to ``Reconstruction``.
        """
        # A shortcut kept because outside code relies on it (issue 4's fixed interface); the one upward
        # reference of this layer, resolved at call time and allowed by name in docs/architecture.md.
        from d4rt.reconstruction import Reconstruction

        return Reconstruction.from_model(self, video, window=window, overlap=overlap, **options)

    # ------------------------------------------------------------------------------------ weights
    def save_pretrained(self, directory: str | Path) -> Path:
        """Write ``config.json`` and ``model.safetensors`` into ``directory`` (created if needed)."""
        return save_checkpoint(self, self.config, directory)

    @classmethod
    def from_pretrained(cls, directory: str | Path | None = None, device: str | torch.device = "cpu") -> "D4RT":
        """Load a model saved with :meth:`save_pretrained`; with no directory, the bundled model.

        Raises :class:`UserError` if the directory or its files are missing, or if the weights' keys or
        shapes do not match the config (naming the mismatched keys). The model is returned in eval mode.
        """
        if directory is None:
            directory = bundled_model_dir()
            if not (directory / "model.safetensors").is_file():
                raise UserError("no bundled model ships with this version of d4rt yet; "
                                "pass a directory written by D4RT.save_pretrained()")
        config, state_dict = read_checkpoint(directory, device)
        with torch.device(device):
            model = cls(config)
        model.load_checked_state_dict(state_dict, f"checkpoint {directory}")
        return model.eval()

    def load_checked_state_dict(self, state_dict: dict[str, torch.Tensor], source: str = "state dict") -> None:
        """``load_state_dict`` that first names every missing, unexpected or mis-shaped key."""
        check_state_dict(self, state_dict, source)
        self.load_state_dict(state_dict, strict=True)

    # ------------------------------------------------------------------------------------ sizes
    def parameter_counts(self) -> dict[str, int]:
        """Parameters per part: encoder, query_embedding, decoder_blocks, heads, decoder (the last
        three together), total. Works on the meta device."""
        def count(module: nn.Module) -> int:
            return sum(p.numel() for p in module.parameters())
        counts = {
            "encoder": count(self.encoder),
            "query_embedding": count(self.query_embedding),
            "decoder_blocks": count(self.decoder.blocks),
            "heads": count(self.decoder.heads),
        }
        counts["decoder"] = counts["query_embedding"] + counts["decoder_blocks"] + counts["heads"]
        counts["total"] = counts["encoder"] + counts["decoder"]
        return counts
