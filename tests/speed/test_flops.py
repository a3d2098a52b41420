"""The analytic FLOP counts match torch's FlopCounterMode on real forward passes; GPU peaks by name."""

import pytest
import torch
from torch.nn.attention import SDPBackend, sdpa_kernel
from torch.utils.flop_counter import FlopCounterMode

from d4rt.speed.flops import decoder_flops_per_query, encoder_flops, peak_tflops, scene_kv_flops
from d4rt.config import D4RTConfig
from d4rt.model import D4RT


def counted(fn) -> int:
    # The math attention kernel is plain matrix products, which the counter sees (fused CPU kernels it does not).
    with sdpa_kernel(SDPBackend.MATH), FlopCounterMode(display=False) as counter, torch.no_grad():
        fn()
    return counter.get_total_flops()


@pytest.mark.parametrize("frames", [3, 4])
def test_encoder_and_decoder_counts_match_the_flop_counter(frames):
    torch.manual_seed(0)
    config = D4RTConfig.preset("tiny", encoder_depth=4, decoder_depth=2)
    model = D4RT(config).eval()
    video = torch.rand(1, frames, config.image_size, config.image_size, 3)
    aspect = torch.tensor([1.5])
    assert counted(lambda: model.encode_tokens(video, aspect)) == encoder_flops(config, frames)

    tokens = model.encode_tokens(video, aspect)
    assert counted(lambda: model.decoder.project_scene(tokens)) == scene_kv_flops(config, frames)
    kv = model.decoder.project_scene(tokens)
    n = 7
    queries = torch.cat([torch.rand(1, n, 2), torch.randint(0, frames, (1, n, 3)).float()], -1)
    assert counted(lambda: model.decode(queries, kv, video)) == n * decoder_flops_per_query(config, frames)


def test_peak_table_by_device_name():
    assert peak_tflops("NVIDIA H100 80GB HBM3", "bf16") == 989.0
    assert peak_tflops("NVIDIA H100 PCIe", "bf16") == 756.0
    assert peak_tflops("NVIDIA H200", "bf16") == 989.0
    assert peak_tflops("NVIDIA A100-SXM4-80GB", "bf16") == 312.0
    assert peak_tflops("NVIDIA A100-SXM4-80GB", "fp32") is None  # MFU is quoted against bf16 peaks only
    assert peak_tflops("NVIDIA GeForce RTX 4090", "bf16") is None
    assert peak_tflops(None, "bf16") is None
