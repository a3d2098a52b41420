"""tools/convert_points_activation.py: a linear points head refitted under ``points_activation: exp`` answers the same
points in its new unit (the motion and the relative pose's translation rescaled alike), every other output unchanged."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.errors import UserError
from d4rt.model import D4RT

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "convert_points_activation.py"
spec = importlib.util.spec_from_file_location("convert_points_activation", SCRIPT)
convert_points_activation = importlib.util.module_from_spec(spec)
spec.loader.exec_module(convert_points_activation)


def spread_model() -> D4RT:
    """A seeded tiny model whose linear points head answers points a few units in front of the camera and spread
    over a range of distances (a freshly initialised head answers nearly zero, where exp is nearly linear)."""
    torch.manual_seed(7)
    model = D4RT(D4RTConfig.preset("tiny", relative_pose_head=True)).eval()
    head = model.decoder.heads.heads["points"]
    with torch.no_grad():
        head.weight.mul_(20.0)
        head.bias.copy_(torch.tensor([0.0, 0.0, 4.0]))
    return model


def samples(count: int = 3, frames: int = 4, queries: int = 300) -> list[dict[str, torch.Tensor]]:
    g = torch.Generator().manual_seed(3)
    out = []
    for _ in range(count):
        times = torch.randint(0, frames, (queries, 3), generator=g).float()
        out.append({"video": torch.rand(frames, 64, 64, 3, generator=g),
                    "queries": torch.cat([torch.rand(queries, 2, generator=g), times], dim=1),
                    "aspect_ratio": torch.ones(())})
    return out


def test_the_converted_model_answers_the_old_points_in_its_new_unit():
    model, data = spread_model(), samples()
    converted, fit = convert_points_activation.convert(model, data)
    assert converted.config.points_activation == "exp" and fit["scale"] > 0
    assert fit["r2"] > 0.95 and fit["median_relative_error"] < 0.1
    old_z = convert_points_activation.head_features(model, data)[1][:, 2]
    assert old_z.max() / old_z.clamp_min(1e-3).min() > 3  # the head spans a range of distances, not one
    sample = data[0]
    with torch.no_grad():
        a = model(sample["video"][None], sample["queries"][None], sample["aspect_ratio"][None])
        b = converted(sample["video"][None], sample["queries"][None], sample["aspect_ratio"][None])
    relative = (b["points"] * fit["scale"] - a["points"]).norm(dim=-1) / a["points"].norm(dim=-1)
    assert float(relative.median()) < 0.1
    torch.testing.assert_close(b["motion"] * fit["scale"], a["motion"], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(b["relative_translation"] * fit["scale"], a["relative_translation"], rtol=1e-4,
                               atol=1e-6)
    for key in ("uv", "visibility", "normals", "confidence", "relative_rotation"):
        assert torch.equal(a[key], b[key]), key


def test_log_distance_inverts_exp_distance():
    from d4rt.model.decoder import exp_distance

    raw = torch.randn(100, 3, generator=torch.Generator().manual_seed(1)) * 3
    torch.testing.assert_close(convert_points_activation.log_distance(exp_distance(raw)), raw, rtol=1e-4, atol=1e-5)
    assert torch.equal(convert_points_activation.log_distance(torch.zeros(1, 3)), torch.zeros(1, 3))


def test_a_checkpoint_already_exp_is_refused_in_one_line():
    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny", points_activation="exp")).eval()
    with pytest.raises(UserError, match="points_activation is 'exp'"):
        convert_points_activation.convert(model, samples(1))
