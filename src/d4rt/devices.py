"""Turning a user's device name into a torch device, with one clear error when it is not there, and
whether the device computes bfloat16 natively."""

from __future__ import annotations

import platform
from pathlib import Path

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


def cpu_name() -> str:
    """The CPU's model name (Linux /proc/cpuinfo), else what the platform module knows: benchmark figures
    name the CPU they were measured on."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


# CPU flags of native bfloat16 arithmetic (Linux /proc/cpuinfo names): Intel AMX tiles, AVX-512 BF16.
BF16_CPU_FLAGS = ("amx_bf16", "avx512_bf16")


def native_bf16(device: torch.device, cpuinfo: str | None = None) -> bool:
    """Whether bfloat16 autocast runs natively (fast) on ``device``: CUDA GPUs that support it, and CPUs with
    AMX-BF16 or AVX512-BF16 (read from /proc/cpuinfo, or ``cpuinfo`` text; False where it cannot be read).
    Without native support bf16 is emulated and slower than float32."""
    if device.type == "cuda":
        return bool(torch.cuda.is_bf16_supported())
    if device.type != "cpu":
        return False
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return False
    flags = set()
    for line in cpuinfo.splitlines():
        if line.startswith("flags"):
            flags.update(line.partition(":")[2].split())
    return any(flag in flags for flag in BF16_CPU_FLAGS)
