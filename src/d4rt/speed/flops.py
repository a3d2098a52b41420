"""FLOPs of the model counted analytically from its config, and the peak throughput of known GPUs.

One multiply-add counts as 2 FLOPs. Counted: every linear layer and both attention matrix products
(Q K^T and A V); not counted: normalisations, softmax, GELU, additions and the RGB patch sampling
(together a few percent). ``tests/benchmark`` checks these counts against
``torch.utils.flop_counter.FlopCounterMode`` on a real forward pass.
"""

from __future__ import annotations

from d4rt.config import D4RTConfig

# Dense (no sparsity) bf16 tensor-core peaks in TFLOP/s, from the vendors' data sheets, matched by the
# longest name fragment contained in torch.cuda.get_device_name(). SXM and PCIe parts differ in clock.
PEAK_BF16_TFLOPS = {
    "H200": 989.0,
    "H100 NVL": 835.0,
    "H100 PCIe": 756.0,
    "H100": 989.0,  # SXM (e.g. "NVIDIA H100 80GB HBM3")
    "A100": 312.0,  # SXM and PCIe, 40 and 80 GB
}


def peak_tflops(device_name: str | None, dtype: str) -> float | None:
    """Peak dense TFLOP/s of the named GPU for ``dtype`` ("bf16"), or None (CPU, fp32, unknown GPU)."""
    if not device_name or dtype != "bf16":
        return None
    matches = [key for key in PEAK_BF16_TFLOPS if key.lower() in device_name.lower()]
    return PEAK_BF16_TFLOPS[max(matches, key=len)] if matches else None


def token_grid(config: D4RTConfig, frames: int) -> tuple[int, int]:
    """(tubelet time steps, tokens per step) of a clip of ``frames`` frames at the encoder input."""
    return -(-frames // config.step_frames), config.grid_size ** 2


def encoder_flops(config: D4RTConfig, frames: int) -> int:
    """FLOPs of one encoder forward over a ``frames``-frame clip (padded to whole tubelets)."""
    steps, per_step = token_grid(config, frames)
    d, mlp = config.encoder_dim, config.encoder_mlp_dim
    video_tokens = steps * per_step
    tokens = video_tokens + 1  # + the aspect-ratio token
    flops = 2 * video_tokens * 3 * config.tubelet_frames * config.patch_size ** 2 * d  # tubelet embedding
    flops += 2 * d  # aspect-ratio embedding
    linear = 2 * tokens * (3 * d * d + d * d + 2 * d * mlp)  # qkv, proj, fc1, fc2
    for index in range(config.encoder_depth):
        if (index + 1) % config.global_attention_every == 0:
            attention = 4 * tokens * tokens * d
        else:  # each time step on its own, the aspect-ratio token alone
            attention = 4 * steps * per_step * per_step * d + 4 * d
        flops += linear + attention
    return flops


def scene_kv_flops(config: D4RTConfig, frames: int) -> int:
    """FLOPs of projecting a clip's scene tokens to the keys and values of every decoder layer."""
    steps, per_step = token_grid(config, frames)
    tokens = steps * per_step + 1
    return config.decoder_depth * 2 * tokens * config.encoder_dim * 2 * config.decoder_dim


def decoder_flops_per_query(config: D4RTConfig, frames: int) -> int:
    """FLOPs of decoding one query against a ``frames``-frame clip (scene keys/values already projected):
    query embedding, every cross-attention + MLP block, and the heads."""
    steps, per_step = token_grid(config, frames)
    tokens = steps * per_step + 1
    d, mlp = config.decoder_dim, config.decoder_mlp_dim
    embed = 2 * (2 + 4 * config.fourier_frequencies) * d + 2 * 3 * config.rgb_patch_size ** 2 * d
    block = 2 * (2 * d * d + 2 * d * mlp) + 4 * tokens * d
    heads = 2 * d * 13
    return embed + config.decoder_depth * block + heads
