"""Rigid-body kinematics of the needle holder (seed 000 Fig. 3: frame f at the clamp point A) and of clamped nodes.

A frame moving rigidly with position p, rotation R, twist (v, w) and acceleration (a, alpha) -- all in the world
frame, v and a of the frame origin -- carries a node with frame coordinates (rho, tau) at
    r   = p + R rho,            r_x   = R tau
    r'  = v + w x d,            r_x'  = w x R tau                           (d = R rho)
    r'' = a + alpha x d + w x (w x d),   r_x'' = alpha x R tau + w x (w x R tau).
The base node A is such a node with rho = 0, tau = e_x: it prescribes q_c = [r_A, r_xA] (eqs. 18-19).
Quaternions are in ROS order (x, y, z, w) (:mod:`needle_common.transforms`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from needle_common.transforms import matrix_quaternion, normalized_unit_quaternion, quaternion_matrix, unit_quaternion

from .banded import NO_REFCOUNTS

_ZERO3 = (0.0, 0.0, 0.0)


_FIELDS = (("position", slice(0, 3)), ("orientation", slice(3, 7)), ("linear_velocity", slice(7, 10)),
           ("angular_velocity", slice(10, 13)), ("linear_acceleration", slice(13, 16)),
           ("angular_acceleration", slice(16, 19)))
_SLICES = dict(_FIELDS)


@dataclass(frozen=True, eq=False)
class BaseMotion:
    """Pose, twist and acceleration of a rigid frame in the world frame -- for the needle base, of frame f at the
    clamp point A (x axis along the undeformed needle).  Velocities and accelerations are world-frame vectors;
    linear ones are those of the frame origin."""

    position: np.ndarray
    orientation: np.ndarray
    linear_velocity: np.ndarray = _ZERO3
    angular_velocity: np.ndarray = _ZERO3
    linear_acceleration: np.ndarray = _ZERO3
    angular_acceleration: np.ndarray = _ZERO3
    rotation: np.ndarray = field(init=False, repr=False, compare=False)
    packed: np.ndarray = field(init=False, repr=False, compare=False)  # the six fields' buffer (19,): views of it

    def __post_init__(self) -> None:
        # one packed buffer: validation and conversion of all six fields with few numpy calls (hot path)
        values = np.empty(19)
        for name, part in _FIELDS:
            try:
                values[part] = getattr(self, name)
            except (ValueError, TypeError):
                raise ValueError(f"BaseMotion.{name} must be {part.stop - part.start} numbers, "
                                 f"got {getattr(self, name)!r}") from None
        if not math.isfinite(values.sum()):
            bad = [name for name, part in _FIELDS if not np.all(np.isfinite(values[part]))]
            raise ValueError(f"BaseMotion.{bad[0]} must be finite, got {getattr(self, bad[0])!r}")
        values[3:7] = normalized_unit_quaternion(values[3:7], "BaseMotion.orientation")
        for name, part in _FIELDS:
            object.__setattr__(self, name, values[part])
        object.__setattr__(self, "rotation", quaternion_matrix(values[3:7]))
        object.__setattr__(self, "packed", values)

    @property
    def axis(self) -> np.ndarray:
        """Unit needle axis r_xA = R e_x in the world frame."""
        return self.rotation[:, 0]

    @classmethod
    def from_packed(cls, values: np.ndarray, rotation: np.ndarray) -> BaseMotion:
        """From already validated packed fields (19,) [position, orientation, v, w, a, alpha] and the matching
        rotation matrix, without copying or checking (the compiled paths produce these, one per step); the six
        fields are views of ``values`` made when read (:meth:`__getattr__`)."""
        motion = object.__new__(cls)
        motion.__dict__.update(rotation=rotation, packed=values)  # frozen: no setattr
        return motion

    def __getattr__(self, name: str) -> np.ndarray:
        """A field of a motion :meth:`from_packed` (only those lack one): its view of ``packed``, made anew at
        each read (nothing cached: the attributes, and so a pickle, do not depend on what was read)."""
        part = _SLICES.get(name)
        packed = self.__dict__.get("packed")
        if part is None or packed is None:
            raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")
        return packed[part]

    @classmethod
    def from_flange(cls, flange_position, flange_orientation, offset_position=_ZERO3,
                    offset_orientation=(0.0, 0.0, 0.0, 1.0), linear_velocity=_ZERO3, angular_velocity=_ZERO3,
                    linear_acceleration=_ZERO3, angular_acceleration=_ZERO3) -> BaseMotion:
        """Motion of the clamp frame from the robot flange's motion (world frame) and the fixed flange-to-clamp
        offset (position of A and rotation of frame f, both in the flange frame)."""
        flange = cls(flange_position, flange_orientation, linear_velocity, angular_velocity, linear_acceleration,
                     angular_acceleration)
        values, rotations = clamp_motions(flange.packed[None, :], *clamp_offset(offset_position, offset_orientation))
        return cls.from_packed(values[0], rotations[0])

    def impose_nodes(self, local_r: np.ndarray, local_rx: np.ndarray, nodes: np.ndarray, target: np.ndarray) -> None:
        """Write [q, qd, qdd] of the given nodes, carried with frame coordinates rho = local_r, tau = local_rx
        (k, 3), into the rows of target (3, n_dof)."""
        rigid_node_kinematics(self.position, self.rotation, self.linear_velocity, self.angular_velocity,
                              self.linear_acceleration, self.angular_acceleration, local_r, local_rx, nodes, target)


# The fields' defaults live in the dataclass's __init__; without them as class attributes, a motion made
# from_packed reads its views (__getattr__) instead of the class's default
for _name in ("linear_velocity", "angular_velocity", "linear_acceleration", "angular_acceleration"):
    delattr(BaseMotion, _name)
STATIC_WORLD = BaseMotion(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))


def clamp_offset(position, orientation, prefix: str = "offset_") -> tuple[np.ndarray, np.ndarray]:
    """Position of A (3,) [m] and rotation of frame f (3, 3) in the flange frame; ValueError names ``<prefix>...``."""
    offset = np.asarray(position, dtype=float)
    if offset.shape == ():
        offset = np.full(3, float(offset))
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise ValueError(f"{prefix}position must be 3 finite numbers, got {position!r}")
    return offset, quaternion_matrix(unit_quaternion(orientation, f"{prefix}orientation"))


def clamp_motions(flange: np.ndarray, offset: np.ndarray, offset_rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clamp-frame motions (k, 19) and rotations (k, 3, 3) from flange motions (k, 19) and a :func:`clamp_offset`."""
    values, rotations = np.empty_like(flange), np.empty((len(flange), 3, 3))
    compose_offsets(flange, offset, offset_rotation, values, rotations)
    return values, rotations


@njit(cache=True)
def dot3(a, b) -> float:
    """a . b of two 3-vectors in scalar arithmetic (numba's ``@`` calls BLAS: ~0.15 us per call in a per-point
    loop, with the temporary of an operand like ``r - p``, against 2 ns)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def offset_dot(point, origin, direction) -> float:
    """(point - origin) . direction of 3-vectors without the temporary difference (``dot3``)."""
    return ((point[0] - origin[0]) * direction[0] + (point[1] - origin[1]) * direction[1]
            + (point[2] - origin[2]) * direction[2])


@njit(cache=True)
def cross(a, b):
    """a x b of two 3-vectors (arrays or tuples) as a tuple: no array is allocated in per-node or per-point loops."""
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


@njit(cache=True)
def rotate(rotation, x):
    """rotation x for a 3 x 3 matrix and a 3-vector, as a tuple (in scalar arithmetic: see ``dot3``)."""
    return (rotation[0, 0] * x[0] + rotation[0, 1] * x[1] + rotation[0, 2] * x[2],
            rotation[1, 0] * x[0] + rotation[1, 1] * x[1] + rotation[1, 2] * x[2],
            rotation[2, 0] * x[0] + rotation[2, 1] * x[1] + rotation[2, 2] * x[2])


@njit(cache=True)
def rotate_back(rotation, x):
    """rotation^T x (a world vector in the rotated frame), as a tuple (``rotate``)."""
    return (rotation[0, 0] * x[0] + rotation[1, 0] * x[1] + rotation[2, 0] * x[2],
            rotation[0, 1] * x[0] + rotation[1, 1] * x[1] + rotation[2, 1] * x[2],
            rotation[0, 2] * x[0] + rotation[1, 2] * x[1] + rotation[2, 2] * x[2])


@njit(cache=True, **NO_REFCOUNTS)
def rigid_node_kinematics(p, rotation, v, w, a, alpha, local_r, local_rx, nodes, target):
    """[q, qd, qdd] of rigidly carried nodes (module docstring) into target (3, n_dof) at the nodes' coordinates."""
    for k in range(nodes.size):
        first = 6 * nodes[k]
        d = rotate(rotation, local_r[k])
        t = rotate(rotation, local_rx[k])
        wd, wt = cross(w, d), cross(w, t)
        alpha_d, w_wd = cross(alpha, d), cross(w, wd)
        alpha_t, w_wt = cross(alpha, t), cross(w, wt)
        for c in range(3):
            target[0, first + c] = p[c] + d[c]
            target[0, first + 3 + c] = t[c]
            target[1, first + c] = v[c] + wd[c]
            target[1, first + 3 + c] = wt[c]
            target[2, first + c] = a[c] + alpha_d[c] + w_wd[c]
            target[2, first + 3 + c] = alpha_t[c] + w_wt[c]


@njit(cache=True)
def compose_offsets(flange, offset, offset_rotation, values, rotations):
    """Motions (k, 19) and rotations (k, 3, 3) of a frame rigidly offset (offset, offset_rotation in the moving
    frame) from the moving frames packed in flange (k, 19) as BaseMotion fields; ``values`` may be ``flange``."""
    for i in range(flange.shape[0]):
        m = flange[i]
        rotation = quaternion_matrix(m[3:7])
        w, alpha = m[10:13], m[16:19]
        d = rotate(rotation, offset)
        wd = cross(w, d)
        alpha_d, w_wd = cross(alpha, d), cross(w, wd)
        for c in range(3):
            column = rotate(rotation, offset_rotation[:, c])
            for r in range(3):
                rotations[i, r, c] = column[r]
        values[i, 3:7] = matrix_quaternion(rotations[i])
        for c in range(3):
            values[i, c] = m[c] + d[c]
            values[i, 7 + c] = m[7 + c] + wd[c]
            values[i, 10 + c] = w[c]
            values[i, 13 + c] = m[13 + c] + alpha_d[c] + w_wd[c]
            values[i, 16 + c] = alpha[c]
