"""Camera trajectories in the TUM RGB-D text format (read by evo, the TUM benchmark tools, and most SLAM
evaluation scripts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.geometry.transforms import rotation_to_quaternion


def write_tum(path: str | Path, timestamps: np.ndarray, cam_to_world: np.ndarray) -> Path:
    """One line per frame: ``timestamp tx ty tz qx qy qz qw``, the camera-to-world pose (camera centre
    and orientation in the world). timestamps: (T,); cam_to_world: (T, 4, 4)."""
    quats = rotation_to_quaternion(cam_to_world[:, :3, :3])
    lines = ["# timestamp tx ty tz qx qy qz qw (camera-to-world, OpenCV camera axes; written by d4rt)"]
    for stamp, pose, (qx, qy, qz, qw) in zip(timestamps, cam_to_world, quats):
        tx, ty, tz = pose[:3, 3]
        lines.append(f"{stamp:.6f} {tx:.9g} {ty:.9g} {tz:.9g} {qx:.9g} {qy:.9g} {qz:.9g} {qw:.9g}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path
