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
    """A stand-in model: ``encode(rgb)`` answers as ``answer_for_clip(clip)`` does for the clip of ``rgb`` (no flip
    averaging: the probe encodes as the model's config says)."""
    def encode(rgb):
        clip = next(clip for clip in _answering.clips if clip.rgb is rgb)
        return SimpleNamespace(query=answer_for_clip(clip), num_frames=clip.num_frames)
    return SimpleNamespace(encode=encode, config=SimpleNamespace(flip_average=False))


@pytest.fixture(scope="module")
def clips():
    clips = [(f"clip_{seed}", render_clip(seed, camera_probe.FRAMES, 32, 40, camera_motion="orbit", num_objects=2,
                                          time_stride=camera_probe.TIME_STRIDE)) for seed in (1, 2)]
    _answering.clips = [clip for _, clip in clips]
    return clips


def test_the_oracle_recovers_every_camera_motion(clips):
    report = camera_probe.probe(_answering(lambda clip: clip.oracle.query), clips)
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
    ate = report["trajectory_ate"]
    assert ate["first"]["mean"] < 1e-4 and ate["adjacent"]["mean"] < 1e-4  # both pairings exact
    assert all(ate[f"adjacent_true_{part}s"]["mean"] < 1e-4 for part in camera_probe.CHAIN_PARTS)
    assert ate["adjacent_smoothed_5"]["mean"] < ate["static"]["mean"]  # a smoothed true path: near it, not exact
    assert ate["static"]["mean"] > 0.1
    steps = report["adjacent_steps"]
    assert steps["steps"] > 0 and steps["median_cosine"] == pytest.approx(1.0, abs=1e-6)
    assert steps["median_axial_share"] == pytest.approx(steps["median_true_axial_share"], abs=1e-6)
    assert steps["median_length_deviation"] == pytest.approx(0.0, abs=1e-6)
    # A line walked at zero speed is the static camera, so the best line is never farther from the path.
    assert 0 < ate["constant_velocity"]["mean"] <= ate["static"]["mean"]


def test_answers_that_ignore_t_cam_recover_no_camera_motion(clips):
    def own_camera(clip):  # every query answered in its source camera: t_cam replaced by t_src
        def query(queries):
            fixed = queries.copy()
            fixed[:, 4] = fixed[:, 2]
            return clip.oracle.query(fixed)
        return query

    report = camera_probe.probe(_answering(own_camera), clips)
    assert report["median_rotation_ratio"] < 1e-6 and report["median_change_ratio"] < 1e-6
    assert report["median_rotation_error"] == pytest.approx(report["median_true_rotation"], abs=1e-3)
    assert report["frames_travelled"] > 0
    assert abs(report["median_translation_cosine"]) < 1e-6 and report["median_translation_ratio"] < 1e-6


def test_a_chain_with_the_true_half_of_each_step_keeps_the_other_half(clips):
    """Steps whose rotations are wrong and translations right: the true rotations restore the path exactly, the
    true translations alone do not (the wrong rotations still turn every later step)."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    truth = clips[0][1].cam_to_world
    steps = np.linalg.inv(truth[:-1]) @ truth[1:]
    steps[:, :3, :3] = steps[:, :3, :3] @ Rotation.from_rotvec([0.0, 0.05, 0.0]).as_matrix()
    wrong = camera_probe.chain(truth[0], steps)
    np.testing.assert_allclose(camera_probe.chain_with_true(wrong, truth, "rotation"), truth, atol=1e-9)
    kept = camera_probe.chain_with_true(wrong, truth, "translation")
    np.testing.assert_allclose(kept[:, :3, :3], wrong[:, :3, :3], atol=1e-9)  # the wrong rotations stay
    assert np.abs(kept[:, :3, 3] - truth[:, :3, 3]).max() > 1e-3


def test_step_directions_read_a_chain_that_walks_straight_ahead():
    """Steps turned onto the optical axis read the cosine of that turn and an axial share of 1; a camera that
    never travels has no step to count."""
    import numpy as np

    truth = np.tile(np.eye(4), (5, 1, 1))
    truth[:, :3, 3] = np.arange(5)[:, None] * np.array([1.0, 0.0, 1.0])  # 45 degrees off the axis, no turn
    ahead = np.tile(np.eye(4), (5, 1, 1))
    ahead[:, 2, 3] = 3.0 * np.arange(5)  # straight ahead, another scale
    figures = camera_probe.step_directions(ahead, truth)
    assert np.allclose(figures["cosine"], np.sqrt(0.5)) and np.allclose(figures["axial_share"], 1.0)
    assert np.allclose(figures["true_axial_share"], np.sqrt(0.5))
    assert np.allclose(figures["length_deviation"], 0.0)  # every step 3 / sqrt(2) times the true one: no drift
    uneven = ahead.copy()
    uneven[:, 2, 3] = np.array([0.0, 1.0, 3.0, 4.0, 6.0])  # steps 1, 2, 1, 2: the median log ratio lies between
    assert np.allclose(camera_probe.step_directions(uneven, truth)["length_deviation"], np.log(2) / 2)
    still = np.tile(np.eye(4), (5, 1, 1))
    assert camera_probe.step_directions(ahead, still)["cosine"].size == 0
    summary = camera_probe.summarise_steps([figures, camera_probe.step_directions(ahead, still)])
    assert summary["steps"] == 4 and summary["median_cosine"] == pytest.approx(np.sqrt(0.5), abs=1e-3)


def test_a_smoothed_chain_keeps_a_steady_walk_and_removes_scatter():
    """A path walked at constant velocity is its own smoothing; the same path with steps that alternate long and
    short comes back closer to it once smoothed."""
    import numpy as np

    steady = np.tile(np.eye(4), (9, 1, 1))
    steady[:, :3, 3] = np.arange(9)[:, None] * np.array([0.3, 0.0, 1.0])
    assert np.allclose(camera_probe.chain_smoothed(steady, 5), steady)
    scattered = steady.copy()
    scattered[:, 0, 3] += 0.2 * (np.arange(9) % 2)  # every other frame pushed sideways
    smoothed = camera_probe.chain_smoothed(scattered, 5)
    distance = lambda poses: np.abs(poses[:, :3, 3] - steady[:, :3, 3]).max()
    assert distance(smoothed) < distance(scattered)
    with pytest.raises(ValueError, match="odd number"):
        camera_probe.chain_smoothed(steady, 4)


def test_a_chain_with_the_true_direction_or_length_keeps_the_other_factor():
    """Steps pointing the true way whose lengths are 2x the truth's for three steps and 4x after: the true lengths
    restore the path exactly; the true directions keep the drifting lengths (one scale per clip cannot undo them)."""
    import numpy as np

    truth = np.tile(np.eye(4), (6, 1, 1))
    truth[1:, :3, 3] = np.cumsum([[1.0, 0.0, 1.0 + 0.2 * i] for i in range(5)], 0)
    steps = np.linalg.inv(truth[:-1]) @ truth[1:]
    steps[:, :3, 3] *= np.array([2.0, 2.0, 2.0, 4.0, 4.0])[:, None]
    built = camera_probe.chain(truth[0], steps)
    np.testing.assert_allclose(camera_probe.chain_with_true(built, truth, "translation_length"), truth, atol=1e-9)
    kept = camera_probe.chain_with_true(built, truth, "translation_direction")
    assert np.abs(kept[:, :3, 3] - truth[:, :3, 3]).max() > 0.5
    with pytest.raises(ValueError, match="translation_direction"):
        camera_probe.chain_with_true(built, truth, "scale")
