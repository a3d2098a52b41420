"""Building blocks: encodings, attention, RGB patch sampling conventions, encoder structure."""

import math

import pytest
import torch
import torch.nn.functional as F

from d4rt.model.layers import CrossAttention, fourier_features, fourier_frequencies, sincos_2d
from d4rt.model.query_embedding import sample_rgb_patches

ZERO, ONE = torch.zeros(3), torch.ones(3)


def test_fourier_frequencies_span_one_cycle_to_the_maximum():
    freqs = fourier_frequencies(8, 32.0)
    assert freqs[0].item() == pytest.approx(1.0) and freqs[-1].item() == pytest.approx(32.0)
    ratios = freqs[1:] / freqs[:-1]
    torch.testing.assert_close(ratios, torch.full_like(ratios, ratios[0].item()))  # log-spaced


def test_fourier_features_layout():
    uv = torch.tensor([[0.25, 0.5]])
    freqs = torch.tensor([1.0, 2.0])
    feats = fourier_features(uv, freqs)
    assert feats.shape == (1, 2 + 2 * 2 * 2)
    angles = 2 * math.pi * torch.tensor([0.25, 0.5, 0.5, 1.0])  # (u f1, u f2, v f1, v f2)
    torch.testing.assert_close(feats[0], torch.cat([uv[0], angles.sin(), angles.cos()]))


def test_sincos_2d_distinguishes_every_grid_cell():
    table = sincos_2d(8, 64).reshape(64, 64)
    distances = torch.cdist(table, table) + torch.eye(64)
    assert distances.min() > 0.1


def test_cross_attention_equals_explicit_softmax_attention():
    torch.manual_seed(0)
    attn = CrossAttention(dim=16, context_dim=24, heads=2)
    with torch.no_grad():
        attn.v_bias.normal_()
    x, ctx = torch.randn(3, 5, 16), torch.randn(3, 7, 24)
    keys, values = attn.project_context(ctx)
    out = attn(x, keys, values)
    wk, wv = attn.kv.weight.chunk(2)
    q = attn.q(x).view(3, 5, 2, 8).transpose(1, 2)
    k = (ctx @ wk.T).view(3, 7, 2, 8).transpose(1, 2)
    v = (ctx @ wv.T + attn.v_bias).view(3, 7, 2, 8).transpose(1, 2)
    weights = (q @ k.transpose(-1, -2) / math.sqrt(8)).softmax(-1)
    expected = attn.proj((weights @ v).transpose(1, 2).reshape(3, 5, 16))
    torch.testing.assert_close(out, expected, atol=1e-5, rtol=1e-5)


# ---------------------------------------------------------------------------------- RGB patches
def ramp_video(h=6, w=10):
    """Pixel (row y, column x) holds (x, y, 0): a linear function bilinear sampling reproduces exactly."""
    ys, xs = torch.meshgrid(torch.arange(h).float(), torch.arange(w).float(), indexing="ij")
    return torch.stack([xs, ys, torch.zeros_like(xs)], dim=-1)[None, None]  # (1, 1, H, W, 3)


def test_pixel_centre_convention():
    video = ramp_video()
    # u = (i + 0.5) / W is the centre of pixel column i; v likewise for rows.
    uv = torch.tensor([[[(3 + 0.5) / 10, (2 + 0.5) / 6]]])
    patch = sample_rgb_patches(video, uv, torch.zeros(1, 1, dtype=torch.long), 1, ZERO, ONE)
    torch.testing.assert_close(patch[0, 0, 0, 0], torch.tensor([3.0, 2.0, 0.0]))


def test_patches_are_bilinear_and_sub_pixel():
    video = ramp_video()
    u, v = 0.537, 0.48  # an arbitrary sub-pixel position well inside the image
    patch = sample_rgb_patches(video, torch.tensor([[[u, v]]]), torch.zeros(1, 1, dtype=torch.long), 3, ZERO, ONE)[0, 0]
    x, y = u * 10 - 0.5, v * 6 - 0.5  # OpenCV continuous pixel coordinates
    offsets = torch.tensor([-1.0, 0.0, 1.0])
    torch.testing.assert_close(patch[..., 0], (x + offsets)[None, :].expand(3, 3), atol=1e-5, rtol=0)
    torch.testing.assert_close(patch[..., 1], (y + offsets)[:, None].expand(3, 3), atol=1e-5, rtol=0)


def test_patch_samples_outside_the_image_read_as_zero():
    video = torch.ones(1, 1, 4, 4, 3)
    patch = sample_rgb_patches(video, torch.tensor([[[0.0, 0.0]]]), torch.zeros(1, 1, dtype=torch.long), 3, ZERO, ONE)[0, 0]
    # Centred on the image corner: the top-left sample is wholly outside, the bottom-right one inside.
    assert patch[0, 0].abs().max() == 0
    torch.testing.assert_close(patch[2, 2], torch.ones(3))
    # The centre (x = y = -0.5) is half a pixel outside in both directions: a quarter of a pixel's weight.
    torch.testing.assert_close(patch[1, 1], torch.full((3,), 0.25))


def test_patches_come_from_the_query_frame_and_batch_element():
    video = torch.arange(2 * 3).float().reshape(2, 3, 1, 1, 1).expand(2, 3, 4, 4, 3) / 10
    frames = torch.tensor([[2, 0], [1, 2]])
    uv = torch.full((2, 2, 2), 0.5)
    patch = sample_rgb_patches(video, uv, frames, 1, ZERO, ONE)[..., 0, 0, 0]
    torch.testing.assert_close(patch, torch.tensor([[0.2, 0.0], [0.4, 0.5]]))


def test_uint8_and_float_sources_agree_and_normalisation_applies():
    video = torch.randint(0, 256, (1, 2, 9, 7, 3), dtype=torch.uint8)
    uv, frame = torch.rand(1, 5, 2), torch.randint(0, 2, (1, 5))
    mean, std = torch.tensor([0.4, 0.5, 0.6]), torch.tensor([0.2, 0.3, 0.4])
    a = sample_rgb_patches(video, uv, frame, 9, mean, std)
    b = sample_rgb_patches(video.float() / 255, uv, frame, 9, mean, std)
    torch.testing.assert_close(a, b)
    raw = sample_rgb_patches(video.float() / 255, torch.full((1, 1, 2), 0.5), torch.zeros(1, 1, dtype=torch.long),
                             1, ZERO, ONE)
    norm = sample_rgb_patches(video.float() / 255, torch.full((1, 1, 2), 0.5), torch.zeros(1, 1, dtype=torch.long),
                              1, mean, std)
    torch.testing.assert_close(norm, (raw - mean) / std)


# ---------------------------------------------------------------------------------- encoder
def test_frame_local_blocks_keep_time_steps_apart(make_model):
    # With only frame-local blocks, editing time step 0 leaves time step 1's tokens untouched.
    model = make_model()
    model.encoder.is_global = lambda index: False
    video = torch.rand(1, 4, 64, 64, 3)
    edited = video.clone()
    edited[:, :2] = torch.rand(1, 2, 64, 64, 3)
    grid = model.config.grid_size ** 2
    with torch.no_grad():
        a, b = (model.encode_tokens(v, torch.ones(1)) for v in (video, edited))
    torch.testing.assert_close(a[:, grid:2 * grid], b[:, grid:2 * grid], atol=0, rtol=0)
    assert not torch.allclose(a[:, :grid], b[:, :grid])
    # ... while the alternating model lets the edit reach the other time step through global blocks.
    model = make_model()
    assert [model.encoder.is_global(i) for i in range(6)] == [False, True] * 3
    with torch.no_grad():
        a, b = (model.encode_tokens(v, torch.ones(1)) for v in (video, edited))
    assert not torch.allclose(a[:, grid:2 * grid], b[:, grid:2 * grid])


def test_lower_resolution_uses_a_resized_spatial_table(make_model):
    model = make_model()
    table = model.encoder.pos_embed(steps=2, rows=4, cols=6)
    assert table.shape == (2, 4, 6, model.config.encoder_dim)
    full = model.encoder.pos_embed(steps=1, rows=8, cols=8)
    torch.testing.assert_close(full[0], model.encoder.pos_embed.space + model.encoder.pos_embed.time[0])


def test_sdpa_is_the_attention_kernel(make_model, monkeypatch):
    calls = []
    original = F.scaled_dot_product_attention

    def spy(*args, **kwargs):
        calls.append(args[0].shape)
        return original(*args, **kwargs)

    monkeypatch.setattr(F, "scaled_dot_product_attention", spy)
    model = make_model()
    with torch.no_grad():
        model(torch.rand(1, 2, 64, 64, 3), torch.zeros(1, 3, 5), torch.ones(1))
    # Frame-local encoder blocks run twice (video tokens, aspect token); global once; decoder once each.
    assert len(calls) == 3 * 2 + 3 + model.config.decoder_depth
