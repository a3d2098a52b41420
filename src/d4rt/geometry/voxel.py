"""Bounded, evenly spread subsets of point clouds."""

from __future__ import annotations

import numpy as np


def voxel_subsample(points: np.ndarray, score: np.ndarray, max_points: int, iterations: int = 16) -> np.ndarray:
    """Indices of at most ``max_points`` points, one per voxel (the highest ``score`` in it), with the
    smallest voxel that allows it: the subset covers the whole cloud evenly instead of its densest parts.

    points: (M, 3) finite; score: (M,) (e.g. confidence). Returns (K,) int64 indices, sorted, K <=
    max_points (close to it unless the cloud has fewer distinct places). The voxel side is found by
    bisection in log scale: a surface fills far fewer voxels than its bounding box holds, so no closed
    form fits every cloud.
    """
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    if len(points) <= max_points:
        return np.arange(len(points))
    side = _voxel_side(points, max_points, iterations)
    order = np.argsort(-score, kind="stable")  # best first: np.unique keeps each voxel's first index
    chosen = _first_per_voxel(points[order], side)
    while len(chosen) > max_points:  # the side was found on a sample: a few more voxels are possible
        side *= 1.02
        chosen = _first_per_voxel(points[order], side)
    return np.sort(order[chosen])


def _first_per_voxel(points: np.ndarray, side: float) -> np.ndarray:
    """Index of the first point in each occupied voxel of the given side."""
    cells = np.floor((points - points.min(0)) / side).astype(np.int64)
    dims = cells.max(0) + 1
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    return np.unique(keys, return_index=True)[1]


def _voxel_side(points: np.ndarray, max_points: int, iterations: int, sample_factor: int = 20) -> float:
    """The smallest voxel side (to a factor 2^(10 / 2^iterations)) whose occupied voxels number at most
    max_points, searched on a fixed random sample of at most sample_factor * max_points points (with
    about 20 points per voxel, the sample occupies nearly the voxels the whole cloud does)."""
    if len(points) > sample_factor * max_points:
        points = points[np.random.default_rng(0).choice(len(points), sample_factor * max_points, replace=False)]
    extent = np.ptp(points, axis=0)
    box = float(np.cbrt(np.prod(np.where(extent > 0, extent, extent.max() or 1.0)) / max_points))
    lo, hi = box / 1000.0, box  # at the bounding box's side the voxels number about max_points
    while len(_first_per_voxel(points, hi)) > max_points:
        lo, hi = hi, hi * 2.0
    for _ in range(iterations):
        mid = float(np.sqrt(lo * hi))
        if len(_first_per_voxel(points, mid)) <= max_points:
            hi = mid
        else:
            lo = mid
    return hi
