"""Encoder throughput: clips/s, scene tokens/s, achieved TFLOP/s and model FLOP utilisation."""

from __future__ import annotations

import torch

from d4rt.speed.flops import encoder_flops, peak_tflops, scene_kv_flops
from d4rt.speed.options import BenchOptions
from d4rt.speed.timing import best_time
from d4rt.model.inputs import encoder_frames


def bench_encoder(model, video: torch.Tensor, options: BenchOptions, device_name: str | None) -> dict:
    """Time the encoder on the resized clip (``encode_tokens``: normalisation, tubelets, ViT) and the
    whole ``model.encode`` (resize from the original frames included), plus the scene key/value
    projection every decoder layer needs once per clip.

    Returns encoder_s, encode_s, scene_kv_s, clips_per_s, tokens_per_s, flops, tflops_per_s and mfu
    (None off the GPU or without a known bf16 peak).
    """
    device = torch.device(options.device)
    config = model.config
    frames = video.shape[0]
    resized = encoder_frames(video, config.image_size, device)[None]
    aspect = torch.tensor([video.shape[2] / video.shape[1]], device=device)
    with torch.no_grad(), options.autocast():
        tokens = model.encode_tokens(resized, aspect)
        encoder_s = best_time(lambda: model.encode_tokens(resized, aspect), device, options.repeats)
        encode_s = best_time(lambda: model.encode(video), device, options.repeats)
        kv_s = best_time(lambda: model.decoder.project_scene(tokens), device, options.repeats)
    flops = encoder_flops(config, frames)
    achieved = flops / encoder_s / 1e12
    peak = peak_tflops(device_name, options.dtype) if device.type == "cuda" else None
    return {
        "scene_tokens": int(tokens.shape[1]),
        "encoder_s": encoder_s,
        "encode_s": encode_s,
        "scene_kv_s": kv_s,
        "clips_per_s": 1.0 / encoder_s,
        "tokens_per_s": tokens.shape[1] / encoder_s,
        "flops": flops,
        "scene_kv_flops": scene_kv_flops(config, frames),
        "tflops_per_s": achieved,
        "peak_tflops": peak,
        "mfu": achieved / peak if peak else None,
    }
