"""voxel_subsample: a bounded subset that spreads over the whole cloud and keeps each voxel's best point."""

import numpy as np
import pytest

from d4rt.geometry.voxel import voxel_subsample


def test_a_dense_patch_does_not_crowd_out_the_rest_of_the_cloud():
    rng = np.random.default_rng(0)
    # A plane (a surface, as clouds from depth are): 90% of its points packed into one small corner.
    sparse = np.c_[rng.uniform(0, 10, (1000, 2)), np.zeros(1000)]
    dense = np.c_[rng.uniform(0, 1, (9000, 2)), np.zeros(9000)]
    points = np.concatenate([sparse, dense])
    score = rng.random(len(points))
    picked = voxel_subsample(points, score, 500)
    assert 400 <= len(picked) <= 500 and np.array_equal(picked, np.unique(picked))
    assert (picked < 1000).mean() > 0.6  # most picks fall outside the crowded corner (random: 10%)


def test_small_clouds_are_kept_and_bad_limits_refused():
    points = np.random.default_rng(1).random((50, 3))
    assert np.array_equal(voxel_subsample(points, np.ones(50), 50), np.arange(50))
    with pytest.raises(ValueError, match="max_points"):
        voxel_subsample(points, np.ones(50), 0)


def test_the_best_point_of_a_voxel_wins():
    # Two tight clusters far apart, two points allowed: one per cluster, the higher score of each.
    points = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [10, 10, 10], [10.01, 10, 10]], dtype=float)
    score = np.array([0.1, 0.9, 0.3, 0.8, 0.2])
    assert voxel_subsample(points, score, 2).tolist() == [1, 3]


def test_the_voxel_count_of_the_side_search_equals_the_distinct_voxels():
    from d4rt.geometry.voxel import _count_voxels, _first_per_voxel

    points = np.random.default_rng(2).normal(size=(5000, 3)) * [3.0, 1.0, 0.2]
    box = points.min(0), points.max(0)
    for side in (0.05, 0.3, 2.0, 100.0):
        assert _count_voxels(points, side, box) == len(_first_per_voxel(points, side))
    assert _count_voxels(points[:0], 1.0, box) == 0
