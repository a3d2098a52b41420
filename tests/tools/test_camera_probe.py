"""tools/camera_probe.py: on the exact oracle every camera motion is recovered, and a model that ignores t_cam
recovers none of it."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import pytest

from d4rt.synthetic import render_clip

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "camera_probe.py"
spec = importlib.util.spec_from_file_location("camera_probe", SCRIPT)
camera_probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(camera_probe)


def _answering(answer_for_clip):
    """A stand-in model: ``encode(rgb).query`` answers as ``answer_for_clip(rgb)`` does."""
    return SimpleNamespace(encode=lambda rgb: SimpleNamespace(query=answer_for_clip(rgb)))


@pytest.fixture(scope="module")
def clips():
    return [(f"clip_{seed}", render_clip(seed, camera_probe.FRAMES, 32, 40, camera_motion="orbit", num_objects=2,
                                         time_stride=camera_probe.TIME_STRIDE)) for seed in (1, 2)]


def test_the_oracle_recovers_every_camera_motion(clips):
    by_rgb = {id(clip.rgb): clip for _, clip in clips}
    report = camera_probe.probe(_answering(lambda rgb: by_rgb[id(rgb)].oracle.query), clips)
    assert report["frames_counted"] > 0 and report["median_true_rotation"] > camera_probe.MIN_ROTATION
    assert report["median_rotation_ratio"] == pytest.approx(1.0, abs=1e-6)
    assert report["median_change_ratio"] == pytest.approx(1.0, abs=1e-6)
    assert report["median_rotation_error"] < 1e-3
    assert report["frames_travelled"] > 0
    assert report["median_translation_cosine"] == pytest.approx(1.0, abs=1e-6)
    assert report["median_translation_ratio"] == pytest.approx(1.0, abs=1e-6)
    assert [g["frames"] for g in report["by_gap"]][:2] == [[1, 3], [4, 7]]
    assert all(g["median_rotation_error"] < 1e-3 for g in report["by_gap"])
    assert all(g["median_translation_cosine"] == pytest.approx(1.0, abs=1e-6)
               for g in report["by_gap"] if g["frames_travelled"])


def test_answers_that_ignore_t_cam_recover_no_camera_motion(clips):
    by_rgb = {id(clip.rgb): clip for _, clip in clips}

    def own_camera(rgb):  # every query answered in its source camera: t_cam replaced by t_src
        def query(queries):
            fixed = queries.copy()
            fixed[:, 4] = fixed[:, 2]
            return by_rgb[id(rgb)].oracle.query(fixed)
        return query

    report = camera_probe.probe(_answering(own_camera), clips)
    assert report["median_rotation_ratio"] < 1e-6 and report["median_change_ratio"] < 1e-6
    assert report["median_rotation_error"] == pytest.approx(report["median_true_rotation"], abs=1e-3)
    assert report["frames_travelled"] > 0
    assert abs(report["median_translation_cosine"]) < 1e-6 and report["median_translation_ratio"] < 1e-6
