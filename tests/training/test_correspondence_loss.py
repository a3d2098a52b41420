"""The correspondence-attention term (stage 79): a decoder head told where a query's point lies at t_tgt.

Checked: the target tokens and weights by hand, the model's ``attention_log_probs`` being exactly the weights its
attention uses (and asking for them changing no answer), the term's value at its bounds, its masks, and a training
run that lowers it."""

from __future__ import annotations

import json
import math

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.layers import merge_heads
from d4rt.training import LossConfig, TrainConfig, d4rt_loss, train
from d4rt.training.losses import correspondence_loss, correspondence_targets
from training_helpers import fast_config

GRID = torch.tensor([3, 4, 4, 2])  # 3 time steps of 2 frames, 4 x 4 tokens


def test_targets_by_hand():
    # Frame 3 is time step 1; (u, v) at the centre of token (row 2, column 1) -> all weight on it.
    queries = torch.tensor([[[0.1, 0.1, 0.0, 3.0, 3.0], [0.5, 0.5, 5.0, 0.0, 0.0], [0.0, 1.0, 1.0, 5.0, 5.0]]])
    uv = torch.tensor([[[1.5 / 4, 2.5 / 4], [0.5, 0.5], [0.0, 1.0]]])
    index, weight = correspondence_targets(queries, uv, GRID)
    assert index.shape == weight.shape == (1, 3, 4)
    torch.testing.assert_close(weight.sum(-1), torch.ones(1, 3))
    first = dict(zip(index[0, 0].tolist(), weight[0, 0].tolist()))
    assert first[16 + 2 * 4 + 1] == pytest.approx(1.0)
    # The image centre lies between tokens (1, 1), (1, 2), (2, 1), (2, 2) of step 0, a quarter each.
    middle = {}
    for i, w in zip(index[0, 1].tolist(), weight[0, 1].tolist()):
        middle[i] = middle.get(i, 0.0) + w
    assert middle == pytest.approx({5: 0.25, 6: 0.25, 9: 0.25, 10: 0.25})
    # A corner (u 0, v 1) of frame 5 (step 2) puts everything on the corner token (row 3, column 0).
    corner = {}
    for i, w in zip(index[0, 2].tolist(), weight[0, 2].tolist()):
        corner[i] = corner.get(i, 0.0) + w
    assert corner == pytest.approx({32 + 3 * 4 + 0: 1.0})


def batch_for(queries: torch.Tensor, uv: torch.Tensor, visible: torch.Tensor) -> dict:
    n = queries.shape[1]
    return {"queries": queries, "uv": uv, "visibility": visible.float(), "valid": torch.ones(1, n, dtype=torch.bool),
            "uv_valid": torch.ones(1, n, dtype=torch.bool)}


def test_loss_is_zero_on_the_target_log_m_when_uniform_and_masks_hidden_points():
    queries = torch.tensor([[[0.2, 0.2, 0.0, 3.0, 3.0], [0.7, 0.7, 0.0, 1.0, 1.0]]])
    uv = torch.tensor([[[1.5 / 4, 2.5 / 4], [1.2, 0.5]]])  # the second is out of frame: not supervised
    batch = batch_for(queries, uv, torch.tensor([[True, True]]))
    m = 3 * 16 + 1  # the aspect-ratio token too
    uniform = torch.full((1, 2, m), -math.log(m))
    assert float(correspondence_loss(uniform, GRID, batch)) == pytest.approx(math.log(m))
    sure = torch.full((1, 2, m), -1e4)
    sure[0, :, 16 + 2 * 4 + 1] = 0.0  # certain of the first query's true token; the second's is masked
    assert float(correspondence_loss(sure, GRID, batch)) == pytest.approx(0.0)
    hidden = batch_for(queries, uv, torch.tensor([[False, True]]))
    empty = correspondence_loss(uniform.requires_grad_(), GRID, hidden)
    assert float(empty.detach()) == 0.0 and empty.requires_grad  # nothing visible in frame: 0, still in the graph


def test_attention_log_probs_are_the_weights_the_attention_uses():
    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny", max_frames=4)).eval()
    video = torch.rand(1, 4, 32, 32, 3)
    queries = torch.cat([torch.rand(1, 5, 2), torch.randint(0, 4, (1, 5, 3)).float()], -1)
    aspect = torch.ones(1)
    with torch.no_grad():
        plain = model(video, queries, aspect)
        asked = model(video, queries, aspect, attention_block=1)
        for key, value in plain.items():
            assert torch.equal(value, asked[key]), key  # asking changes no answer
        assert asked["token_grid"].tolist() == [2, 4, 4, 2]
        log_probs = asked["attention_log_probs"]
        assert log_probs.shape == (1, 5, 2 * 16 + 1)
        torch.testing.assert_close(log_probs.exp().sum(-1), torch.ones(1, 5))
        # Block 1's first head, rebuilt from its input: its weights times its values are what it passes on.
        tokens = model.encode_tokens(video, aspect)
        kv = model.decoder.project_scene(tokens)
        x = model.query_embedding(queries, video)
        x = model.decoder.blocks[0](x, *kv[0])
        block = model.decoder.blocks[1]
        inside = block.attn.q(block.norm1(x))
        keys, values = kv[1]
        heads = torch.nn.functional.scaled_dot_product_attention(
            inside.reshape(1, 5, block.attn.heads, -1).transpose(1, 2), keys, values)
        torch.testing.assert_close(merge_heads(heads)[..., :values.shape[-1]],
                                   log_probs.exp() @ values[:, 0], rtol=1e-4, atol=1e-5)
        with pytest.raises(UserError, match="attention_block must be 0-3"):
            model(video, queries, aspect, attention_block=4)


def test_the_loss_asks_for_the_attention_and_the_config_checks_the_block(clip_dir):
    with pytest.raises(UserError, match="attention_log_probs"):
        d4rt_loss({"points": torch.zeros(1, 1, 3)}, {}, LossConfig(weight_correspondence=1.0))
    assert LossConfig().attention_block is None and LossConfig(weight_correspondence=0.5).attention_block == 0
    with pytest.raises(UserError, match="correspondence_block must be below the decoder's 4 blocks"):
        TrainConfig.from_dict(fast_config(clip_dir, loss={"weight_correspondence": 1.0,
                                                          "correspondence_block": 4})).validate()
    with pytest.raises(UserError, match="correspondence_block must be an integer"):
        LossConfig(correspondence_block=-1).validate()


def test_the_term_can_be_learnt_and_the_trainer_logs_it(tmp_path, clip_dir):
    # Fitting one fixed batch: the gradient reaches the head's queries and keys (a random model learns it).
    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny", max_frames=4)).train()
    video = torch.rand(1, 4, 32, 32, 3)
    queries = torch.cat([torch.rand(1, 64, 2), torch.randint(0, 4, (1, 64, 3)).float()], -1)
    batch = batch_for(queries, torch.rand(1, 64, 2), torch.ones(1, 64, dtype=torch.bool))
    optimiser = torch.optim.AdamW(model.parameters(), lr=1e-3)
    values = []
    for _ in range(25):
        out = model(video, queries, torch.ones(1), attention_block=0)
        loss = correspondence_loss(out["attention_log_probs"], out["token_grid"], batch)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        values.append(float(loss.detach()))
    assert values[0] == pytest.approx(math.log(2 * 16 + 1), rel=0.05) and values[-1] < 0.5 * values[0]
    # The trainer asks the model for the attention the loss needs and logs the term.
    validation = {"every": 2, "directory": str(clip_dir), "num_clips": 1, "frames": 4, "track_points": 16,
                  "num_queries": 64, "tasks": []}  # validation asks for the attention too
    config = fast_config(clip_dir, loss={"weight_correspondence": 0.5, "correspondence_block": 2},
                         run={"max_steps": 2, "checkpoint_every": 2, "log_every": 1}, validation=validation)
    train(TrainConfig.from_dict(config), tmp_path / "run")
    rows = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    logged = [row["loss/correspondence"] for row in rows if "loss/correspondence" in row]
    assert len(logged) >= 2 and all(0 < v < math.log(2 * 16 + 1) + 1 for v in logged)
    assert any(key.endswith("correspondence") and key != "loss/correspondence" for row in rows for key in row)
