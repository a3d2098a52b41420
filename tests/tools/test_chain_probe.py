"""tools/chain_probe.py: the exact oracle's chained trajectory is exact every way (its similarity fits at scale 1),
and a chain whose steps turn wrongly is repaired by the true rotations alone (the decomposition the probe reports)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from d4rt.evaluation.metrics.pose import pose_metrics
from d4rt.geometry.transforms import rigid, rotation_about_axis
from d4rt.synthetic import render_clip

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "chain_probe.py"
spec = importlib.util.spec_from_file_location("chain_probe", SCRIPT)
chain_probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(chain_probe)


def test_the_oracle_chains_the_true_trajectory_every_way():
    clip = render_clip(3, 8, 36, 48, num_objects=2, camera_motion="orbit")
    oracle_model = SimpleNamespace(encode=lambda rgb: clip.oracle, config=SimpleNamespace(flip_average=False))
    row = chain_probe.probe_clip(oracle_model, clip)
    assert max(row["ate"].values()) < 1e-6  # the similarity chain too
    np.testing.assert_allclose(row["step_scale"], 1, atol=1e-6)
    np.testing.assert_allclose(row["step_translation_cosine"], 1, atol=1e-6)
    np.testing.assert_allclose(row["step_length_ratio"], 1, atol=1e-6)
    assert max(row["step_rotation_error"]) < 1e-4
    np.testing.assert_allclose(row["step_rotation_ratio"], 1, atol=1e-4)


def test_steps_that_turn_wrongly_are_repaired_by_the_true_rotations_alone():
    # A camera circling a point 3 units away through 90 degrees, always facing it.
    turns = rigid(rotation_about_axis([0.0, 1.0, 0.0], np.radians(np.linspace(0, 90, 12))), np.zeros(3))
    truth = turns @ rigid(np.eye(3), [0.0, 0.0, -3.0])
    wrong = chain_probe.steps(truth)
    wrong[:, :3, :3] = np.eye(3)  # a camera that never turns (as the shipped weights nearly do); translations exact
    model = chain_probe.chain(wrong)
    ates = {way: pose_metrics(poses, truth)["ate"] for way, poses in chain_probe.rebuilt(model, truth).items()}
    spread = np.sqrt(((truth[:, :3, 3] - truth[:, :3, 3].mean(0)) ** 2).sum(1).mean())  # a camera that never moves
    assert ates["model"] > 0.1 * spread
    assert ates["true_rotations"] < 1e-9
    assert ates["true_translations"] > 0.1 * spread
    # Rebuilding a trajectory from its own steps changes nothing (frame 0 at the identity).
    relative = np.linalg.inv(truth[0]) @ truth
    np.testing.assert_allclose(chain_probe.chain(chain_probe.steps(truth)), relative, atol=1e-12)
