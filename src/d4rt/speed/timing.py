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


def reset_peak_memory(device: torch.device) -> bool:
    """Start a new peak: CUDA's max-allocated counter, and on Linux the process's resident-set peak
    (writing 5 to /proc/self/clear_refs resets VmHWM to the current resident size). Returns whether
    the CPU peak was reset; where it cannot be (not Linux, not allowed) it stays the whole process's."""
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_rss_bytes() -> int:
    """Peak resident set size (bytes) since the last :func:`reset_peak_memory` on Linux (VmHWM), else
    the process's peak from getrusage (KiB on Linux, bytes on macOS)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def peak_memory_bytes(device: torch.device) -> int:
    """CUDA: the most memory tensors held at once since :func:`reset_peak_memory` (max allocated).
    CPU: the peak resident set size since then (model, inputs, Python and everything else included)."""
    if device.type == "cuda":
        return int(torch.cuda.max_memory_allocated(device))
    return peak_rss_bytes()


def measure_peak(device: torch.device, fn: Callable[[], object]) -> tuple[object, int]:
    """``fn()`` and the peak memory (bytes, :func:`peak_memory_bytes`) while it ran."""
    reset_peak_memory(device)
    result = fn()
    return result, peak_memory_bytes(device)
