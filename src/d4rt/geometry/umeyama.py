"""Least-squares similarity / rigid alignment of corresponding point sets (Umeyama, 1991)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from d4rt.errors import UserError


@dataclass
class Similarity:
    """dst ~= scale * rotation @ src + translation. rotation: (3, 3); translation: (3,)."""

    rotation: torch.Tensor
    translation: torch.Tensor
    scale: torch.Tensor

    def matrix(self) -> torch.Tensor:
        """As a 4x4 matrix [s R | t]."""
        m = torch.eye(4, dtype=self.rotation.dtype, device=self.rotation.device)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = self.translation
        return m

    def apply(self, points: torch.Tensor) -> torch.Tensor:
        """points: (..., 3) -> (..., 3)."""
        return self.scale * points @ self.rotation.T + self.translation


def umeyama(src: torch.Tensor, dst: torch.Tensor, weights: torch.Tensor | None = None,
            with_scale: bool = False, allow_degenerate: bool = False) -> Similarity:
    """The rotation, translation (and scale, if ``with_scale``) minimising
    sum_i w_i |dst_i - (s R src_i + t)|^2. src, dst: (N, 3); weights: (N,) non-negative.

    The rotation is always proper (det +1): the reflection that can solve degenerate or noisy inputs
    is excluded by the sign correction of the SVD. Planar point sets (rank 2) still give the exact
    rotation; fewer than 3 non-collinear points, or zero total weight, raise an error. Computed in
    float64 and returned in src's dtype.

    ``allow_degenerate=True`` (trajectory evaluation, like evo's alignment) accepts collinear points and
    as few as one: the residual is still minimised, though the rotation about the line is then not
    unique; if the source points coincide the best similarity maps them all onto the target centroid
    (scale 0).
    """
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise UserError(f"umeyama needs two (N, 3) point sets, got {tuple(src.shape)} and {tuple(dst.shape)}")
    x, y = src.double(), dst.double()
    w = torch.ones(len(x), dtype=torch.float64, device=x.device) if weights is None else weights.double()
    finite = torch.isfinite(x).all(1) & torch.isfinite(y).all(1) & torch.isfinite(w) & (w > 0)
    x, y, w = x[finite], y[finite], w[finite]
    min_points = 1 if allow_degenerate else 3
    if len(x) < min_points or w.sum() <= 0:
        raise UserError(f"umeyama needs at least {min_points} weighted, finite correspondences, got {len(x)}")
    w = w / w.sum()
    mx, my = w @ x, w @ y
    xc, yc = x - mx, y - my
    cov = (yc * w[:, None]).T @ xc  # (3, 3): sum_i w_i y_i x_i^T
    u, sing, vt = torch.linalg.svd(cov)
    if not allow_degenerate and sing[1] <= 1e-12 * max(sing[0].item(), 1e-300):
        raise UserError("umeyama: the points are collinear (or coincide); a rotation is not determined")
    d = torch.ones(3, dtype=torch.float64, device=x.device)
    if torch.linalg.det(u) * torch.linalg.det(vt) < 0:
        d[2] = -1.0
    rot = u @ torch.diag(d) @ vt
    if with_scale:
        var_x = (w * (xc * xc).sum(1)).sum()
        scale = (sing * d).sum() / var_x if var_x > 0 else torch.zeros((), dtype=torch.float64, device=x.device)
    else:
        scale = torch.ones((), dtype=torch.float64, device=x.device)
    trans = my - scale * rot @ mx
    dt = src.dtype if src.is_floating_point() else torch.float64
    return Similarity(rot.to(dt), trans.to(dt), scale.to(dt))
