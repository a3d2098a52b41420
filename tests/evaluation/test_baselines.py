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
