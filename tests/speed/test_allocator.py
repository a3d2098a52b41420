"""d4rt.allocator: the C heap keeps multi-MB buffers for reuse (set once per process, by the CLI), and the
user's own glibc settings win."""

import os
import subprocess
import sys

import pytest

from subprocess_budget import budget

PROBE = "from d4rt.allocator import reuse_large_buffers; print(reuse_large_buffers(), reuse_large_buffers())"


def run_probe(**env) -> str:
    environment = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")} | env
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=environment,
                          timeout=budget(60))
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_thresholds_are_set_once_unless_the_environment_sets_them():
    assert run_probe() == "True True"  # glibc: set, and the second call does nothing more
    assert run_probe(MALLOC_TRIM_THRESHOLD_="1048576") == "False False"


def test_a_freed_multi_megabyte_buffer_is_reused_in_this_process():
    # The CLI sets the thresholds at start; here the test process does, then a freed 6 MB buffer's
    # memory comes back for the next one of that size (same address), instead of fresh pages.
    from d4rt.allocator import reuse_large_buffers

    if not reuse_large_buffers():
        pytest.skip("not glibc, or thresholds set in the environment")
    import numpy as np

    first = np.empty(6 << 20, dtype=np.uint8)
    address = first.ctypes.data
    del first
    assert np.empty(6 << 20, dtype=np.uint8).ctypes.data == address
