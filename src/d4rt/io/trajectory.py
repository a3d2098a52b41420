"""Camera trajectories in the TUM RGB-D text format (read by evo, the TUM benchmark tools, and most SLAM
evaluation scripts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) with w >= 0 of rotation matrices (..., 3, 3) -> (..., 4)."""
    from trimesh.transformations import quaternion_from_matrix  # here: importing trimesh takes 0.5 s

    flat = np.asarray(rotation, dtype=np.float64).reshape(-1, 3, 3)
    quats = np.stack([quaternion_from_matrix(r) for r in flat])
    quats *= np.where(quats[:, :1] < 0, -1.0, 1.0)  # q and -q are one rotation: pick w >= 0
    return quats.reshape(*np.shape(rotation)[:-2], 4)


def write_tum(path: str | Path, timestamps: np.ndarray, cam_to_world: np.ndarray) -> Path:
    """One line per frame: ``timestamp tx ty tz qx qy qz qw``, the camera-to-world pose (camera centre
    and orientation in the world). timestamps: (T,); cam_to_world: (T, 4, 4)."""
    quats = rotation_to_quaternion(cam_to_world[:, :3, :3])
    lines = ["# timestamp tx ty tz qx qy qz qw (camera-to-world, OpenCV camera axes; written by d4rt)"]
    for stamp, pose, (qw, qx, qy, qz) in zip(timestamps, cam_to_world, quats):
        tx, ty, tz = pose[:3, 3]
        lines.append(f"{stamp:.6f} {tx:.9g} {ty:.9g} {tz:.9g} {qx:.9g} {qy:.9g} {qz:.9g} {qw:.9g}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path
