"""Rigid transforms between the camera frames and the output (world) frame (REP 103: metres, right-handed)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation


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
        quaternion = values[3:]
        norm = np.linalg.norm(quaternion)
        if not np.isfinite(norm) or norm < 1e-9:
            raise ValueError("quaternion must be finite and non-zero")
        return cls(Rotation.from_quat(quaternion / norm).as_matrix(), values[:3])

    def as_xyz_quaternion(self) -> list[float]:
        """``[x, y, z, qx, qy, qz, qw]``."""
        return [*self.translation.tolist(), *Rotation.from_matrix(self.rotation).as_quat().tolist()]

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map points ``(..., 3)`` from the child to the parent frame."""
        return np.asarray(points) @ self.rotation.T + self.translation

    def apply_to_vectors(self, vectors: np.ndarray) -> np.ndarray:
        """Rotate free vectors ``(..., 3)`` (velocities, tangents) from the child to the parent frame."""
        return np.asarray(vectors) @ self.rotation.T

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


def quaternion_from_x_axis(direction: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of the least rotation taking the x axis onto ``direction``."""
    unit = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    w = 1.0 + unit[0]
    if w < 1e-9:  # opposite to x: half a turn about z
        return np.array([0.0, 0.0, 1.0, 0.0])
    quaternion = np.array([0.0, -unit[2], unit[1], w])  # axis x × unit, scaled so that the angle is halved
    return quaternion / np.linalg.norm(quaternion)
