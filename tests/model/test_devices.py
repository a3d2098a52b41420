"""Device names and native bfloat16 detection (what `d4rt reconstruct --dtype auto` decides from)."""

import pytest
import torch

from d4rt.devices import native_bf16, resolve_device
from d4rt.errors import UserError

AMX_CPU = "processor\t: 0\nflags\t\t: fpu sse2 avx2 avx512f avx512_bf16 amx_bf16 amx_tile\n"
OLD_CPU = "processor\t: 0\nflags\t\t: fpu sse2 avx2 fma\n"


def test_native_bf16_follows_the_cpu_flags():
    cpu = torch.device("cpu")
    assert native_bf16(cpu, AMX_CPU) and not native_bf16(cpu, OLD_CPU) and not native_bf16(cpu, "")
    assert not native_bf16(torch.device("meta"))


def test_device_names():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(UserError, match="is not a torch device"):
        resolve_device("gpu0", "--device")
