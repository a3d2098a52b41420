"""Config ``target_frame_heads``: the first heads of every decoder cross-attention see only the scene tokens of the
query's t_tgt time step (stage 81). Checked: a restricted head is exactly attention over that step's tokens and
blind to every other token, inference and the training forward agree, the attention the loss reads is masked the
same way, and the config and ``init_from`` accept and refuse what they should."""

from __future__ import annotations

import json

import pytest
import torch
import torch.nn.functional as F

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.inputs import encoder_frames
from d4rt.model.layers import CrossAttention, FrameRestriction, split_heads

R = 4  # tokens per time step in the layer tests: 3 steps, then one extra (aspect-ratio) token


def layer_inputs(seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    attention = CrossAttention(16, 8, heads=2)
    x, context = torch.randn(1, 6, 16, generator=g), torch.randn(1, 3 * R + 1, 8, generator=g)
    steps = torch.tensor([[0, 2, 1, 2, 0, 1]])
    return attention, x, context, steps


def test_a_restricted_head_is_attention_over_its_steps_tokens_only():
    attention, x, context, steps = layer_inputs()
    frame = FrameRestriction(steps, R, heads=1)
    keys, values = attention.project_context(context)
    q = split_heads(attention.q(x), 2)
    within = frame.attend(q[:, :1], keys[:, :1], values[:, :1])
    for n, step in enumerate(steps[0].tolist()):
        part = slice(step * R, (step + 1) * R)
        expected = F.scaled_dot_product_attention(q[:, :1, n:n + 1], keys[:, :1, part], values[:, :1, part])
        torch.testing.assert_close(within[:, :, n:n + 1], expected)
    # Changing every token outside step 1 leaves the restricted head of the step-1 queries unchanged.
    changed = context.clone()
    changed[:, :R] += 5.0
    changed[:, 2 * R:] -= 3.0
    step_one = steps[0] == 1
    with torch.no_grad():
        def first_head(ctx):
            k, v = attention.project_context(ctx)
            return frame.attend(q[:, :1], k[:, :1], v[:, :1])

        torch.testing.assert_close(first_head(context)[:, :, step_one], first_head(changed)[:, :, step_one])
        # ... while the unrestricted attention of the same queries does see the change.
        plain_before = attention(x, *attention.project_context(context))
        plain_after = attention(x, *attention.project_context(changed))
    assert not torch.allclose(plain_before[:, step_one], plain_after[:, step_one])


def test_every_head_restricted_and_the_log_probs_masked_alike():
    attention, x, context, steps = layer_inputs(1)
    frame = FrameRestriction(steps, R, heads=2)
    keys, values = attention.project_context(context)
    with torch.no_grad():
        out = attention(x, keys, values, frame)
        q = split_heads(attention.q(x), 2)
        torch.testing.assert_close(out, attention.proj(frame.attend(q, keys, values).transpose(1, 2).reshape(1, 6, 16)))
        log_probs = attention.attention_log_probs(x, keys, head=1, frame=frame)
    inside = frame.mask(3 * R + 1)
    assert inside.shape == (1, 6, 3 * R + 1) and not inside[..., -1].any()  # never the aspect-ratio token
    assert torch.isinf(log_probs[~inside]).all() and torch.isfinite(log_probs[inside]).all()
    torch.testing.assert_close(log_probs.exp().sum(-1), torch.ones(1, 6))
    # The weights are the ones the head uses: they reproduce its output from the values.
    torch.testing.assert_close(log_probs.exp() @ values[:, 1], frame.attend(q, keys, values)[:, 1])


def test_inference_and_the_training_forward_agree():
    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny", max_frames=6, target_frame_heads=1)).eval()
    video = torch.rand(6, 24, 40, 3)
    queries = torch.cat([torch.rand(50, 2), torch.randint(0, 6, (50, 3)).float()], 1)
    answers = model.encode(video).query(queries, chunk_size=16)
    with torch.no_grad():
        trained = model(encoder_frames(video, 64, "cpu")[None], queries[None], torch.tensor([40 / 24]))
    for key in ("points", "uv", "visibility", "confidence"):
        torch.testing.assert_close(answers[key], trained[key][0], rtol=1e-5, atol=1e-5)
    plain = D4RT(model.config.replace(target_frame_heads=0)).eval()
    plain.load_state_dict(model.state_dict())
    assert not torch.allclose(plain.encode(video).query(queries)["points"], answers["points"])


def test_config_checks_and_old_configs(tmp_path):
    with pytest.raises(UserError, match="target_frame_heads must be an integer in 0-3"):
        D4RTConfig.preset("tiny", target_frame_heads=4)
    with pytest.raises(UserError, match="target_frame_heads"):
        D4RTConfig.preset("tiny", target_frame_heads=-1)
    model = D4RT(D4RTConfig.preset("tiny", max_frames=4))
    model.save_pretrained(tmp_path / "old")
    config = json.loads((tmp_path / "old" / "config.json").read_text())
    config.pop("target_frame_heads", None)  # written before the option existed
    (tmp_path / "old" / "config.json").write_text(json.dumps(config))
    assert D4RT.from_pretrained(tmp_path / "old").config.target_frame_heads == 0


def test_init_from_restricts_heads_of_a_checkpoint_but_never_frees_them(tmp_path, build_from_checkpoint, make_model):
    base = make_model()
    base.save_pretrained(tmp_path / "plain")
    model = build_from_checkpoint(tmp_path / "plain", target_frame_heads=1)
    assert model.config.target_frame_heads == 1
    assert all(torch.equal(model.state_dict()[k], v) for k, v in base.state_dict().items())  # no weight changes
    make_model(target_frame_heads=2).save_pretrained(tmp_path / "restricted")
    with pytest.raises(UserError, match="different model config"):
        build_from_checkpoint(tmp_path / "restricted", target_frame_heads=1)
