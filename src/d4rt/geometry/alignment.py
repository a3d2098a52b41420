"""Least-squares similarity alignment of corresponding 3D point sets (Umeyama 1991), in float64 numpy."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from d4rt.errors import UserError


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation. rotation: (3, 3) proper; translation: (3,)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """points: (..., 3) -> (..., 3)."""
        return self.scale * points @ self.rotation.T + self.translation

    def apply_to_poses(self, cam_to_world: np.ndarray) -> np.ndarray:
        """Map camera-to-world poses (..., 4, 4) through the similarity: rotations turn, centres move and
        scale (evo's ``align(correct_scale=True)``: scale the translations, then apply the rigid part)."""
        out = np.array(cam_to_world, dtype=np.float64, copy=True)
        out[..., :3, :3] = self.rotation @ out[..., :3, :3]
        out[..., :3, 3] = self.apply(out[..., :3, 3])
        return out


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = True) -> Similarity:
    """The similarity (rigid if ``with_scale`` is False) minimising sum ||target - (s R source + t)||^2.

    source, target: (N, 3) corresponding points, N >= 1. This is the closed form of Umeyama (1991), as
    in evo's ``umeyama_alignment``. If the source points all coincide the scale is undefined; the optimum
    is then the constant map onto the target centroid (scale 0, identity rotation).
    """
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape or len(src) == 0:
        raise UserError(f"umeyama needs two (N, 3) point sets of equal shape, got {src.shape} and {dst.shape}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise UserError("umeyama: point sets contain NaN or infinite values")
    mean_src, mean_dst = src.mean(0), dst.mean(0)
    src_c, dst_c = src - mean_src, dst - mean_dst
    var_src = float((src_c ** 2).sum(1).mean())
    if var_src == 0.0:
        return Similarity(0.0 if with_scale else 1.0, np.eye(3), mean_dst - (0.0 if with_scale else 1.0) * mean_src)
    cov = dst_c.T @ src_c / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:  # reflection: flip the weakest axis
        sign[2, 2] = -1.0
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / var_src) if with_scale else 1.0
    return Similarity(scale, rotation, mean_dst - scale * rotation @ mean_src)
