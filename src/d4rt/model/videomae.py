"""Initialise the encoder from a public VideoMAE v2 checkpoint (OpenGVLab/VideoMAEv2).

The paper initialises its encoder from VideoMAE v2 and shows random initialisation is far worse
(Sintel AbsRel 0.738 vs 0.302). VideoMAE v2 checkpoint layout (``models/modeling_finetune.py`` and
``models/modeling_pretrain.py`` of the public code), per encoder of width C, MLP width F, tubelet t x p x p:

    patch_embed.proj.weight (C, 3, t, p, p), patch_embed.proj.bias (C,)     Conv3d tubelet embedding
    blocks.N.norm1.weight/bias (C,)
    blocks.N.attn.qkv.weight (3C, C)                                        no bias in the Linear ...
    blocks.N.attn.q_bias, blocks.N.attn.v_bias (C,)                         ... q and v biases apart
    blocks.N.attn.proj.weight (C, C), .bias (C,)
    blocks.N.norm2.weight/bias (C,)
    blocks.N.mlp.fc1.weight (F, C), .bias (F,); blocks.N.mlp.fc2.weight (C, F), .bias (C,)
    blocks.N.gamma_1, blocks.N.gamma_2 (C,)                                 only with layer scale
    norm.weight/bias (C,)                                                   final norm (pre-training)
    fc_norm.*, head.*                                                       classification (fine-tuned)

Pre-training checkpoints put the encoder under ``encoder.`` next to ``decoder.*``,
``encoder_to_decoder.weight`` and ``mask_token``; files may wrap everything in ``model`` or ``module``.
Sizes: ViT-S 384/12/6, ViT-B 768/12/12, ViT-L 1024/24/16, ViT-H 1280/32/16 (patch 16, MLP 4C),
ViT-g 1408/40/16 with MLP 6144 and patch 14; all with 2-frame tubelets.

What converts: the tubelet embedding (resized when the patch size differs, e.g. ViT-g's 14 -> 16,
with the pseudo-inverse resize of FlexiViT: the new kernel w' minimises ||B^T w' - w|| where B resizes a
patch bilinearly, so <resize(x), w'> = <x, w> exactly when upsampling), every block (layer scale folded
into ``attn.proj`` and ``mlp.fc2``), and the final norm. Both attention kinds of our encoder (frame-local
and global) take VideoMAE's (global) blocks as they are.

What does not: the position encoding (VideoMAE uses a fixed 1-D sinusoid over the flattened token index
at 224 px, which is not a time + space sum; ours stays at its sine-cosine initialisation and is
learned), the aspect-ratio token (new), and the heads. These are listed in the returned report.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from d4rt.config import D4RTConfig
from d4rt.errors import UserError

# width -> (depth, heads, mlp width, patch size) of the VideoMAE v2 encoders.
VIDEOMAE_V2_SIZES = {
    384: (12, 6, 1536, 16),    # ViT-S
    768: (12, 12, 3072, 16),   # ViT-B
    1024: (24, 16, 4096, 16),  # ViT-L
    1280: (32, 16, 5120, 16),  # ViT-H
    1408: (40, 16, 6144, 14),  # ViT-g
}

_WRAPPERS = ("model", "module", "state_dict")
_BLOCK_KEY = re.compile(r"^blocks\.(\d+)\.(.+)$")
_BLOCK_PARAMS = {
    "norm1.weight", "norm1.bias", "attn.qkv.weight", "attn.q_bias", "attn.v_bias", "attn.proj.weight",
    "attn.proj.bias", "norm2.weight", "norm2.bias", "mlp.fc1.weight", "mlp.fc1.bias", "mlp.fc2.weight",
    "mlp.fc2.bias",
}
# Parts of VideoMAE checkpoints with no counterpart in the D4RT encoder.
_DROPPED = re.compile(r"^(decoder\.|encoder_to_decoder\.|mask_token$|head\.|fc_norm\.|pos_embed$|cls_token$)")


@dataclass
class ConversionReport:
    """What :func:`load_videomae_v2` did. Keys are relative to ``model.encoder``."""

    loaded: list[str] = field(default_factory=list)
    kept_initialised: list[str] = field(default_factory=list)
    dropped_source_keys: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def unwrap_checkpoint(checkpoint: dict[str, Any]) -> dict[str, torch.Tensor]:
    """The flat VideoMAE state dict inside a loaded checkpoint: unwrap ``model``/``module``/``state_dict``
    and strip ``module.``, ``_orig_mod.``, ``backbone.`` prefixes (``encoder.`` is handled by
    :func:`convert_videomae_v2`, which needs it to tell encoder from decoder keys)."""
    for key in _WRAPPERS:
        if key in checkpoint and isinstance(checkpoint[key], dict):
            checkpoint = checkpoint[key]
            break
    flat = {}
    for key, value in checkpoint.items():
        if not isinstance(value, torch.Tensor):
            continue
        for prefix in ("module.", "_orig_mod.", "backbone."):
            if key.startswith(prefix):
                key = key[len(prefix):]
        flat[key] = value
    return flat


def resize_patch_kernel(weight: torch.Tensor, size: int) -> torch.Tensor:
    """Pseudo-inverse resize of a patch kernel ``(..., p, p) -> (..., size, size)`` (FlexiViT).

    ``B: (size^2, p^2)`` is bilinear (antialiased) resizing of a flattened p x p patch; the new kernel
    ``w' = pinv(B^T) w`` gives ``<B x, w'> = <x, w>`` for every patch x when upsampling, and the least
    squares best kernel when downsampling.
    """
    p = weight.shape[-1]
    if p == size:
        return weight
    basis = torch.eye(p * p, dtype=torch.float64, device=weight.device).reshape(p * p, 1, p, p)
    resized = F.interpolate(basis, size=(size, size), mode="bilinear", align_corners=False, antialias=size < p)
    resize_matrix = resized.reshape(p * p, size * size).T  # B: (size^2, p^2)
    solve = torch.linalg.pinv(resize_matrix.T)  # (size^2, p^2)
    flat = weight.reshape(-1, p * p).to(torch.float64)
    return (flat @ solve.T).reshape(*weight.shape[:-2], size, size).to(weight.dtype)


def convert_videomae_v2(state_dict: dict[str, torch.Tensor], config: D4RTConfig) -> tuple[dict[str, torch.Tensor], ConversionReport]:
    """Map a (flat) VideoMAE v2 state dict onto the keys of ``D4RT(config).encoder``.

    Raises :class:`UserError` when the checkpoint cannot fit the config (width, depth, MLP, heads of a
    known VideoMAE size, tubelet frames) or has keys this converter does not know.
    """
    report = ConversionReport()
    encoder_keys = any(k.startswith("encoder.") for k in state_dict)
    source: dict[str, torch.Tensor] = {}
    for key, value in state_dict.items():
        if encoder_keys:
            if not key.startswith("encoder."):
                if not _DROPPED.match(key):
                    raise UserError(f"unrecognised VideoMAE v2 key {key!r}")
                report.dropped_source_keys.append(key)
                continue
            key = key[len("encoder."):]
        if _DROPPED.match(key):
            report.dropped_source_keys.append(("encoder." if encoder_keys else "") + key)
            continue
        source[key] = value

    if "patch_embed.proj.weight" not in source:
        raise UserError("not a VideoMAE v2 checkpoint: no patch_embed.proj.weight")
    kernel = source.pop("patch_embed.proj.weight")
    if kernel.ndim != 5 or kernel.shape[1] != 3:
        raise UserError(f"VideoMAE patch_embed.proj.weight must be (C, 3, t, p, p), got {tuple(kernel.shape)}")
    width, _, frames, p, _ = kernel.shape
    _check_size("encoder width", width, config.encoder_dim)
    _check_size("tubelet frames", frames, config.tubelet_frames)
    if width in VIDEOMAE_V2_SIZES:
        heads = VIDEOMAE_V2_SIZES[width][1]
        _check_size("attention heads (known VideoMAE v2 size)", heads, config.encoder_heads)
    if p != config.patch_size:
        kernel = resize_patch_kernel(kernel, config.patch_size)
        report.notes.append(f"patch embedding resized from {p}x{p} to {config.patch_size}x{config.patch_size}")

    out = {"patch_embed.proj.weight": kernel.reshape(width, -1), "patch_embed.proj.bias": source.pop("patch_embed.proj.bias")}
    blocks: dict[int, dict[str, torch.Tensor]] = {}
    for key in list(source):
        match = _BLOCK_KEY.match(key)
        if match:
            blocks.setdefault(int(match.group(1)), {})[match.group(2)] = source.pop(key)
    depth = len(blocks)
    if sorted(blocks) != list(range(depth)):
        raise UserError(f"VideoMAE checkpoint block indices are not 0..{depth - 1}")
    _check_size("encoder depth", depth, config.encoder_depth)
    for index, params in blocks.items():
        out.update(_convert_block(index, params, report))
    for name in ("norm.weight", "norm.bias"):
        if name in source:
            out[name] = source.pop(name)
    if source:
        raise UserError(f"unrecognised VideoMAE v2 key(s): {', '.join(sorted(source)[:5])}")
    return out, report


def _convert_block(index: int, params: dict[str, torch.Tensor], report: ConversionReport) -> dict[str, torch.Tensor]:
    if "attn.scale" in params:
        raise UserError("VideoMAE checkpoints with cosine attention (cos_attn) are not supported")
    params = dict(params)
    gamma_1, gamma_2 = params.pop("gamma_1", None), params.pop("gamma_2", None)
    width = params["attn.qkv.weight"].shape[1]
    for bias in ("attn.q_bias", "attn.v_bias"):
        if bias not in params:  # a model built with qkv_bias=False: its biases are exactly zero
            params[bias] = params["attn.qkv.weight"].new_zeros(width)
            report.notes.append(f"blocks.{index}.{bias} absent in checkpoint, set to 0")
    unknown = set(params) - _BLOCK_PARAMS
    if unknown:
        raise UserError(f"unrecognised VideoMAE v2 key(s) in block {index}: {', '.join(sorted(unknown))}")
    # Layer scale: x + gamma * (W h + b) == x + (gamma W) h + gamma b, so fold gamma into the last linear.
    if gamma_1 is not None:
        params["attn.proj.weight"] = params["attn.proj.weight"] * gamma_1[:, None]
        params["attn.proj.bias"] = params["attn.proj.bias"] * gamma_1
    if gamma_2 is not None:
        params["mlp.fc2.weight"] = params["mlp.fc2.weight"] * gamma_2[:, None]
        params["mlp.fc2.bias"] = params["mlp.fc2.bias"] * gamma_2
    return {f"blocks.{index}.{name}": value for name, value in params.items()}


def _check_size(what: str, checkpoint_value: int, config_value: int) -> None:
    if checkpoint_value != config_value:
        raise UserError(f"VideoMAE checkpoint {what} is {checkpoint_value} but the config has {config_value}")


def load_videomae_v2(model: Any, checkpoint: str | Path | dict[str, Any]) -> ConversionReport:
    """Initialise ``model.encoder`` (a :class:`D4RT`) from a VideoMAE v2 checkpoint.

    Args:
        model: the D4RT model whose encoder is overwritten.
        checkpoint: a path to a ``.pth``/``.pt`` (read with ``weights_only=True``) or ``.safetensors``
            file, or an already-loaded dict.

    Returns:
        :class:`ConversionReport` naming what was loaded, what stayed at its initialisation (position
        tables, aspect-ratio token, final norm if the checkpoint has none) and what was dropped.
    """
    if not isinstance(checkpoint, dict):
        checkpoint = _read(Path(checkpoint))
    converted, report = convert_videomae_v2(unwrap_checkpoint(checkpoint), model.config)
    target = model.encoder.state_dict()
    wrong = [f"{k} {tuple(v.shape)} vs encoder {tuple(target[k].shape)}"
             for k, v in converted.items() if k in target and v.shape != target[k].shape]
    unknown = [k for k in converted if k not in target]
    if wrong or unknown:
        raise UserError("VideoMAE checkpoint does not fit the encoder: " + "; ".join((wrong + unknown)[:5]))
    merged = {k: converted[k].to(target[k].dtype) if k in converted else v for k, v in target.items()}
    model.encoder.load_state_dict(merged, strict=True)
    report.loaded = sorted(converted)
    report.kept_initialised = sorted(set(target) - set(converted))
    return report


def _read(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise UserError(f"VideoMAE checkpoint not found: {path}")
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        return load_file(str(path))
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a bad pickle
        raise UserError(f"cannot read VideoMAE checkpoint {path}: {err}") from None
