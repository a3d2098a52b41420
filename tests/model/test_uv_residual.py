"""The residual 2D head (config ``uv_residual``): the head answers the displacement from the query's own (u, v),
and a checkpoint trained with the plain head can be turned residual (never back) by ``model.init_from``."""

from __future__ import annotations

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT

UV_KEYS = ("decoder.heads.heads.uv.weight", "decoder.heads.heads.uv.bias")


def test_the_residual_head_adds_the_query_position_and_nothing_else(make_model, random_video, random_queries):
    plain = make_model()
    residual = D4RT(plain.config.replace(uv_residual=True)).eval()
    residual.load_state_dict(plain.state_dict(), strict=True)  # same parameters: only the parameterisation differs
    video, queries, aspect = random_video(4, 64, 64, dtype=torch.float32)[None], random_queries(40, 4)[None], torch.ones(1)
    with torch.no_grad():
        a, b = plain(video, queries, aspect), residual(video, queries, aspect)
    assert torch.allclose(b["uv"], a["uv"] + queries[..., :2], atol=1e-6)
    for key in ("points", "visibility", "motion", "normals", "confidence"):
        assert torch.equal(a[key], b[key]), key


def test_a_zero_residual_head_answers_no_motion_through_the_inference_path(make_model, random_video, random_queries):
    model = make_model(uv_residual=True)
    with torch.no_grad():
        for key in UV_KEYS:
            model.state_dict()[key].zero_()
    queries = random_queries(40, 4)
    answer = model.encode(random_video(4, 64, 64)).query(queries)
    assert torch.allclose(torch.as_tensor(answer["uv"]), queries[:, :2], atol=1e-6)


def test_init_from_turns_a_plain_head_residual_starting_from_no_motion(tmp_path, build_from_checkpoint, make_model):
    base = make_model()
    base.save_pretrained(tmp_path / "plain")
    model = build_from_checkpoint(tmp_path / "plain", uv_residual=True)
    for key, value in base.state_dict().items():
        if key in UV_KEYS:  # a head trained on absolute (u, v) would double it: it starts at zero
            assert not model.state_dict()[key].any(), key
        else:
            assert torch.equal(model.state_dict()[key], value), key


def test_init_from_refuses_to_turn_a_residual_head_plain(tmp_path, build_from_checkpoint, make_model):
    make_model(uv_residual=True).save_pretrained(tmp_path / "residual")
    with pytest.raises(UserError, match="different model config"):
        build_from_checkpoint(tmp_path / "residual")
    loaded = D4RT.from_pretrained(tmp_path / "residual")  # the setting travels with the checkpoint
    assert loaded.config.uv_residual is True


def test_uv_residual_must_be_a_boolean():
    with pytest.raises(UserError, match="uv_residual must be true or false"):
        D4RTConfig.preset("tiny", uv_residual="yes")
