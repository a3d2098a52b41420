"""Checkpoint files: ``model.safetensors`` plus ``config.json`` beside it, and strict key checking.

A checkpoint whose keys or shapes differ from the model built from its config is refused with a message
naming the mismatched keys; nothing is loaded partially (no ``strict=False``).
"""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from d4rt.config import D4RTConfig
from d4rt.errors import UserError

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
BUNDLED_MODEL = "d4rt-tiny"
_SHOWN = 5  # mismatched keys named in one error line
# Parts that ``model.init_from`` may add to a checkpoint without them (never remove), and that
# tools/average_weights.py takes whole from the checkpoints that have them: config flag -> prefix of their tensors.
ADDABLE_PARTS = {"relative_pose_head": "decoder.heads.relative_pose.", "dense_depth_head": "dense_depth."}


def bundled_model_dir() -> Path:
    """Where the model that ships inside the package lives: ``d4rt/assets/d4rt-tiny/``."""
    return Path(__file__).resolve().parent.parent / "assets" / BUNDLED_MODEL


def save_checkpoint(model: nn.Module, config: D4RTConfig, directory: str | Path) -> Path:
    """Write ``config.json`` and ``model.safetensors`` (float tensors as they are) into ``directory``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tensors = {name: tensor.detach().contiguous().cpu() for name, tensor in model.state_dict().items()}
    save_file(tensors, str(directory / WEIGHTS_NAME), metadata={"format": "pt", "d4rt_config": config.to_json()})
    config.save(directory / CONFIG_NAME)
    return directory


def read_checkpoint(directory: str | Path, device: str | torch.device = "cpu") -> tuple[D4RTConfig, dict[str, torch.Tensor]]:
    """Read the config and the tensors of a checkpoint directory written by :func:`save_checkpoint`."""
    directory = Path(directory)
    if not directory.is_dir():
        raise UserError(f"checkpoint directory not found: {directory}")
    config_path, weights_path = directory / CONFIG_NAME, directory / WEIGHTS_NAME
    for path in (config_path, weights_path):
        if not path.is_file():
            raise UserError(f"checkpoint {directory} has no {path.name}")
    config = D4RTConfig.load(config_path)
    try:
        tensors = load_file(str(weights_path), device=str(device))
    except (SafetensorError, OSError) as err:
        raise UserError(f"cannot read {weights_path}: {err}") from None
    return config, tensors


def check_state_dict(model: nn.Module, state_dict: dict[str, torch.Tensor], source: str) -> None:
    """Raise :class:`UserError` unless ``state_dict`` has exactly the model's keys and shapes."""
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state_dict))
    unexpected = sorted(set(state_dict) - set(expected))
    wrong_shape = sorted(
        f"{key} {tuple(state_dict[key].shape)} vs model {tuple(expected[key].shape)}"
        for key in set(expected) & set(state_dict)
        if tuple(state_dict[key].shape) != tuple(expected[key].shape)
    )
    problems = [f"{label}: {_listing(keys)}" for label, keys in
                (("missing keys", missing), ("unexpected keys", unexpected), ("shape mismatch", wrong_shape)) if keys]
    if problems:
        raise UserError(f"{source} does not match the model config; " + "; ".join(problems))


def _listing(keys: list[str]) -> str:
    shown = ", ".join(keys[:_SHOWN])
    return shown + (f" (+{len(keys) - _SHOWN} more)" if len(keys) > _SHOWN else "")
