"""Function-preserving deepening (``d4rt.model.grow.deepen``): a grown model answers exactly as the model it grew
from, keeps every old block's kind of attention, and its new blocks learn from the first step."""

from __future__ import annotations

import pytest
import torch

from d4rt.errors import UserError
from d4rt.model.grow import deepen, spread


def _outputs(model, video, queries):
    with torch.no_grad():
        return model(video, queries, torch.full((1,), 1.5))


def test_a_deepened_model_answers_every_output_as_before(make_model, random_video, random_queries):
    # A relative-pose head and non-square aspect: every part of the forward pass is exercised.
    base = make_model(relative_pose_head=True)
    with torch.no_grad():  # trained-looking weights: fresh ones have near-zero outputs that hide a misplaced block
        for parameter in base.parameters():
            parameter.add_(0.05 * torch.randn_like(parameter))
    grown = deepen(base, encoder_depth=10, decoder_depth=6, seed=3).eval()
    assert (grown.config.encoder_depth, grown.config.decoder_depth) == (10, 6)
    video, queries = random_video(6, 64, 64, dtype=torch.float32)[None], random_queries(50, 6)[None]
    before, after = _outputs(base, video, queries), _outputs(grown, video, queries)
    for key, value in before.items():
        assert torch.allclose(after[key], value, atol=1e-5, rtol=1e-5), key
    # ... and the check is not vacuous: a grown model whose old blocks are reordered answers differently.
    shuffled = grown.state_dict()
    for name in ("attn.proj.weight", "mlp.fc2.weight"):
        shuffled[f"encoder.blocks.0.{name}"], shuffled[f"encoder.blocks.4.{name}"] = (
            shuffled[f"encoder.blocks.4.{name}"].clone(), shuffled[f"encoder.blocks.0.{name}"].clone())
    grown.load_state_dict(shuffled)
    assert not torch.allclose(_outputs(grown, video, queries)["points"], before["points"], atol=1e-3)


def test_old_blocks_keep_their_kind_of_attention(make_model):
    base = make_model()
    grown = deepen(base, encoder_depth=10)
    # Old groups (local, global) sit at groups 0, 2, 4 of the new encoder; every global block stays global.
    for old_index, new_index in ((0, 0), (1, 1), (2, 4), (3, 5), (4, 8), (5, 9)):
        assert base.encoder.is_global(old_index) == grown.encoder.is_global(new_index)
        assert torch.equal(base.encoder.blocks[old_index].mlp.fc1.weight, grown.encoder.blocks[new_index].mlp.fc1.weight)
    for new_index in (2, 3, 6, 7):
        assert not grown.encoder.blocks[new_index].attn.proj.weight.any()
        assert grown.encoder.blocks[new_index].attn.qkv.weight.std() > 0.01  # fresh, not zero: it can learn


def test_new_blocks_receive_gradients_from_the_first_step(make_model, random_video, random_queries):
    grown = deepen(make_model(), encoder_depth=8, decoder_depth=5).train()
    out = grown(random_video(4, 64, 64, dtype=torch.float32)[None], random_queries(20, 4)[None], torch.ones(1))
    out["points"].square().mean().backward()
    # 3 groups -> 4: old groups at 0, 2, 3, so blocks 2 (local) and 3 (global) are new; decoder block 1 or 2 is new.
    assert grown.encoder.blocks[2].mlp.fc2.weight.grad.abs().sum() > 0
    assert grown.encoder.blocks[3].attn.proj.weight.grad.abs().sum() > 0
    new_decoder = set(range(5)) - set(spread(4, 5))
    assert all(grown.decoder.blocks[i].mlp.fc2.weight.grad.abs().sum() > 0 for i in new_decoder)


def test_spread_keeps_the_ends_and_the_order():
    assert spread(3, 5) == [0, 2, 4]
    assert spread(4, 6) == [0, 2, 3, 5]
    assert spread(1, 4) == [0]
    assert spread(4, 4) == [0, 1, 2, 3]


def test_deepen_refuses_to_shrink_or_to_break_the_attention_pattern(make_model):
    base = make_model()
    with pytest.raises(UserError, match="grows a model"):
        deepen(base, encoder_depth=4)
    with pytest.raises(UserError, match="whole groups"):
        deepen(base, encoder_depth=9)


def test_a_deepened_checkpoint_is_what_init_from_loads_with_the_new_depths(tmp_path, make_model, build_from_checkpoint):
    grown = deepen(make_model(), encoder_depth=8, decoder_depth=6)
    grown.save_pretrained(tmp_path / "grown")
    model = build_from_checkpoint(tmp_path / "grown", encoder_depth=8, decoder_depth=6)
    for key, value in grown.state_dict().items():
        assert torch.equal(model.state_dict()[key], value), key
    with pytest.raises(UserError, match="different model config"):
        build_from_checkpoint(tmp_path / "grown")  # the tiny preset's depths: refused, never loaded loosely


def test_a_larger_input_keeps_every_weight_meaning_what_it_did(tmp_path, make_model, random_video, random_queries,
                                                                 build_from_checkpoint):
    """with_input_size: the position table is the run-time resize for the new grid, the query's Fourier frequencies
    stay, every other weight is copied; the model then runs on the larger input and trains on from init_from."""
    from d4rt.model.grow import with_input_size

    base = make_model()
    larger = with_input_size(base, 96).eval()
    assert (larger.config.image_size, larger.config.grid_size) == (96, 12)
    pos = larger.encoder.pos_embed
    assert pos.space.shape[:2] == (12, 12) and torch.equal(pos.space, base.encoder.pos_embed.space_table(12, 12))
    assert torch.equal(larger.query_embedding.frequencies, base.query_embedding.frequencies)
    assert larger.config.fourier_max_frequency == base.config.fourier_max == 32.0
    changed = [k for k, v in base.state_dict().items() if not torch.equal(v, larger.state_dict()[k])]
    assert changed == ["encoder.pos_embed.space"]
    out = _outputs(larger, random_video(4, 96, 96, dtype=torch.float32)[None], random_queries(20, 4)[None])
    assert out["points"].shape == (1, 20, 3) and torch.isfinite(out["points"]).all()
    with pytest.raises(UserError, match="multiple of patch_size"):
        with_input_size(base, 100)
    larger.save_pretrained(tmp_path / "larger")
    model = build_from_checkpoint(tmp_path / "larger", image_size=96, fourier_max_frequency=32.0)
    assert torch.equal(model.encoder.pos_embed.space, pos.space)


def test_shorter_tubelets_give_a_still_clip_the_old_tokens_once_per_frame(make_model, random_video, random_queries,
                                                                        tmp_path, build_from_checkpoint):
    """with_tubelet_frames: on a clip that does not move, every token before the first attention block is the old
    tubelet's token, once per frame; the answers differ only by the aspect-ratio token's halved share of attention
    (a few per cent of an answer at most); the copy trains on from init_from with the new span."""
    from d4rt.model.grow import with_tubelet_frames

    base = make_model()
    shorter = with_tubelet_frames(base, 1).eval()
    assert shorter.config.tubelet_frames == 1 and shorter.config.max_time_steps == 2 * base.config.max_time_steps
    still = random_video(1, 64, 64, dtype=torch.float32).repeat(8, 1, 1, 1)[None]
    mean, std = still.new_tensor(base.config.pixel_mean), still.new_tensor(base.config.pixel_std)
    norm = (still - mean) / std
    with torch.no_grad():
        old = base.encoder.patch_embed(norm) + base.encoder.pos_embed(4, 8, 8)
        new = shorter.encoder.patch_embed(norm) + shorter.encoder.pos_embed(8, 8, 8)
    torch.testing.assert_close(new, old.repeat_interleave(2, dim=1), rtol=1e-5, atol=1e-5)
    queries = random_queries(30, 8)[None]
    a, b = _outputs(base, still, queries), _outputs(shorter, still, queries)
    assert (a["points"] - b["points"]).abs().max() < 0.05 * a["points"].abs().mean()
    with pytest.raises(UserError, match="divisor of 2"):
        with_tubelet_frames(base, 2)
    with pytest.raises(UserError, match="do not overlap"):
        with_tubelet_frames(make_model(tubelet_stride=1), 1)
    shorter.save_pretrained(tmp_path / "t1")
    model = build_from_checkpoint(tmp_path / "t1", tubelet_frames=1)
    assert torch.equal(model.encoder.patch_embed.proj.weight, shorter.encoder.patch_embed.proj.weight)


def test_overlapping_tubelets_keep_the_old_tokens_and_add_those_between(make_model, random_video, random_queries,
                                                                         tmp_path, build_from_checkpoint):
    """with_tubelet_stride: the kernel is kept, so the tubelets that start where the old ones did give the old tokens
    exactly (before any attention) on any clip; each time step takes the old row of its first frame; the model answers
    queries at every frame and trains on from init_from."""
    from d4rt.model.grow import with_tubelet_stride

    base = make_model()
    overlapping = with_tubelet_stride(base, 1).eval()
    assert overlapping.config.step_frames == 1 and overlapping.config.max_time_steps == 24
    assert torch.equal(overlapping.encoder.patch_embed.proj.weight, base.encoder.patch_embed.proj.weight)
    video = random_video(6, 64, 64, dtype=torch.float32)[None]
    norm = (video - video.new_tensor(base.config.pixel_mean)) / video.new_tensor(base.config.pixel_std)
    with torch.no_grad():
        old = base.encoder.patch_embed(norm) + base.encoder.pos_embed(3, 8, 8)
        new = overlapping.encoder.patch_embed(norm) + overlapping.encoder.pos_embed(6, 8, 8)
    assert torch.equal(new[:, ::2], old)
    assert not torch.allclose(new[:, 1::2], old, atol=1e-3)  # the tubelets between: frames 1-2 and 3-4, new tokens
    out = _outputs(overlapping, video, random_queries(20, 6)[None])
    assert out["points"].shape == (1, 20, 3) and torch.isfinite(out["points"]).all()
    with pytest.raises(UserError, match="more often than every 2 frames"):
        with_tubelet_stride(base, 2)
    overlapping.save_pretrained(tmp_path / "s1")
    model = build_from_checkpoint(tmp_path / "s1", tubelet_stride=1)
    assert torch.equal(model.encoder.pos_embed.time, overlapping.encoder.pos_embed.time)
