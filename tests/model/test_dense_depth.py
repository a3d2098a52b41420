"""The dense depth head (config ``dense_depth_head``, stage 67): one log-depth per input pixel from the scene
tokens, laid out as the tubelets cut the clip; added to a trained checkpoint by ``model.init_from`` (never
removed); the queries' outputs do not depend on it."""

from __future__ import annotations

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT


@pytest.mark.parametrize("frames", [4, 5])  # 5: the last tubelet is padded with a repeated frame
def test_each_pixel_reads_the_token_of_its_own_tubelet(make_model, random_video, random_queries, frames):
    model = make_model(dense_depth_head=True)
    video, queries, aspect = random_video(frames, 64, 64, dtype=torch.float32)[None], random_queries(8, frames)[None], \
        torch.ones(1)
    with torch.no_grad():
        tokens = model.encode_tokens(video, aspect)
        dense = model(video, queries, aspect)["dense_log_depth"]
    assert dense.shape == (1, frames, 64, 64)
    # Tubelet (time step 1, row 2, column 3) covers frames 2-3, pixel rows 16-23 and columns 24-31.
    k, p, rows, cols = 2, 8, 8, 8
    token = tokens[:, (1 * rows + 2) * cols + 3]
    block = model.dense_depth.mlp(token).reshape(k, p, p)
    end = min(4, frames)
    assert torch.allclose(dense[0, 2:end, 16:24, 24:32], block[:end - 2], atol=1e-6)


def test_the_head_changes_no_query_output(make_model, random_video, random_queries):
    plain = make_model()
    dense = D4RT(plain.config.replace(dense_depth_head=True)).eval()
    state = dense.state_dict()
    state.update(plain.state_dict())
    dense.load_state_dict(state, strict=True)
    video, queries, aspect = random_video(4, 64, 64, dtype=torch.float32)[None], random_queries(40, 4)[None], \
        torch.ones(1)
    with torch.no_grad():
        a, b = plain(video, queries, aspect), dense(video, queries, aspect)
    assert set(b) - set(a) == {"dense_log_depth"}
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_init_from_adds_the_head_and_keeps_every_trained_weight(tmp_path, build_from_checkpoint, make_model):
    base = make_model()
    base.save_pretrained(tmp_path / "plain")
    model = build_from_checkpoint(tmp_path / "plain", dense_depth_head=True)
    assert any(key.startswith("dense_depth.") for key in model.state_dict())
    for key, value in base.state_dict().items():
        assert torch.equal(model.state_dict()[key], value), key


def test_init_from_refuses_to_drop_the_head(tmp_path, build_from_checkpoint, make_model):
    make_model(dense_depth_head=True).save_pretrained(tmp_path / "dense")
    with pytest.raises(UserError, match="different model config"):
        build_from_checkpoint(tmp_path / "dense")
    assert D4RT.from_pretrained(tmp_path / "dense").config.dense_depth_head is True


def test_dense_depth_head_must_be_a_boolean():
    with pytest.raises(UserError, match="dense_depth_head must be true or false"):
        D4RTConfig.preset("tiny", dense_depth_head=1)
