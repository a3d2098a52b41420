"""The exponential points head (config ``points_activation: exp``): a point's direction comes from the head, its
distance from an exponential of the head's length, and a linear-head checkpoint trains on under it only when it was
converted (``tools/convert_points_activation.py``) and the config says so."""

from __future__ import annotations

import json

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.decoder import exp_distance


def test_exp_distance_keeps_the_direction_and_exponentiates_the_length():
    raw = torch.randn(200, 3, generator=torch.Generator().manual_seed(0)) * 2
    point = exp_distance(raw)
    length = raw.norm(dim=-1)
    torch.testing.assert_close(point.norm(dim=-1), torch.expm1(length), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(point / point.norm(dim=-1, keepdim=True), raw / length[:, None], rtol=1e-5, atol=1e-6)
    # A ratio of distances is a difference of lengths: 50 m against 1 m costs the head ln(51 / 2) more, not 50x.
    far, near = exp_distance(torch.tensor([[0.0, 0.0, float(torch.log1p(torch.tensor(50.0)))]])), \
        exp_distance(torch.tensor([[0.0, 0.0, float(torch.log1p(torch.tensor(1.0)))]]))
    torch.testing.assert_close(far[0, 2] / near[0, 2], torch.tensor(50.0))


def test_exp_distance_is_smooth_at_zero():
    raw = torch.zeros(2, 3, requires_grad=True)
    exp_distance(raw).sum().backward()
    assert torch.equal(exp_distance(raw.detach()), torch.zeros(2, 3))
    torch.testing.assert_close(raw.grad, torch.ones(2, 3))  # d/dr of r * (1 + |r| / 2 + ...) at 0
    small = torch.full((1, 3), 1e-7)
    torch.testing.assert_close(exp_distance(small), small, rtol=1e-5, atol=0)


def test_the_exp_head_answers_exp_distance_of_the_linear_head_with_the_same_weights(make_model, random_video,
                                                                                      random_queries):
    linear = make_model(relative_pose_head=True)
    exp = D4RT(linear.config.replace(points_activation="exp")).eval()
    exp.load_state_dict(linear.state_dict(), strict=True)  # same parameters: only the points' meaning differs
    video, queries = random_video(4, 64, 64, dtype=torch.float32)[None], random_queries(60, 4)[None]
    queries[0, :20, 4] = queries[0, :20, 2]  # some same-camera queries (the relative pose is the identity there)
    with torch.no_grad():
        a, b = linear(video, queries, torch.ones(1)), exp(video, queries, torch.ones(1))
    same = (queries[0, :, 4] == queries[0, :, 2])
    torch.testing.assert_close(b["points"][0, same], exp_distance(a["points"][0, same]), rtol=1e-5, atol=1e-6)
    # Elsewhere the relative pose moves the exponentiated point: R exp(r) + t, never exp(R r + t).
    rotation, translation = b["relative_rotation"][0, ~same], b["relative_translation"][0, ~same]
    rotated = (rotation.transpose(-1, -2) @ (a["points"][0, ~same] - translation)[..., None])[..., 0]
    expected = (rotation @ exp_distance(rotated)[..., None])[..., 0] + translation
    torch.testing.assert_close(b["points"][0, ~same], expected, rtol=1e-4, atol=1e-5)
    for key in ("uv", "visibility", "motion", "normals", "confidence"):
        assert torch.equal(a[key], b[key]), key


def test_the_setting_travels_with_the_checkpoint_and_init_from_checks_it(tmp_path, build_from_checkpoint, make_model):
    make_model(points_activation="exp").save_pretrained(tmp_path / "exp")
    assert D4RT.from_pretrained(tmp_path / "exp").config.points_activation == "exp"
    assert build_from_checkpoint(tmp_path / "exp", points_activation="exp").config.points_activation == "exp"
    with pytest.raises(UserError, match="different model config"):
        build_from_checkpoint(tmp_path / "exp")  # a converted head is not a linear one
    make_model().save_pretrained(tmp_path / "linear")
    with pytest.raises(UserError, match="different model config"):
        build_from_checkpoint(tmp_path / "linear", points_activation="exp")  # an unconverted head is not either


def test_old_configs_read_as_linear_and_a_bad_value_is_named():
    written = D4RTConfig.preset("tiny").to_dict()
    del written["points_activation"]  # a checkpoint saved before the field existed
    assert D4RTConfig.from_json(json.dumps(written)).points_activation == "linear"
    with pytest.raises(UserError, match="points_activation must be one of"):
        D4RTConfig.preset("tiny", points_activation="log")
