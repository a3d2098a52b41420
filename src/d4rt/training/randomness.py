"""Per-rank seeding and the random-generator states a checkpoint carries (JSON, no pickles).

Model initialisation uses ``seed`` on every rank (identical weights before any wrapper broadcasts them);
everything after it draws from per-rank streams seeded with ``(seed, rank)``.
"""

from __future__ import annotations

import base64
import random

import numpy as np
import torch


def seed_rank(seed: int, rank: int) -> None:
    """Seed Python's, NumPy's and torch's (CPU and CUDA) global generators for ``rank``."""
    mixed = int(np.random.SeedSequence([seed, rank]).generate_state(1)[0])
    random.seed(mixed)
    np.random.seed(mixed)
    torch.manual_seed(mixed)


def capture_rng_state(device: torch.device) -> dict:
    """The global generators' states as JSON-serialisable values."""
    numpy_state = np.random.get_state(legacy=False)
    numpy_state["state"]["key"] = numpy_state["state"]["key"].tolist()
    version, internal, gauss = random.getstate()
    return {
        "python": [version, list(internal), gauss],
        "numpy": numpy_state,
        "torch": _encode(torch.get_rng_state()),
        "cuda": _encode(torch.cuda.get_rng_state(device)) if device.type == "cuda" else None,
    }


def restore_rng_state(state: dict, device: torch.device) -> None:
    """Inverse of :func:`capture_rng_state`."""
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))
    numpy_state = dict(state["numpy"])
    numpy_state["state"] = {**numpy_state["state"], "key": np.asarray(numpy_state["state"]["key"], dtype=np.uint32)}
    np.random.set_state(numpy_state)
    torch.set_rng_state(_decode(state["torch"]))
    if device.type == "cuda" and state.get("cuda") is not None:
        torch.cuda.set_rng_state(_decode(state["cuda"]), device)


def _encode(state: torch.Tensor) -> str:
    return base64.b64encode(state.cpu().numpy().tobytes()).decode("ascii")


def _decode(text: str) -> torch.Tensor:
    return torch.frombuffer(bytearray(base64.b64decode(text)), dtype=torch.uint8)
