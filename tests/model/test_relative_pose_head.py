"""The relative-pose head (config ``relative_pose_head``): the points, motion and normals heads answer in
camera t_src and a per-query rotation + translation moves them into camera t_cam."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT
from d4rt.model.decoder import _IDENTITY_6D, rotation_from_6d

POSE_KEYS = ("decoder.heads.relative_pose.weight", "decoder.heads.relative_pose.bias")


def make_model(**overrides) -> D4RT:
    torch.manual_seed(1234)
    return D4RT(D4RTConfig.preset("tiny", **overrides)).eval()


def random_video(frames: int, height: int, width: int) -> torch.Tensor:
    return torch.randint(0, 256, (frames, height, width, 3), generator=torch.Generator().manual_seed(0),
                         dtype=torch.uint8)


def random_queries(n: int, frames: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.cat([torch.rand(n, 2, generator=g), torch.randint(0, frames, (n, 3), generator=g).float()], 1)


def _rotation(axis, degrees: float) -> torch.Tensor:
    """Rodrigues' formula: (3, 3) rotation about ``axis`` by ``degrees``."""
    k = torch.tensor(axis, dtype=torch.float64)
    k = k / k.norm()
    skew = torch.tensor([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]], dtype=torch.float64)
    a = math.radians(degrees)
    return torch.eye(3, dtype=torch.float64) + math.sin(a) * skew + (1 - math.cos(a)) * skew @ skew


def _with_head(base: D4RT) -> D4RT:
    """``base``'s weights in a model with the head added, its layer set to zero (the identity pose)."""
    model = D4RT(base.config.replace(relative_pose_head=True)).eval()
    state = base.state_dict()
    state.update({k: torch.zeros_like(model.state_dict()[k]) for k in POSE_KEYS})
    model.load_state_dict(state, strict=True)
    return model


def test_rotation_from_6d_is_a_rotation_and_recovers_its_columns():
    d6 = torch.randn(50, 6, dtype=torch.float64)
    r = rotation_from_6d(d6)
    assert torch.allclose(r @ r.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(50, 3, 3), atol=1e-12)
    assert torch.allclose(torch.linalg.det(r), torch.ones(50, dtype=torch.float64), atol=1e-12)
    assert torch.equal(rotation_from_6d(torch.tensor(_IDENTITY_6D)), torch.eye(3))
    r0 = _rotation([0.3, -1.0, 0.5], 40.0)
    assert torch.allclose(rotation_from_6d(torch.cat([r0[:, 0], r0[:, 1]])), r0, atol=1e-12)


def test_a_zero_head_answers_exactly_as_the_model_without_it():
    base = make_model()
    video, queries = random_video(6, 64, 64), random_queries(300, 6)
    with torch.no_grad():
        plain = base.encode(video).query(queries)
        headed = _with_head(base).encode(video).query(queries)
    for key in plain:
        assert torch.equal(torch.as_tensor(plain[key]), torch.as_tensor(headed[key])), key


def test_head_moves_points_motion_and_normals_into_camera_t_cam():
    base = make_model()
    model = _with_head(base)
    r0, t0 = _rotation([1.0, 2.0, -0.5], 30.0).float(), torch.tensor([0.4, -0.2, 1.5])
    with torch.no_grad():  # a constant pose for every query: bias only
        model.decoder.heads.relative_pose.bias.copy_(
            torch.cat([r0[:, 0], r0[:, 1], t0]) - torch.tensor(_IDENTITY_6D + (0.0, 0.0, 0.0)))
    video, queries = random_video(6, 64, 64), random_queries(400, 6, seed=3)
    same = queries[:, 2] == queries[:, 4]
    assert 0 < int(same.sum()) < len(queries)
    with torch.no_grad():
        plain = {k: torch.as_tensor(v) for k, v in base.encode(video).query(queries).items()}
        moved = {k: torch.as_tensor(v) for k, v in model.encode(video).query(queries).items()}
    expected_points = torch.where(same[:, None], plain["points"], plain["points"] @ r0.T + t0)
    assert torch.allclose(moved["points"], expected_points, atol=1e-5)
    assert torch.allclose(moved["motion"], torch.where(same[:, None], plain["motion"], plain["motion"] @ r0.T),
                          atol=1e-5)
    assert torch.allclose(moved["normals"], torch.where(same[:, None], plain["normals"], plain["normals"] @ r0.T),
                          atol=1e-5)
    for key in ("uv", "visibility", "confidence"):  # not camera-t_cam quantities
        assert torch.equal(moved[key], plain[key]), key


def test_head_keeps_queries_independent():
    model = make_model(relative_pose_head=True)
    torch.nn.init.normal_(model.decoder.heads.relative_pose.weight, std=0.05)
    video, queries = random_video(4, 64, 64), random_queries(64, 4, seed=5)
    scene = model.encode(video)
    with torch.no_grad():
        together = scene.query(queries)["points"]
        alone = np.concatenate([np.asarray(scene.query(queries[i:i + 1])["points"]) for i in range(0, 64, 7)])
    assert np.allclose(np.asarray(together)[::7], alone, atol=1e-5)


def test_init_from_adds_the_head_to_a_checkpoint_without_it(tmp_path, build_from_checkpoint):
    base = make_model()
    base.save_pretrained(tmp_path / "plain")
    model = build_from_checkpoint(tmp_path / "plain", relative_pose_head=True)
    for key, value in base.state_dict().items():
        assert torch.equal(model.state_dict()[key], value), key
    # The added layer is initialised as a fresh model's (not zero: a zero layer passes no gradient upstream).
    weight = model.state_dict()[POSE_KEYS[0]]
    assert 0.01 < float(weight.std()) < 0.03 and not model.state_dict()[POSE_KEYS[1]].any()


def test_init_from_refuses_to_drop_a_trained_head(tmp_path, build_from_checkpoint):
    make_model(relative_pose_head=True).save_pretrained(tmp_path / "headed")
    with pytest.raises(UserError, match="different model config"):
        build_from_checkpoint(tmp_path / "headed")
