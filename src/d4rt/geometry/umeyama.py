"""Least-squares similarity / rigid alignment of corresponding point sets (Umeyama, 1991)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from d4rt.errors import DegenerateFit, UserError


@dataclass
class Similarity:
    """dst ~= scale * rotation @ src + translation. rotation: (..., 3, 3); translation: (..., 3);
    scale: (...) (one similarity, or a batch of them from :func:`batched_umeyama`)."""

    rotation: torch.Tensor
    translation: torch.Tensor
    scale: torch.Tensor

    def matrix(self) -> torch.Tensor:
        """As (..., 4, 4) matrices [s R | t]."""
        batch = self.rotation.shape[:-2]
        m = torch.eye(4, dtype=self.rotation.dtype, device=self.rotation.device).expand(*batch, 4, 4).clone()
        m[..., :3, :3] = self.scale[..., None, None] * self.rotation
        m[..., :3, 3] = self.translation
        return m

    def apply(self, points: torch.Tensor) -> torch.Tensor:
        """points: (N, 3) -> (N, 3) (one similarity)."""
        return self.scale * points @ self.rotation.T + self.translation


def umeyama(src: torch.Tensor, dst: torch.Tensor, weights: torch.Tensor | None = None,
            with_scale: bool = False, allow_degenerate: bool = False) -> Similarity:
    """The rotation, translation (and scale, if ``with_scale``) minimising
    sum_i w_i |dst_i - (s R src_i + t)|^2. src, dst: (N, 3); weights: (N,) non-negative.

    The rotation is always proper (det +1): the reflection that can solve degenerate or noisy inputs
    is excluded by the sign correction of the SVD. Planar point sets (rank 2) still give the exact
    rotation; fewer than 3 non-collinear points, or zero total weight, raise an error. Non-finite points
    and non-positive weights are left out. Computed in float64 and returned in src's dtype.

    ``allow_degenerate=True`` (trajectory evaluation, like evo's alignment) accepts collinear points and
    as few as one: the residual is still minimised, though the rotation about the line is then not
    unique; if the source points coincide the best similarity maps them all onto the target centroid
    (scale 0).
    """
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise UserError(f"umeyama needs two (N, 3) point sets, got {tuple(src.shape)} and {tuple(dst.shape)}")
    fit = batched_umeyama(src[None], dst[None], None if weights is None else weights[None], with_scale,
                          allow_degenerate)
    return Similarity(fit.rotation[0], fit.translation[0], fit.scale[0])


def batched_umeyama(src: torch.Tensor, dst: torch.Tensor, weights: torch.Tensor | None = None,
                    with_scale: bool = False, allow_degenerate: bool = False) -> Similarity:
    """:func:`umeyama` of F independent point-set pairs at once (one batched SVD, no Python loop).

    src, dst: (F, N, 3); weights: (F, N). Returns a :class:`Similarity` with rotation (F, 3, 3),
    translation (F, 3), scale (F,). Left-out points (non-finite, weight <= 0) get weight 0, which is the
    same fit as removing them. Any pair without enough points, or collinear, raises as :func:`umeyama`.
    """
    if src.shape != dst.shape or src.ndim != 3 or src.shape[2] != 3:
        raise UserError(f"batched_umeyama needs two (F, N, 3) point sets, got {tuple(src.shape)} and "
                        f"{tuple(dst.shape)}")
    x, y = src.double(), dst.double()
    w = torch.ones(x.shape[:2], dtype=torch.float64, device=x.device) if weights is None else weights.double()
    keep = torch.isfinite(x).all(-1) & torch.isfinite(y).all(-1) & torch.isfinite(w) & (w > 0)
    x, y = torch.where(keep[..., None], x, 0.0), torch.where(keep[..., None], y, 0.0)
    w = torch.where(keep, w, 0.0)
    min_points = 1 if allow_degenerate else 3
    total, count = w.sum(-1), keep.sum(-1)
    short = (count < min_points) | (total <= 0)
    if bool(short.any()):
        got = int(count[short.nonzero()[0, 0]])
        raise DegenerateFit(f"umeyama needs at least {min_points} weighted, finite correspondences, got {got}")
    w = w / total[:, None]
    mx, my = (w[..., None] * x).sum(1), (w[..., None] * y).sum(1)  # (F, 3)
    xc, yc = x - mx[:, None], y - my[:, None]
    cov = (yc * w[..., None]).transpose(1, 2) @ xc  # (F, 3, 3): sum_i w_i y_i x_i^T
    u, sing, vt = torch.linalg.svd(cov)
    if not allow_degenerate and bool((sing[:, 1] <= 1e-12 * sing[:, 0].clamp(min=1e-300)).any()):
        raise DegenerateFit("umeyama: the points are collinear (or coincide); a rotation is not determined")
    d = torch.ones(len(cov), 3, dtype=torch.float64, device=x.device)
    d[:, 2] = torch.where(torch.linalg.det(u) * torch.linalg.det(vt) < 0, -1.0, 1.0)
    rot = u @ torch.diag_embed(d) @ vt
    if with_scale:
        var_x = (w * (xc * xc).sum(-1)).sum(-1)
        scale = torch.where(var_x > 0, (sing * d).sum(-1) / var_x.clamp(min=1e-300), 0.0)
    else:
        scale = torch.ones(len(cov), dtype=torch.float64, device=x.device)
    trans = my - scale[:, None] * (rot @ mx[..., None])[..., 0]
    dt = src.dtype if src.is_floating_point() else torch.float64
    return Similarity(rot.to(dt), trans.to(dt), scale.to(dt))
