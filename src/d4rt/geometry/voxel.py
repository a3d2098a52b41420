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


def _voxel_keys(points: np.ndarray, side: float, box: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(M,) int64 id of the voxel of the given side that holds each point; box: the points' (min, max)
    per axis when already known (a reduction over the points costs as much as the rest)."""
    lo, hi = box if box is not None else (points.min(0), points.max(0))
    cells = ((points - lo) / side).astype(np.int64)  # >= 0, so truncation is the floor
    dims = ((hi - lo) / side).astype(np.int64) + 1  # the largest cell index + 1 on each axis
    return (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]


def _first_per_voxel(points: np.ndarray, side: float) -> np.ndarray:
    """Index of the first point in each occupied voxel of the given side."""
    return np.unique(_voxel_keys(points, side), return_index=True)[1]


def _count_voxels(points: np.ndarray, side: float, box: tuple[np.ndarray, np.ndarray]) -> int:
    """Number of occupied voxels of the given side (a plain sort: several times faster than np.unique)."""
    keys = np.sort(_voxel_keys(points, side, box))
    return int(np.count_nonzero(keys[1:] != keys[:-1])) + 1 if len(keys) else 0


def _voxel_side(points: np.ndarray, max_points: int, iterations: int, sample_factor: int = 20) -> float:
    """The smallest voxel side (to a factor 2^(10 / 2^iterations)) whose occupied voxels number at most
    max_points, searched on a fixed random sample of at most sample_factor * max_points points (with
    about 20 points per voxel, the sample occupies nearly the voxels the whole cloud does)."""
    if len(points) > sample_factor * max_points:
        points = points[np.random.default_rng(0).choice(len(points), sample_factor * max_points, replace=False)]
    bounds = points.min(0), points.max(0)
    extent = bounds[1] - bounds[0]
    box = float(np.cbrt(np.prod(np.where(extent > 0, extent, extent.max() or 1.0)) / max_points))
    lo, hi = box / 1000.0, box  # at the bounding box's side the voxels number about max_points
    while _count_voxels(points, hi, bounds) > max_points:
        lo, hi = hi, hi * 2.0
    for _ in range(iterations):
        mid = float(np.sqrt(lo * hi))
        if _count_voxels(points, mid, bounds) <= max_points:
            hi = mid
        else:
            lo = mid
    return hi
