"""Carrying a reconstruction into the world and units of known camera poses (from SLAM, a motion-capture system,
GPS/IMU, a dataset's ground truth): the Sim(3) that maps the estimated cameras onto the known ones.

The rotation comes from the cameras' orientations, not from their centres, so that a camera moving along a straight
line (whose centres leave the rotation about that line free) is aligned as well as any other; the scale and
translation are then the least-squares fit of the known centres to the rotated estimated ones.
"""

from __future__ import annotations

import numpy as np

from d4rt.errors import UserError


def similarity_to_known_poses(estimated: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, float]:
    """estimated, known: (T, 4, 4) camera-to-world poses of the same frames.

    Returns ``(sim (4, 4) [sR | t], rms)``: sim carries the estimated world onto the known one (a point x goes to
    s R x + t, a pose P to ``similarity_times_pose(sim, P)``); R is the rotation nearest to the mean of
    R_known_i R_estimated_i^T (chordal mean), s and t minimise sum_i |c_known_i - (s R c_estimated_i + t)|^2 over
    the camera centres c; rms is the root-mean-square distance left between the known centres and the mapped
    estimated ones, in the known units. A one-line error if the poses cannot fix a scale (a camera that does not
    move in either) or the fitted scale is not positive.
    """
    estimated, known = np.asarray(estimated, dtype=np.float64), np.asarray(known, dtype=np.float64)
    if known.shape != estimated.shape or known.ndim != 3 or known.shape[1:] != (4, 4):
        raise UserError(f"known poses must be ({len(estimated)}, 4, 4) camera-to-world matrices, one per frame, got "
                        f"shape {known.shape}")
    if not np.isfinite(known).all():
        raise UserError("known poses contain NaN or infinite values")
    rotations = known[:, :3, :3]
    if np.abs(rotations @ np.swapaxes(rotations, 1, 2) - np.eye(3)).max() > 1e-4:
        raise UserError("known poses must be rigid: their 3x3 rotation blocks are not orthonormal")
    u, _, vt = np.linalg.svd((rotations @ np.swapaxes(estimated[:, :3, :3], 1, 2)).sum(0))
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    mapped = estimated[:, :3, 3] @ rotation.T
    target = known[:, :3, 3]
    mapped_c, target_c = mapped - mapped.mean(0), target - target.mean(0)
    spread_known = float(np.sqrt((target_c ** 2).sum(1).mean()))
    spread_estimated = float(np.sqrt((mapped_c ** 2).sum(1).mean()))
    if len(known) < 2 or spread_known == 0 or spread_estimated < 1e-12:
        raise UserError("the camera does not move in the known poses (or in the estimate), so they cannot fix the "
                        "scale: give the scale itself instead (--scale)")
    scale = float((target_c * mapped_c).sum() / (mapped_c ** 2).sum())
    if not scale > 0:
        raise UserError("the estimated camera path runs against the known one (fitted scale <= 0): the estimate is too "
                        "poor to carry into the known poses' world; give the scale itself instead (--scale)")
    sim = np.eye(4)
    sim[:3, :3] = scale * rotation
    sim[:3, 3] = target.mean(0) - scale * mapped.mean(0)
    rms = float(np.sqrt(((target - (scale * mapped + sim[:3, 3])) ** 2).sum(1).mean()))
    return sim, rms
