"""torch.hub entry points (as CoTracker offers them): one line loads the model.

    model = torch.hub.load("path/to/a/d4rt/clone", "d4rt", source="local")   # offline, from a clone
    model = torch.hub.load("path/to/a/d4rt/clone", "d4rt", source="local", checkpoint="runs/my-run")  # your own
    rec = model.reconstruct(video)   # video: (T, H, W, 3) uint8 or float in [0, 1]

The weights are the ones the clone bundles (src/d4rt/assets/d4rt-tiny): nothing is downloaded. The code is the
clone's own (its src/ goes first on sys.path, unless d4rt was already imported in this process), so the clone's
dependencies (below) must be installed.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

dependencies = ["torch", "numpy", "safetensors", "einops", "yaml", "PIL", "av", "scipy", "tqdm"]

_SRC = Path(__file__).resolve().parent / "src"


def _import_d4rt():
    # torch.hub puts the clone on sys.path, but the package lives in src/ (the layout pip installs from).
    if str(_SRC) not in sys.path:
        sys.path.insert(0, str(_SRC))
    import d4rt.model

    return d4rt.model


def d4rt(pretrained: bool = True, checkpoint: str | None = None, device: str = "cpu", **config_overrides):
    """The D4RT model, in eval mode.

    pretrained: load the bundled weights (or ``checkpoint``, a folder written by ``save_pretrained`` or ``d4rt
    train``); False gives a freshly initialised model of the ``tiny`` preset (``config_overrides`` change its
    fields, e.g. ``encoder_depth=8``), for training. Errors are d4rt's one-line ``UserError``.
    """
    model_module = _import_d4rt()
    from d4rt.config import D4RTConfig
    from d4rt.errors import UserError

    if pretrained:
        if config_overrides:
            raise UserError(f"config overrides {sorted(config_overrides)} need pretrained=False: trained weights "
                            "fix their config")
        return model_module.D4RT.from_pretrained(checkpoint, device=device)
    if checkpoint is not None:
        raise UserError("checkpoint= loads weights: it needs pretrained=True")
    with torch.device(device):
        return model_module.D4RT(D4RTConfig.preset("tiny", **config_overrides)).eval()
