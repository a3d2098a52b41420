"""Shared fixtures for the model tests: small seeded models and videos (everything runs on CPU)."""

from __future__ import annotations

import pytest
import torch

from d4rt.config import D4RTConfig
from d4rt.model import D4RT


@pytest.fixture(autouse=True)
def _deterministic():
    torch.manual_seed(0)
    yield


def make_model(**overrides) -> D4RT:
    """A seeded tiny model in eval mode, with any config field overridden."""
    torch.manual_seed(1234)
    return D4RT(D4RTConfig.preset("tiny", **overrides)).eval()


def random_video(frames: int, height: int, width: int, dtype=torch.uint8, seed: int = 0) -> torch.Tensor:
    """A random (T, H, W, 3) video: uint8 0..255 or float in [0, 1]."""
    g = torch.Generator().manual_seed(seed)
    if dtype == torch.uint8:
        return torch.randint(0, 256, (frames, height, width, 3), generator=g, dtype=torch.uint8)
    return torch.rand(frames, height, width, 3, generator=g, dtype=dtype)


def random_queries(n: int, frames: int, seed: int = 0) -> torch.Tensor:
    """(n, 5) valid queries: (u, v) uniform in [0, 1], integer times in [0, frames)."""
    g = torch.Generator().manual_seed(seed)
    uv = torch.rand(n, 2, generator=g)
    t = torch.randint(0, frames, (n, 3), generator=g).float()
    return torch.cat([uv, t], dim=1)


@pytest.fixture(scope="module")
def tiny_model() -> D4RT:
    return make_model()


@pytest.fixture(name="make_model")
def _make_model_fixture():
    return make_model


@pytest.fixture(name="random_video")
def _random_video_fixture():
    return random_video


@pytest.fixture(name="random_queries")
def _random_queries_fixture():
    return random_queries


@pytest.fixture
def build_from_checkpoint():
    """``build(init_from, **overrides) -> D4RT``: the model a CPU trainer builds from ``model.init_from`` with the
    tiny preset and ``overrides`` (where a checkpoint may differ from the config it is trained on)."""
    from d4rt.training.config import TrainConfig
    from d4rt.training.distributed import DistributedContext
    from d4rt.training.trainer import Trainer

    def build(init_from, **overrides) -> D4RT:
        config = TrainConfig.from_dict({"model": {"preset": "tiny", "overrides": overrides, "init_from": str(init_from)},
                                        "data": {"dataset": {"size": [64, 64]}}, "run": {"device": "cpu"}})
        return Trainer(config, "unused", DistributedContext.from_environment("cpu"))._build_model()

    return build
