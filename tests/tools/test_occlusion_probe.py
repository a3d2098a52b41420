"""tools/occlusion_probe.py: occlusion accuracy per threshold, the every-point-visible constant and the recall of
hidden points, on a hand-checked example."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "occlusion_probe.py"
spec = importlib.util.spec_from_file_location("occlusion_probe", SCRIPT)
occlusion_probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(occlusion_probe)


def test_visibility_scores_by_hand():
    probability = np.array([[0.9, 0.2], [0.6, 0.4]])
    visible = np.array([[True, False], [False, False]])
    scores = occlusion_probe.visibility_scores(probability, visible)
    assert scores["oa@0.5"] == 0.75  # one hidden point called visible
    assert scores["oa@0.3"] == 0.5 and scores["oa@0.7"] == 1.0 and scores["oa@0.9"] == 0.75
    assert scores["constant_oa"] == 0.25  # every point called visible
    assert scores["predicted_visible"] == 0.5
    assert scores["occluded_recall"] == pytest.approx(2 / 3)


def test_all_visible_truth_has_no_recall():
    scores = occlusion_probe.visibility_scores(np.full((3, 4), 0.8), np.ones((3, 4), bool))
    assert scores["oa@0.5"] == 1.0 == scores["constant_oa"] and np.isnan(scores["occluded_recall"])
    assert occlusion_probe.TRACK_SCALING == "median"


def test_the_in_frame_gate_and_the_out_of_frame_share_by_hand():
    probability = np.array([[0.9, 0.2], [0.6, 0.4]])
    visible = np.array([[True, False], [False, False]])
    predicted_in_frame = np.array([[True, True], [False, True]])  # the hidden point called visible leaves the image
    truly_in_frame = np.array([[True, False], [True, True]])
    scores = occlusion_probe.visibility_scores(probability, visible, predicted_in_frame, truly_in_frame)
    assert scores["oa_in_frame_gate"] == 1.0 and scores["oa@0.5"] == 0.75
    assert scores["hidden_out_of_frame"] == pytest.approx(1 / 3)


def test_in_frame_projects_with_pixel_centres_at_half_integers():
    k = np.array([[[10.0, 0, 1.5], [0, 10.0, 0.5], [0, 0, 1]]])  # 4 x 2 image, principal point at its centre - 0.5
    points = np.array([[[0.0, 0, 1], [0.21, 0, 1], [0.19, 0, 1], [0.0, 0.11, 1], [0, 0, -1]]])
    assert occlusion_probe.in_frame(points, k, (2, 4)).tolist() == [[True, False, True, False, False]]
