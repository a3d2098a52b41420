"""The reference baselines: what a method that does nothing scores."""

from __future__ import annotations

import numpy as np

from d4rt.evaluation.baselines import make_baseline
from d4rt.evaluation.metrics.pose import pose_metrics
from d4rt.evaluation.readers.synthetic import sequence_from_clip
from d4rt.synthetic import render_clip


def test_static_camera_ate_is_the_spread_of_the_true_camera_centres():
    sequence = sequence_from_clip(render_clip(3, 8, 24, 32, camera_motion="orbit", num_objects=2), "clip", 4)
    prediction = make_baseline("static-camera").predict(sequence, {"pose"})
    assert prediction.cam_to_world.shape == (8, 4, 4) and prediction.depth is None
    assert np.array_equal(prediction.cam_to_world, np.broadcast_to(np.eye(4), (8, 4, 4)))
    centres = sequence.cam_to_world[:, :3, 3]
    spread = np.sqrt(np.mean(np.sum((centres - centres.mean(0)) ** 2, axis=1)))
    assert spread > 0.1
    assert np.isclose(pose_metrics(prediction.cam_to_world, sequence.cam_to_world)["ate"], spread, rtol=1e-9)


def test_constant_velocity_ate_is_the_residual_of_the_best_straight_line_through_the_true_centres():
    sequence = sequence_from_clip(render_clip(5, 8, 24, 32, camera_motion="orbit", num_objects=2), "clip", 4)
    prediction = make_baseline("constant-velocity").predict(sequence, {"pose"})
    assert prediction.cam_to_world.shape == (8, 4, 4) and prediction.depth is None
    assert np.array_equal(prediction.cam_to_world[:, :3, :3], np.broadcast_to(np.eye(3), (8, 3, 3)))
    # Least squares of the true centres on (i, 1): the straight line walked at constant speed that fits best.
    centres = sequence.cam_to_world[:, :3, 3]
    design = np.stack([np.arange(8.0), np.ones(8)], 1)
    residual = centres - design @ np.linalg.lstsq(design, centres, rcond=None)[0]
    line_rms = np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))
    spread = np.sqrt(np.mean(np.sum((centres - centres.mean(0)) ** 2, axis=1)))
    assert 1e-3 < line_rms < spread  # an orbit bends: the line misses it, yet by less than a camera that stays
    assert np.isclose(pose_metrics(prediction.cam_to_world, sequence.cam_to_world)["ate"], line_rms, rtol=1e-6)
