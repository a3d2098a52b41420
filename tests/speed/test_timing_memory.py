"""Per-part CPU memory peaks: the resident-set peak can be reset on Linux, so a part's peak is its own."""

import os

import numpy as np
import pytest
import torch

from d4rt.speed.timing import measure_peak, peak_rss_bytes, reset_peak_memory

CPU = torch.device("cpu")


@pytest.mark.skipif(not os.access("/proc/self/clear_refs", os.W_OK), reason="needs Linux /proc/self/clear_refs")
def test_a_part_peak_is_its_own_not_the_process_peak():
    size = 200 * 2**20

    def big():
        a = np.ones(size // 8)  # touched, so resident
        return float(a[-1])

    _, with_big = measure_peak(CPU, big)
    _, small = measure_peak(CPU, lambda: np.ones(1000).sum())
    assert with_big - small > 0.8 * size  # the earlier part's 200 MiB no longer counts
    assert reset_peak_memory(CPU) is True
    assert peak_rss_bytes() < with_big - 0.8 * size
