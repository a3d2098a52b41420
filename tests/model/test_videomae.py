"""VideoMAE v2 -> encoder conversion, on state dicts built with the public checkpoint's names and shapes.

The reference computations below re-implement VideoMAE v2's published block (models/modeling_finetune.py:
pre-norm attention with q/v biases, GELU MLP, optional layer scale gamma) directly from the raw tensors,
independently of d4rt's modules.
"""

import pytest
import torch
import torch.nn.functional as F

from d4rt.errors import UserError
from d4rt.model.videomae import convert_videomae_v2, load_videomae_v2, resize_patch_kernel


def videomae_state_dict(width=192, depth=6, mlp=768, patch=16, frames=2, layer_scale=False, prefix="",
                        pretrain_extras=False, classifier=False):
    """Random tensors under VideoMAE v2's key names and shapes."""
    g = torch.Generator().manual_seed(7)

    def rnd(*shape):
        return torch.randn(*shape, generator=g) * 0.05

    sd = {
        "patch_embed.proj.weight": rnd(width, 3, frames, patch, patch),
        "patch_embed.proj.bias": rnd(width),
    }
    for i in range(depth):
        b = f"blocks.{i}."
        sd.update({
            b + "norm1.weight": 1 + rnd(width), b + "norm1.bias": rnd(width),
            b + "attn.qkv.weight": rnd(3 * width, width),
            b + "attn.q_bias": rnd(width), b + "attn.v_bias": rnd(width),
            b + "attn.proj.weight": rnd(width, width), b + "attn.proj.bias": rnd(width),
            b + "norm2.weight": 1 + rnd(width), b + "norm2.bias": rnd(width),
            b + "mlp.fc1.weight": rnd(mlp, width), b + "mlp.fc1.bias": rnd(mlp),
            b + "mlp.fc2.weight": rnd(width, mlp), b + "mlp.fc2.bias": rnd(width),
        })
        if layer_scale:
            sd[b + "gamma_1"] = 0.1 + rnd(width)
            sd[b + "gamma_2"] = 0.1 + rnd(width)
    if classifier:
        sd.update({"fc_norm.weight": 1 + rnd(width), "fc_norm.bias": rnd(width),
                   "head.weight": rnd(400, width), "head.bias": rnd(400)})
    else:
        sd.update({"norm.weight": 1 + rnd(width), "norm.bias": rnd(width)})
    sd = {prefix + k: v for k, v in sd.items()}
    if pretrain_extras:
        sd.update({"decoder.blocks.0.norm1.weight": rnd(96), "decoder.norm.weight": rnd(96),
                   "decoder.head.weight": rnd(3 * frames * patch * patch, 96),
                   "encoder_to_decoder.weight": rnd(96, width), "mask_token": rnd(1, 1, 96)})
    return sd


def reference_block(x, sd, i, heads, eps=1e-6):
    """VideoMAE v2's Block.forward written out from the raw tensors."""
    def p(name):
        return sd.get(f"blocks.{i}.{name}")
    b, n, c = x.shape
    h = F.layer_norm(x, (c,), p("norm1.weight"), p("norm1.bias"), eps)
    bias = torch.cat([p("attn.q_bias"), torch.zeros(c), p("attn.v_bias")])
    qkv = F.linear(h, p("attn.qkv.weight"), bias).reshape(b, n, 3, heads, c // heads).permute(2, 0, 3, 1, 4)
    q, k, v = qkv[0] * (c // heads) ** -0.5, qkv[1], qkv[2]
    attn = (q @ k.transpose(-2, -1)).softmax(-1)
    out = F.linear((attn @ v).transpose(1, 2).reshape(b, n, c), p("attn.proj.weight"), p("attn.proj.bias"))
    x = x + (p("gamma_1") if p("gamma_1") is not None else 1) * out
    h = F.layer_norm(x, (c,), p("norm2.weight"), p("norm2.bias"), eps)
    mlp = F.linear(F.gelu(F.linear(h, p("mlp.fc1.weight"), p("mlp.fc1.bias"))), p("mlp.fc2.weight"), p("mlp.fc2.bias"))
    return x + (p("gamma_2") if p("gamma_2") is not None else 1) * mlp


@pytest.mark.parametrize("layer_scale", [False, True])
def test_converted_blocks_compute_what_videomae_computes(make_model, layer_scale):
    model = make_model(image_size=64, patch_size=16)
    sd = videomae_state_dict(layer_scale=layer_scale)
    load_videomae_v2(model, sd)
    x = torch.randn(2, 10, 192)
    with torch.no_grad():
        for i, block in enumerate(model.encoder.blocks):
            torch.testing.assert_close(block(x), reference_block(x, sd, i, heads=3), atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(model.encoder.norm.weight, sd["norm.weight"])


def test_tubelet_embedding_equals_videomae_conv3d(make_model):
    model = make_model(image_size=64, patch_size=16)
    sd = videomae_state_dict()
    load_videomae_v2(model, sd)
    video = torch.randn(1, 4, 64, 64, 3)
    with torch.no_grad():
        ours = model.encoder.patch_embed(video).flatten(1, 3)
    conv = F.conv3d(video.permute(0, 4, 1, 2, 3), sd["patch_embed.proj.weight"], sd["patch_embed.proj.bias"], stride=(2, 16, 16))
    torch.testing.assert_close(ours, conv.flatten(2).transpose(1, 2), atol=1e-5, rtol=1e-5)


def test_overlapping_tubelets_are_the_conv3d_at_that_stride(make_model):
    """tubelet_stride 1: a two-frame tubelet every frame, the clip's last frame repeated past its end."""
    model = make_model(tubelet_stride=1)
    video = torch.randn(1, 5, 64, 64, 3)
    embed = model.encoder.patch_embed
    weight = embed.proj.weight.reshape(-1, 3, 2, 8, 8)
    padded = torch.cat([video, video[:, -1:]], dim=1).permute(0, 4, 1, 2, 3)
    conv = F.conv3d(padded, weight, embed.proj.bias, stride=(1, 8, 8))  # (1, dim, 5, 8, 8)
    with torch.no_grad():
        ours = embed(video)
    assert ours.shape == (1, 5, 8, 8, model.config.encoder_dim)
    torch.testing.assert_close(ours, conv.permute(0, 2, 3, 4, 1), atol=1e-5, rtol=1e-5)
    assert model.config.num_scene_tokens(5) == 5 * 64 + 1


def test_pretraining_checkpoint_layout_with_wrapper_and_prefix(make_model):
    model = make_model()  # patch 8: the 16x16 kernels are resized
    checkpoint = {"model": videomae_state_dict(prefix="encoder.", pretrain_extras=True), "epoch": 1200}
    before = {k: v.clone() for k, v in model.encoder.state_dict().items()}
    report = load_videomae_v2(model, checkpoint)
    assert report.kept_initialised == ["aspect_embed.bias", "aspect_embed.weight", "pos_embed.space", "pos_embed.time"]
    assert "decoder.head.weight" in report.dropped_source_keys and "mask_token" in report.dropped_source_keys
    assert any("resized from 16x16 to 8x8" in note for note in report.notes)
    after = model.encoder.state_dict()
    for key in report.kept_initialised:
        assert torch.equal(before[key], after[key])
    for key in report.loaded:
        assert not torch.equal(before[key], after[key]), key
    assert model.encoder.patch_embed.proj.weight.shape == (192, 3 * 2 * 8 * 8)


def test_finetuned_classifier_layout_and_torch_file(make_model, tmp_path):
    model = make_model()
    path = tmp_path / "vit_k710_ft.pth"
    torch.save({"module": videomae_state_dict(classifier=True)}, path)
    report = load_videomae_v2(model, path)
    assert "norm.weight" in report.kept_initialised  # fine-tuned models keep only fc_norm (after pooling)
    assert {"fc_norm.weight", "head.weight"} <= set(report.dropped_source_keys)


def test_pseudo_inverse_resize_preserves_patch_responses_when_upsampling():
    # ViT-g's 14x14 kernels to the paper's 16x16: <resize(x), w'> must equal <x, w> for any patch x.
    w = torch.randn(5, 3, 2, 14, 14, dtype=torch.float64)
    w16 = resize_patch_kernel(w, 16)
    assert w16.shape == (5, 3, 2, 16, 16)
    x = torch.randn(3 * 2, 1, 14, 14, dtype=torch.float64)
    x16 = F.interpolate(x, size=(16, 16), mode="bilinear", align_corners=False).reshape(3, 2, 16, 16)
    torch.testing.assert_close((w16 * x16).sum((1, 2, 3, 4)), (w * x.reshape(3, 2, 14, 14)).sum((1, 2, 3, 4)))


def test_layer_scale_is_folded_not_dropped(make_model):
    model = make_model(image_size=64, patch_size=16)
    sd = videomae_state_dict(layer_scale=True)
    converted, _ = convert_videomae_v2(sd, model.config)
    torch.testing.assert_close(converted["blocks.0.mlp.fc2.bias"], sd["blocks.0.mlp.fc2.bias"] * sd["blocks.0.gamma_2"])


@pytest.mark.parametrize("source, overrides, message", [
    ({"depth": 4}, {}, "encoder depth is 4 but the config has 6"),
    ({"width": 96, "mlp": 384}, {}, "encoder width is 96 but the config has 192"),
    ({"frames": 1}, {}, "tubelet frames is 1 but the config has 2"),
    ({"width": 384, "mlp": 1536}, {"encoder_dim": 384, "encoder_heads": 4, "encoder_mlp_dim": 1536},
     "attention heads .* is 6 but the config has 4"),
    ({"mlp": 512}, {}, r"mlp\.fc1\.weight \(512, 192\) vs encoder \(768, 192\)"),
])
def test_mismatched_checkpoints_raise(make_model, source, overrides, message):
    model = make_model(**overrides)
    with pytest.raises(UserError, match=message):
        load_videomae_v2(model, videomae_state_dict(**source))


def test_unknown_keys_raise(make_model):
    sd = videomae_state_dict()
    sd["blocks.0.attn.relative_position_bias_table"] = torch.zeros(3)
    with pytest.raises(UserError, match="relative_position_bias_table"):
        load_videomae_v2(make_model(), sd)
    with pytest.raises(UserError, match="not a VideoMAE v2 checkpoint"):
        load_videomae_v2(make_model(), {"weight": torch.zeros(1)})
