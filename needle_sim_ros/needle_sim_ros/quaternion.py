"""Unit-quaternion helpers (x, y, z, w order, as in ROS) for one quaternion at a time, compiled (numba).

They run inside the compiled base-trajectory kernels, per pose sample: they take arrays or tuples and return
tuples, so a chain of them allocates no temporary arrays (a 4-element array per call made the window fit ~1.6x
slower). Cheap to call from Python too (~1 µs; scipy's Rotation costs ~50 µs per construction, too much for a 1 kHz
loop). The rotation matrix of a quaternion is :func:`needle_sim_ros.model.kinematics.quaternion_matrix`.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def multiply(a, b) -> tuple[float, float, float, float]:
    """Hamilton product a * b (the rotation b followed by a)."""
    ax, ay, az, aw = a[0], a[1], a[2], a[3]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


@njit(cache=True)
def conjugate(q) -> tuple[float, float, float, float]:
    """Inverse of a unit quaternion."""
    return -q[0], -q[1], -q[2], q[3]


@njit(cache=True)
def to_rotation_vector(q) -> tuple[float, float, float]:
    """Rotation vector (axis times angle in [0, pi]) of a unit quaternion."""
    sign = -1.0 if q[3] < 0.0 else 1.0  # q and -q are the same rotation: take the short way
    x, y, z, w = sign * q[0], sign * q[1], sign * q[2], sign * q[3]
    n = np.sqrt(x * x + y * y + z * z)
    # 2 atan2(n, w) / n -> 2 / w for n -> 0 (error O(n^2), below round-off at n < 1e-8)
    factor = 2.0 / w if n < 1e-8 else 2.0 * np.arctan2(n, w) / n
    return x * factor, y * factor, z * factor


@njit(cache=True)
def from_rotation_vector(r) -> tuple[float, float, float, float]:
    """Unit quaternion of a rotation vector."""
    angle = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    # sin(angle/2) / angle -> 1/2 - angle^2/48 for small angles
    factor = 0.5 - angle * angle / 48.0 if angle < 1e-8 else np.sin(0.5 * angle) / angle
    return r[0] * factor, r[1] * factor, r[2] * factor, np.cos(0.5 * angle)
