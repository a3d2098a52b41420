"""tools/near_object_probe.py: per-body near depth errors by hand, and resting against floating bodies."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "tools" / "near_object_probe.py"
spec = importlib.util.spec_from_file_location("near_object_probe", SCRIPT)
probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(probe)


def scene_depth() -> tuple[np.ndarray, np.ndarray]:
    """(2, 10, 10) depth and ids: a wall at 6 m (id 0), body 1 at 1 m on the left half of the top rows, body 2 at
    2 m on the right half of them (50 pixels each)."""
    depth = np.full((2, 10, 10), 6.0, np.float32)
    ids = np.zeros((2, 10, 10), np.uint8)
    depth[:, :5, :5], ids[:, :5, :5] = 1.0, 1
    depth[:, :5, 5:], ids[:, :5, 5:] = 2.0, 2
    return depth, ids


def test_exact_depth_up_to_scale_and_shift_reads_zero():
    depth, ids = scene_depth()
    assert probe.body_log_ratios(3.0 * depth + 0.5, depth, ids) == pytest.approx({1: 0.0, 2: 0.0}, abs=1e-5)


def test_a_near_body_read_twice_too_far():
    depth, ids = scene_depth()
    pred = np.where(ids == 1, 2.0, depth)  # body 1 read at 2 m: the wall and body 2 decide the alignment (exact)
    ratios = probe.body_log_ratios(pred, depth, ids)
    assert ratios[1] == pytest.approx(np.log(2.0), abs=1e-5) and ratios[2] == pytest.approx(0.0, abs=1e-5)
    few = ids.copy()
    few[1:, :, :] = 0  # body 1 keeps 25 near pixels and body 2 25: fewer than MIN_PIXELS, no rows
    assert probe.body_log_ratios(pred, depth, few) == {}


def pose(z: float, tilt_degrees: float = 0.0) -> np.ndarray:
    c, s = np.cos(np.radians(tilt_degrees)), np.sin(np.radians(tilt_degrees))
    out = np.eye(4)
    out[1:3, 1:3] = [[c, -s], [s, c]]  # turned about x: its z axis leaves the vertical
    out[2, 3] = z
    return out


def test_resting_bodies_sit_upright_at_their_half_height():
    body = SimpleNamespace(half_extents=[0.3, 0.2, 0.4], name="box")
    frames = lambda *poses: np.stack([np.stack([np.eye(4), p]) for p in poses])  # (T, 2, 4, 4): environment, body
    clip = lambda *poses: SimpleNamespace(object_to_world=frames(*poses), scene=SimpleNamespace(bodies=[None, body]))
    assert probe.is_resting(clip(pose(0.4), pose(0.4)), 1)
    assert not probe.is_resting(clip(pose(0.4), pose(0.9)), 1)  # lifted in the second frame
    assert not probe.is_resting(clip(pose(0.4), pose(0.4, tilt_degrees=20)), 1)  # tipped over
    assert probe.body_group(clip(pose(0.4), pose(0.4)), 1) == "resting"
    assert probe.body_group(clip(pose(0.4), pose(0.9)), 1) == "floating"
    body.name = "arm_link1"  # the arm's parts are grounded through its base, lifted or not
    assert probe.body_group(clip(pose(0.4), pose(0.9)), 1) == "articulated"


def test_summary_counts_and_medians_by_group():
    rows = [{"group": "floating", "log_ratio": np.log(2.0)}, {"group": "floating", "log_ratio": -np.log(2.0)},
            {"group": "floating", "log_ratio": np.log(4.0)}, {"group": "resting", "log_ratio": 0.1}]
    out = probe.summarise(rows)
    assert out["floating"] == {"bodies": 3, "median_abs_log_ratio": round(np.log(2.0), 4), "median_ratio": 2.0}
    assert out["resting"]["bodies"] == 1 and out["resting"]["median_ratio"] == pytest.approx(np.exp(0.1), abs=1e-3)


def test_the_size_prior_observer_rescales_floating_bodies_only():
    depth, ids = scene_depth()
    bodies = [None, SimpleNamespace(half_extents=[0.2, 0.2, 0.2], name="sphere"),
              SimpleNamespace(half_extents=[0.1, 0.4, 0.2], name="box")]
    frames = np.stack([np.stack([np.eye(4), pose(1.0), pose(0.2)])] * 2)  # body 1 floats; body 2 rests at 0.2
    clip = SimpleNamespace(depth=depth, object_ids=ids, object_to_world=frames, scene=SimpleNamespace(bodies=bodies))
    read = probe.size_prior_depth(clip, median_size=0.4)
    assert np.allclose(read[ids == 1], 2.0)  # a 0.2 m body taken for a 0.4 m one: read twice as far
    assert np.array_equal(read[ids != 1], depth[ids != 1])  # the environment and the resting body exactly
    assert 0.15 < probe.size_prior_median(draws=2_000) < 0.65  # inside the generator's size range
