"""Camera trajectories in the TUM RGB-D text format (read by evo, the TUM benchmark tools, and most SLAM
evaluation scripts): written for every reconstruction, read for ground truth and for known poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d4rt.errors import UserError
from d4rt.geometry.transforms import quaternion_to_rotation, rigid, rotation_to_quaternion


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


def read_tum_trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A TUM trajectory file -> (timestamps (N,), camera-to-world poses (N, 4, 4))."""
    path = Path(path)
    try:
        rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
        values = np.array(rows, dtype=np.float64)
    except (OSError, ValueError) as err:
        raise UserError(f"cannot read TUM trajectory {path}: {err}") from None
    if values.ndim != 2 or values.shape[1] != 8:
        raise UserError(f"{path}: TUM lines need 8 numbers (timestamp tx ty tz qx qy qz qw)")
    return values[:, 0], rigid(quaternion_to_rotation(values[:, 4:]), values[:, 1:4])


def nearest_poses(trajectory: tuple[np.ndarray, np.ndarray], timestamps: np.ndarray,
                  max_difference: float = 0.02) -> np.ndarray:
    """The pose nearest in time to each timestamp (TUM's association rule, at most 20 ms apart): (T, 4, 4)."""
    stamps, poses = trajectory
    index = np.abs(stamps[None, :] - timestamps[:, None]).argmin(1)
    gap = np.abs(stamps[index] - timestamps)
    if (gap > max_difference).any():
        worst = int(gap.argmax())
        raise UserError(f"no pose within {max_difference} s of frame time {timestamps[worst]:.4f} in the trajectory "
                        f"(its times run from {stamps.min():.4f} to {stamps.max():.4f})")
    return poses[index]


def load_known_poses(path: str | Path, source_frames: np.ndarray, timestamps: np.ndarray | None) -> np.ndarray:
    """Camera-to-world poses (T, 4, 4) of the frames used, from a file of your own: a TUM trajectory (.txt, matched
    to the frames by time, which needs ``timestamps`` (T,) in seconds) or a .npy of (N, 4, 4) matrices, one per
    frame of the source (indexed by ``source_frames`` (T,), the frames' numbers in the source)."""
    path = Path(path)
    if path.suffix == ".npy":
        try:
            poses = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as err:
            raise UserError(f"cannot read known poses {path}: {err}") from None
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise UserError(f"{path}: known poses must be (N, 4, 4) camera-to-world matrices, got shape {poses.shape}")
        if int(np.max(source_frames)) >= len(poses):
            raise UserError(f"{path} holds {len(poses)} poses but source frame {int(np.max(source_frames))} is used "
                            "(one pose per frame of the source, in order)")
        return poses[np.asarray(source_frames)].astype(np.float64)
    if path.suffix != ".txt":
        raise UserError(f"known poses must be a TUM trajectory (.txt) or a .npy of (N, 4, 4) matrices, got {path.name}")
    if timestamps is None:
        raise UserError(f"a TUM trajectory ({path.name}) is matched to the frames by time, and these frames have no "
                        "clock (a video file or an image folder named by times has one): give a .npy of (N, 4, 4) "
                        "poses instead")
    return nearest_poses(read_tum_trajectory(path), np.asarray(timestamps, dtype=np.float64))
