"""Camera trajectories in the TUM RGB-D text format (read by evo, the TUM benchmark tools, and most SLAM
evaluation scripts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.geometry.transforms import rotation_to_quaternion


HEADER = "# timestamp tx ty tz qx qy qz qw (camera-to-world, OpenCV camera axes; written by d4rt)\n"


def tum_lines(timestamps: np.ndarray, cam_to_world: np.ndarray) -> list[str]:
    """One line per frame (with its newline): ``timestamp tx ty tz qx qy qz qw``, the camera-to-world pose
    (camera centre and orientation in the world). timestamps: (T,); cam_to_world: (T, 4, 4)."""
    quats = rotation_to_quaternion(cam_to_world[:, :3, :3])
    lines = []
    for stamp, pose, (qx, qy, qz, qw) in zip(timestamps, cam_to_world, quats):
        tx, ty, tz = pose[:3, 3]
        lines.append(f"{stamp:.6f} {tx:.9g} {ty:.9g} {tz:.9g} {qx:.9g} {qy:.9g} {qz:.9g} {qw:.9g}\n")
    return lines


def write_tum(path: str | Path, timestamps: np.ndarray, cam_to_world: np.ndarray) -> Path:
    """The whole trajectory as a TUM file (:func:`tum_lines` under a header line)."""
    path = Path(path)
    path.write_text(HEADER + "".join(tum_lines(timestamps, cam_to_world)))
    return path
