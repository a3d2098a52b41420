"""Wall-clock timing and peak memory, correct on CPU and GPU.

GPU work is asynchronous: every timed region starts and ends with a device synchronisation, so a time
covers the work itself and not only its launch. Times are the best of several runs after a warm-up
(the least disturbed by other processes, and past one-off costs such as allocator growth or
``torch.compile``).
"""

from __future__ import annotations

import resource
import sys
import time
from typing import Callable

import torch


def synchronize(device: torch.device) -> None:
    """Wait for all queued work on ``device`` (a no-op on the CPU)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_once(fn: Callable[[], object], device: torch.device) -> float:
    """Seconds ``fn()`` takes, device work included."""
    synchronize(device)
    start = time.perf_counter()
    fn()
    synchronize(device)
    return time.perf_counter() - start


def best_time(fn: Callable[[], object], device: torch.device, repeats: int = 3, warmup: int = 1) -> float:
    """Best of ``repeats`` timed runs of ``fn`` (seconds) after ``warmup`` untimed ones."""
    for _ in range(warmup):
        fn()
    return min(time_once(fn, device) for _ in range(max(1, repeats)))


def reset_peak_memory(device: torch.device) -> None:
    """Start a new CUDA peak (the CPU's resident-set peak cannot be reset: it is the process's)."""
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def peak_rss_bytes() -> int:
    """The process's peak resident set size so far (bytes), from getrusage (KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def peak_memory_bytes(device: torch.device) -> int:
    """CUDA: the most memory tensors held at once since :func:`reset_peak_memory` (max allocated).
    CPU: the process's peak resident set size (model, inputs, Python and everything else included)."""
    if device.type == "cuda":
        return int(torch.cuda.max_memory_allocated(device))
    return peak_rss_bytes()
