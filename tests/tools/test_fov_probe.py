"""tools/fov_probe.py: the ridge probe recovers a linear signal through noise features, cross-validation prefers
weak regularisation when the signal is clean, and the scores read errors and slopes exactly."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "fov_probe.py"
spec = importlib.util.spec_from_file_location("fov_probe", SCRIPT)
fov_probe = importlib.util.module_from_spec(spec)
sys.modules["fov_probe"] = fov_probe  # tools/fov_ceiling.py imports it by this name
spec.loader.exec_module(fov_probe)


def test_ridge_recovers_a_linear_target_among_noise_features():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 20)) * rng.uniform(0.1, 10, size=20)  # features on very different scales
    y = 0.3 * x[:, 3] / x[:, 3].std() - 0.5
    alpha, errors = fov_probe.choose_alpha(x[:300], y[:300])
    assert alpha == fov_probe.ALPHAS[0] and errors[0] < 1e-4  # a clean signal: the weakest ridge wins
    predict = fov_probe.ridge_fit(x[:300], y[:300], alpha)
    assert np.abs(predict(x[300:]) - y[300:]).max() < 0.01


def test_scores_read_relative_error_and_log_slope():
    true = np.log(np.array([0.5, 1.0, 2.0]))
    exact = fov_probe.scores(true, true)
    assert exact["median_focal_error"] == pytest.approx(0.0, abs=1e-12) and exact["slope"] == pytest.approx(1.0)
    half = fov_probe.scores(0.5 * true, true)  # keeps half of the log focal
    assert half["slope"] == pytest.approx(0.5)
    assert half["per_clip_error"][0] == pytest.approx(round(math.sqrt(2) - 1, 4))
    assert half["median_focal_error"] == pytest.approx(1 - 1 / math.sqrt(2))  # errors 0.414, 0, 0.293
    assert fov_probe.log_focal(np.array([60.0, 64.0, 70.0]), 64) == pytest.approx(0.0)


def test_the_ceiling_reads_the_probes_features():
    """tools/fov_ceiling.py trains on the probe's features computed from its own stored uint8 frames: they must be
    tools/fov_probe.py's features of the same clip."""
    import torch

    from d4rt.config import D4RTConfig
    from d4rt.model import D4RT

    ceiling_spec = importlib.util.spec_from_file_location("fov_ceiling", SCRIPT.with_name("fov_ceiling.py"))
    ceiling = importlib.util.module_from_spec(ceiling_spec)
    ceiling_spec.loader.exec_module(ceiling)
    torch.manual_seed(0)
    model = D4RT(D4RTConfig.preset("tiny")).eval()
    rgb = np.random.default_rng(1).integers(0, 256, size=(4, 64, 64, 3), dtype=np.uint8)  # at the encoder's size
    with torch.no_grad():
        from_uint8 = ceiling.pooled(model, torch.from_numpy(rgb), 1.0).numpy()
    assert from_uint8.shape == (2 * model.config.encoder_dim,)
    np.testing.assert_allclose(from_uint8, fov_probe.pooled_tokens(model, rgb), atol=1e-5)
