"""Quaternions (x, y, z, w: ROS order) and rigid transforms: the suite's one module for them.

The single-quaternion helpers are compiled (numba): they run inside the compiled base-trajectory and kinematics
kernels, per pose sample, and take arrays or tuples; those returning tuples allocate no temporary arrays (a
4-element array per call made the window fit ~1.6x slower). Cheap to call from Python too (~1 us; scipy's Rotation
costs ~50 us per construction, too much for a 1 kHz loop). :class:`RigidTransform` maps points between frames
(REP 103: metres, right-handed).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

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


@njit(cache=True)
def quaternion_matrix(quaternion: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = quaternion[0], quaternion[1], quaternion[2], quaternion[3]
    return np.array((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),  # flat: compiled, one
                     2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),  # allocation (nested
                     2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y))).reshape(3, 3)  # lists: 9)


@njit(cache=True)
def matrix_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0 of a rotation matrix (Shepperd's method)."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    k = 0
    best = trace
    for i in range(3):
        if m[i, i] > best:
            best = m[i, i]
            k = i + 1
    if k == 0:
        w = 0.5 * np.sqrt(1.0 + trace)
        x, y, z = (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w)
    elif k == 1:
        x = 0.5 * np.sqrt(1.0 + 2 * m[0, 0] - trace)
        w, y, z = (m[2, 1] - m[1, 2]) / (4 * x), (m[0, 1] + m[1, 0]) / (4 * x), (m[0, 2] + m[2, 0]) / (4 * x)
    elif k == 2:
        y = 0.5 * np.sqrt(1.0 + 2 * m[1, 1] - trace)
        w, x, z = (m[0, 2] - m[2, 0]) / (4 * y), (m[0, 1] + m[1, 0]) / (4 * y), (m[1, 2] + m[2, 1]) / (4 * y)
    else:
        z = 0.5 * np.sqrt(1.0 + 2 * m[2, 2] - trace)
        w, x, y = (m[1, 0] - m[0, 1]) / (4 * z), (m[0, 2] + m[2, 0]) / (4 * z), (m[1, 2] + m[2, 1]) / (4 * z)
    quaternion = np.array([x, y, z, w])
    quaternion /= np.sqrt(x * x + y * y + z * z + w * w)
    if w < 0.0:
        quaternion = -quaternion
    return quaternion


def unit_quaternion(value, name: str = "orientation") -> np.ndarray:
    """A finite quaternion (x, y, z, w) of norm 1 (within 1e-6), renormalized; ValueError otherwise."""
    quaternion = np.asarray(value, dtype=float)
    if quaternion.shape != (4,) or not np.all(np.isfinite(quaternion)):
        raise ValueError(f"{name} must be 4 finite numbers, got {value!r}")
    return normalized_unit_quaternion(quaternion, name)


def normalized_unit_quaternion(quaternion: np.ndarray, name: str) -> np.ndarray:
    """A finite float quaternion (4,) of norm 1 within 1e-6, renormalized; ValueError naming ``name`` otherwise."""
    norm = math.sqrt(float(quaternion @ quaternion))
    if abs(norm - 1.0) > 1e-6:
        raise ValueError(f"{name} must be a unit quaternion (x, y, z, w), got norm {norm:.9g}")
    return quaternion / norm


def nonzero_quaternion(quaternion: Sequence[float]) -> bool:
    """Whether a quaternion (x, y, z, w) is finite and non-zero (norm >= 1e-9): one a transform normalizes."""
    norm = float(np.linalg.norm(quaternion))
    return math.isfinite(norm) and norm >= 1e-9


def quaternions_from_x_axes(directions: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of the least rotations taking the x axis onto each of ``directions`` (..., 3)."""
    unit = np.asarray(directions, dtype=float)
    unit = unit / np.linalg.norm(unit, axis=-1, keepdims=True)
    w = 1.0 + unit[..., 0]
    quaternions = np.stack([np.zeros_like(w), -unit[..., 2], unit[..., 1], w], axis=-1)  # axis e_x x unit
    quaternions[w < 1e-9] = [0.0, 0.0, 1.0, 0.0]  # opposite to x: half a turn about z
    return quaternions / np.linalg.norm(quaternions, axis=-1, keepdims=True)


def rotate(quaternion: Sequence[float], vector: Sequence[float]) -> tuple[float, float, float]:
    """``vector`` rotated by the unit quaternion (x, y, z, w): v + 2w (q x v) + 2 q x (q x v)."""
    x, y, z, w = quaternion
    vx, vy, vz = vector
    cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    return (vx + 2 * (w * cx + y * cz - z * cy), vy + 2 * (w * cy + z * cx - x * cz),
            vz + 2 * (w * cz + x * cy - y * cx))


@dataclass(frozen=True)
class RigidTransform:
    """Pose of a child frame in a parent frame: ``x_parent = rotation @ x_child + translation``."""

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        rotation = np.asarray(self.rotation, dtype=float).reshape(3, 3)
        translation = np.asarray(self.translation, dtype=float).reshape(3)
        if not (np.all(np.isfinite(rotation)) and np.all(np.isfinite(translation))):
            raise ValueError("RigidTransform: rotation and translation must be finite")
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
            raise ValueError("RigidTransform: rotation is not a proper rotation matrix")
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "translation", translation)

    @classmethod
    def from_xyz_quaternion(cls, xyz_quaternion: Sequence[float]) -> "RigidTransform":
        """From ``[x, y, z, qx, qy, qz, qw]`` (metres, quaternion normalized here; zero quaternion rejected)."""
        values = np.asarray(xyz_quaternion, dtype=float).reshape(7)
        if not nonzero_quaternion(values[3:]):
            raise ValueError("quaternion must be finite and non-zero")
        return cls(quaternion_matrix(values[3:] / np.linalg.norm(values[3:])), values[:3])

    def as_xyz_quaternion(self) -> list[float]:
        """``[x, y, z, qx, qy, qz, qw]`` (qw >= 0)."""
        return [*self.translation.tolist(), *matrix_quaternion(self.rotation).tolist()]

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map points ``(..., 3)`` from the child to the parent frame."""
        return np.asarray(points) @ self.rotation.T + self.translation

    def inverse(self) -> "RigidTransform":
        return RigidTransform(self.rotation.T, -self.rotation.T @ self.translation)

    def compose(self, other: "RigidTransform") -> "RigidTransform":
        """``self ∘ other``: maps other's child frame into self's parent frame."""
        return RigidTransform(self.rotation @ other.rotation, self.rotation @ other.translation + self.translation)


def look_at_rotation(forward: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Rotation (columns = optical x, y, z axes in the parent frame) of a camera looking along ``forward``
    whose image x axis is as close as possible to ``right`` (optical frame: z forward, x right, y down)."""
    z = np.asarray(forward, dtype=float)
    z = z / np.linalg.norm(z)
    x = np.asarray(right, dtype=float) - np.dot(right, z) * z
    x = x / np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])
