"""Settings of the C heap (glibc's malloc) for d4rt's workloads.

Decoding a chunk of queries allocates and frees a few buffers of several MB each (e.g. (4096, 768) bf16
activations: 6 MB), over and over. glibc serves buffers above its mmap threshold with fresh pages from
the kernel and returns them on free, and trims the top of its heap once enough is free there: either
way the next chunk's buffers start as untouched pages, and faulting them in cost more than the matrix
products themselves (measured on the decoder's MLP, 4,096 queries, 2 threads: 5.3 ms, 1.9 ms with the
settings below; `d4rt reconstruct` of 48 frames of 128x128: 13.6-14.7 s instead of 16.9-18.0 s, about the
same peak memory). With a fixed mmap threshold of 16 MB and a trim threshold of 64 MB, buffers of that size
are reused from the heap; larger arrays (video frames, whole outputs) still come from, and go back to, the
kernel.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys

MMAP_THRESHOLD = 16 << 20  # bytes: allocations up to this size are served from the heap
TRIM_THRESHOLD = 64 << 20  # bytes of free memory at the top of the heap kept for reuse
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt parameters (malloc.h)
_ENVIRONMENT = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


@functools.cache
def reuse_large_buffers() -> bool:
    """Set the thresholds above for this process (once; later calls do nothing). Returns whether they were
    set: not where the C library is not glibc, nor where the user set either threshold in the environment
    (glibc's own variables, which win)."""
    if not sys.platform.startswith("linux") or any(name in os.environ for name in _ENVIRONMENT):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.gnu_get_libc_version  # glibc only: musl and others have no such mallopt parameters
    except (OSError, AttributeError):
        return False
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(libc.mallopt(_M_TRIM_THRESHOLD,
                                                                                          TRIM_THRESHOLD))
