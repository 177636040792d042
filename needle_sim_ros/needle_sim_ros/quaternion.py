"""Unit-quaternion helpers (x, y, z, w order, as in ROS), vectorized over leading axes.

Plain numpy: scipy's Rotation costs ~50 µs per construction, too much for a 1 kHz loop that handles several
rotations per step.
"""
from __future__ import annotations

import numpy as np


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (the rotation b followed by a)."""
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion."""
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def to_rotation_vector(q: np.ndarray) -> np.ndarray:
    """Rotation vector (axis times angle in [0, pi]) of unit quaternions."""
    q = np.where(q[..., 3:] < 0.0, -q, q)  # q and -q are the same rotation: take the short way
    v, w = q[..., :3], q[..., 3]
    n = np.linalg.norm(v, axis=-1)
    small = n < 1e-8
    # 2 atan2(n, w) / n -> 2 / w for n -> 0 (error O(n^2), below round-off at n < 1e-8)
    factor = np.where(small, 2.0 / np.where(small, w, 1.0), 2.0 * np.arctan2(n, w) / np.where(small, 1.0, n))
    return v * factor[..., None]


def from_rotation_vector(r: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors."""
    angle = np.linalg.norm(r, axis=-1)
    half = 0.5 * angle
    small = angle < 1e-8
    # sin(angle/2) / angle -> 1/2 - angle^2/48 for small angles
    factor = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([r * factor[..., None], np.cos(half)[..., None]], axis=-1)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of one unit quaternion."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
