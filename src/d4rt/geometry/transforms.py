"""Rigid transforms as 4x4 homogeneous matrices (numpy or torch, any leading shape)."""

from __future__ import annotations

import numpy as np
import torch

Array = np.ndarray | torch.Tensor


def invert_rigid(transform: Array) -> Array:
    """Inverse of rigid transforms [R | t]: [R^T | -R^T t]. transform: (..., 4, 4)."""
    rot = transform[..., :3, :3]
    trans = transform[..., :3, 3:]
    if isinstance(transform, torch.Tensor):
        rot_t = rot.transpose(-1, -2)
        out = torch.zeros_like(transform)
    else:
        rot_t = np.swapaxes(rot, -1, -2)
        out = np.zeros_like(transform)
    out[..., :3, :3] = rot_t
    out[..., :3, 3:] = -(rot_t @ trans)
    out[..., 3, 3] = 1
    return out


def apply_transform(transform: Array, points: Array) -> Array:
    """Apply 4x4 transforms to points. transform: (..., 4, 4); points: (..., 3) -> (..., 3).

    Written as explicit sums of products (no batched matmul) so results do not depend on the BLAS
    library or thread count: the synthetic engine promises bit-identical output for the same seed.
    """
    r, t = transform[..., :3, :3], transform[..., :3, 3]
    x, y, z = points[..., 0:1], points[..., 1:2], points[..., 2:3]
    return r[..., :, 0] * x + r[..., :, 1] * y + r[..., :, 2] * z + t


def apply_rotation(transform: Array, vectors: Array) -> Array:
    """Apply only the rotation part of (..., 4, 4) or (..., 3, 3) transforms to (..., 3) vectors."""
    r = transform[..., :3, :3]
    x, y, z = vectors[..., 0:1], vectors[..., 1:2], vectors[..., 2:3]
    return r[..., :, 0] * x + r[..., :, 1] * y + r[..., :, 2] * z


def similarity_times_pose(sim: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """A rigid pose (4, 4) after a Sim(3) ``sim`` (4, 4, [sR | t]) -> rigid (4, 4): the camera's rotation
    turns by R and its centre maps by the Sim(3) (a scale applies to positions, not to orientations)."""
    scale = np.cbrt(np.linalg.det(sim[:3, :3]))
    rot = sim[:3, :3] / scale
    out = np.eye(4)
    out[:3, :3] = rot @ pose[:3, :3]
    out[:3, 3] = sim[:3, :3] @ pose[:3, 3] + sim[:3, 3]
    return out


def rotation_about_axis(axis: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rodrigues' formula. axis: (3,) (normalised inside); angle: scalar or (...,) radians -> (..., 3, 3)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    angle = np.asarray(angle, dtype=np.float64)
    kx, ky, kz = axis
    k = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    s = np.sin(angle)[..., None, None]
    c = np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def rigid(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Assemble (..., 4, 4) transforms from rotations (..., 3, 3) and translations (..., 3)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    shape = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = np.zeros(shape + (4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def quaternion_to_rotation(quaternion_xyzw: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) in (x, y, z, w) order (TUM / ROS) -> rotation matrices (..., 3, 3).
    The quaternion is normalised first."""
    q = np.asarray(quaternion_xyzw, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) in (x, y, z, w) order with w >= 0
    (q and -q are the same rotation). Shepperd's method: divide by the largest of the four candidate
    components, so no case loses precision."""
    r = np.asarray(rotation, dtype=np.float64)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    trace = m00 + m11 + m22
    candidates = np.stack([1 + trace, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    pick = np.argmax(candidates, -1)
    s = 2.0 * np.sqrt(np.take_along_axis(candidates, pick[..., None], -1)[..., 0])  # 4 * |largest|
    d21, d02, d10 = r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]
    s01, s02, s12 = r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1]
    by_case = np.stack([
        np.stack([d21 / s, d02 / s, d10 / s, s / 4], -1),
        np.stack([s / 4, s01 / s, s02 / s, d21 / s], -1),
        np.stack([s01 / s, s / 4, s12 / s, d02 / s], -1),
        np.stack([s02 / s, s12 / s, s / 4, d10 / s], -1),
    ], -2)
    q = np.take_along_axis(by_case, pick[..., None, None], -2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return q * np.where(q[..., 3:] < 0, -1.0, 1.0)
