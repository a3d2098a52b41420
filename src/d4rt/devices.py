"""Turning a user's device name into a torch device, with one clear error when it is not there."""

from __future__ import annotations

import torch

from d4rt.errors import UserError


def resolve_device(name: str, what: str = "device") -> torch.device:
    """"auto" (CUDA if available, else the CPU) or any torch device name ("cpu", "cuda", "cuda:1", "mps").

    A malformed name, or a device this machine does not have, raises :class:`UserError` naming it;
    ``what`` names the setting in that message (e.g. "--device").
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError:
        raise UserError(f"{what} {name!r} is not a torch device (auto, cpu, cuda, cuda:1, mps, ...)") from None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise UserError(f"{what} {name!r} asked for but CUDA is not available on this machine")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise UserError(f"{what} {name!r} asked for but only {torch.cuda.device_count()} CUDA device(s) exist")
    elif device.type == "mps" and not torch.backends.mps.is_available():
        raise UserError(f"{what} {name!r} asked for but MPS is not available on this machine")
    return device
