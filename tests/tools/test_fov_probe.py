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


def test_the_ceiling_tool_imports_the_probe():
    ceiling = importlib.util.spec_from_file_location("fov_ceiling", SCRIPT.with_name("fov_ceiling.py"))
    module = importlib.util.module_from_spec(ceiling)
    ceiling.loader.exec_module(module)
    assert module.choose_alpha is fov_probe.choose_alpha
