"""torch.hub.load from a local clone (source="local"): the bundled weights, one's own, or a fresh model; offline."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from d4rt.errors import UserError
from d4rt.model import D4RT

REPO = Path(__file__).resolve().parents[2]


def _load(*args, **kwargs):
    return torch.hub.load(str(REPO), "d4rt", *args, source="local", trust_repo=True, **kwargs)


def test_hub_loads_the_bundled_weights_exactly(tmp_path):
    model = _load()
    bundled = D4RT.from_pretrained()
    assert model.config == bundled.config and not model.training
    assert all(torch.equal(v, bundled.state_dict()[k]) for k, v in model.state_dict().items())
    bundled.save_pretrained(tmp_path / "mine")
    assert _load(checkpoint=str(tmp_path / "mine")).config == bundled.config


def test_hub_gives_a_fresh_model_with_overrides_and_refuses_mixed_requests():
    fresh = _load(pretrained=False, encoder_depth=2)
    assert fresh.config.encoder_depth == 2 and fresh.config.name == "tiny"
    with pytest.raises(UserError, match="need pretrained=False"):
        _load(encoder_depth=2)
    with pytest.raises(UserError, match="needs pretrained=True"):
        _load(pretrained=False, checkpoint="somewhere")
