"""Cameras from query answers (paper Sec. 2.1): intrinsics from points seen in their own frame, and
relative poses from the same points at the same time expressed in two cameras."""

from __future__ import annotations

import numpy as np
import torch

from d4rt.errors import DegenerateFit, UserError
from d4rt.geometry.umeyama import batched_umeyama


def intrinsics_from_points(points: np.ndarray, uv: np.ndarray, confidence: np.ndarray, height: int, width: int,
                           method: str = "median", square: bool = False) -> np.ndarray:
    """Pinhole intrinsics from points seen in their own frame, in that frame's camera.

    points: (N, 3) camera-frame points of the pixels at normalised positions uv: (N, 2) (of one frame,
    or of several frames that share one camera); confidence: (N,) (<= 0 or non-finite: unused).
    Returns K (3, 3) in pixels for a height x width image.

    - "median" (the paper's recipe): principal point at the image centre, fx = median of
      z (u - 0.5) / x over the points (and fy likewise), in normalised units, then times W (H). Points
      close to the central column (row) are left out: there the ratio is 0 / 0.
    - "lstsq": least squares of x_pix = fx * X / Z + cx (and y likewise), weighted by confidence:
      exact for an off-centre principal point too (e.g. after a crop).

    square: one focal length for both axes (square pixels, fx = fy), fitted to the x and y
    observations together; otherwise fx and fy are fitted separately.
    """
    ok = np.isfinite(points).all(1) & np.isfinite(uv).all(1) & np.isfinite(confidence) & (confidence > 0)
    ok &= points[:, 2] > 0
    p, uv, c = points[ok], uv[ok], confidence[ok]
    if len(p) < 4:
        raise DegenerateFit(f"too few valid points ({len(p)}) to estimate intrinsics")
    a, b = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    x_pix, y_pix = uv[:, 0] * width - 0.5, uv[:, 1] * height - 0.5
    if method == "median":
        fx_all = _focal_ratios(uv[:, 0] - 0.5, a) * width
        fy_all = _focal_ratios(uv[:, 1] - 0.5, b) * height
        if square:
            fx = fy = _median_focal(np.concatenate([fx_all, fy_all]))
        else:
            fx, fy = _median_focal(fx_all), _median_focal(fy_all)
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    elif method == "lstsq":
        if square:
            fx, cx, cy = _weighted_square_fit(a, b, x_pix, y_pix, c)
            fy = fx
        else:
            fx, cx = _weighted_line(a, x_pix, c)
            fy, cy = _weighted_line(b, y_pix, c)
    else:
        raise UserError(f"intrinsics method must be 'median' or 'lstsq', got {method!r}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _focal_ratios(offset: np.ndarray, ratio: np.ndarray, min_offset: float = 0.05) -> np.ndarray:
    """offset / ratio (a normalised focal length) for the points far enough from the centre line."""
    keep = (np.abs(offset) > min_offset) & (np.abs(ratio) > 1e-9)
    return offset[keep] / ratio[keep]


def _median_focal(values: np.ndarray) -> float:
    if not len(values):
        raise DegenerateFit("no points far enough from the image centre to estimate the focal length")
    return float(np.median(values))


def _weighted_square_fit(a: np.ndarray, b: np.ndarray, x: np.ndarray, y: np.ndarray,
                         w: np.ndarray) -> tuple[float, float, float]:
    """f, cx, cy of the weighted least-squares fit x = f a + cx, y = f b + cy (one focal length)."""
    sw = np.sqrt(np.concatenate([w, w]))
    zeros, ones = np.zeros_like(a), np.ones_like(a)
    design = np.concatenate([np.stack([a, ones, zeros], 1), np.stack([b, zeros, ones], 1)]) * sw[:, None]
    (f, cx, cy), *_ = np.linalg.lstsq(design, np.concatenate([x, y]) * sw, rcond=None)
    return float(f), float(cx), float(cy)


def _weighted_line(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Slope and intercept of the weighted least-squares line y = m x + q."""
    sw = np.sqrt(w)
    design = np.stack([x, np.ones_like(x)], 1) * sw[:, None]
    (m, q), *_ = np.linalg.lstsq(design, y * sw, rcond=None)
    return float(m), float(q)


def relative_poses(points_here: np.ndarray, points_there: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per frame, the rigid transform (4, 4) taking camera-"here" coordinates to camera-"there"
    coordinates, from the same points at the same time expressed in both cameras; all frames in one
    batched SVD (no Python loop over them).

    points_here, points_there: (F, N, 3); weights: (F, N) (non-finite points or weights, or weights
    <= 0, are left out per frame). Returns (F, 4, 4); a frame with fewer than 3 usable points, or
    collinear ones, raises :class:`UserError` (see :func:`d4rt.geometry.umeyama.batched_umeyama`).
    """
    sim = batched_umeyama(*(torch.from_numpy(np.asarray(a, dtype=np.float64))
                            for a in (points_here, points_there, weights)))
    return sim.matrix().numpy()


def pose_graph(num_frames: int, edges: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Every frame's camera-to-world pose (the world: camera 0) from relative fits between pairs of frames, by
    linear least squares: rotations first (chordal averaging, each projected onto SO(3)), then positions.

    edges: (E, 2) int frame pairs (i, j); transforms: (E, 4, 4), each taking camera-i coordinates to camera-j
    coordinates (as :func:`relative_poses` returns). Every frame must be joined to frame 0 through the edges.
    Returns (num_frames, 4, 4). Exact when the fits agree (a chain of adjacent fits alone gives the chained poses).
    Why linear: with camera-to-world R_i, c_i, a fit (A, b) says R_i = R_j A and c_i - c_j = R_j b, both linear
    in the unknowns, so one dense solve per stage answers a clip's few dozen frames at once.
    """
    edges = np.asarray(edges, dtype=np.int64)
    if edges.ndim != 2 or edges.shape[1] != 2 or len(edges) != len(transforms):
        raise ValueError(f"edges must be (E, 2) beside transforms (E, 4, 4), got {edges.shape} and {np.shape(transforms)}")
    if num_frames == 1:
        return np.eye(4)[None]
    unknown = num_frames - 1  # frame 0 is fixed at the identity
    rows = 3 * len(edges)
    # Rotation rows: R_i^T - A^T R_j^T = 0, for each of the 3 columns of R^T (rows of R) at once.
    m = np.zeros((rows, 3 * unknown))
    rhs = np.zeros((rows, 3))
    for e, ((i, j), t) in enumerate(zip(edges, transforms)):
        block = slice(3 * e, 3 * e + 3)
        for frame, coef in ((i, np.eye(3)), (j, -t[:3, :3].T)):
            if frame == 0:
                rhs[block] -= coef  # R_0 = I moves to the right-hand side
            else:
                m[block, 3 * (frame - 1):3 * frame] += coef
    _check_connected(m, num_frames)
    solution = np.linalg.lstsq(m, rhs, rcond=None)[0]  # (3 * unknown, 3): stacked R_i^T
    rotations = np.concatenate([np.eye(3)[None], solution.reshape(unknown, 3, 3).transpose(0, 2, 1)])
    u, _, vt = np.linalg.svd(rotations)
    flip = np.sign(np.linalg.det(u @ vt))
    rotations = u @ (vt * np.stack([np.ones_like(flip), np.ones_like(flip), flip], -1)[..., None])
    # Position rows: c_i - c_j = R_j b.
    m = np.zeros((rows, 3 * unknown))
    rhs = np.zeros(rows)
    for e, ((i, j), t) in enumerate(zip(edges, transforms)):
        block = slice(3 * e, 3 * e + 3)
        rhs[block] = rotations[j] @ t[:3, 3]
        for frame, sign in ((i, 1.0), (j, -1.0)):
            if frame:
                m[block, 3 * (frame - 1):3 * frame] += sign * np.eye(3)
    centres = np.concatenate([np.zeros((1, 3)), np.linalg.lstsq(m, rhs, rcond=None)[0].reshape(unknown, 3)])
    poses = np.broadcast_to(np.eye(4), (num_frames, 4, 4)).copy()
    poses[:, :3, :3], poses[:, :3, 3] = rotations, centres
    return poses


def _check_connected(design: np.ndarray, num_frames: int) -> None:
    """A frame no edge ties to frame 0 leaves the least squares underdetermined: name it instead of guessing."""
    if np.linalg.matrix_rank(design) < design.shape[1]:
        raise UserError(f"pose graph: not every one of the {num_frames} frames is joined to frame 0 by a fit")
