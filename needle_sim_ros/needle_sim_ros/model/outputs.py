"""Outputs of a needle state: centerline, tip pose, strain and curvature (eq. 8) along the needle, energies."""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from needle_common.transforms import matrix_quaternion, quaternion_matrix, unit_quaternion

from .elastic import elastic_energy
from .forces import Gravity
from .kinematics import cross, dot3
from .mesh import Interpolation, interpolate
from .model import NeedleModel

__all__ = ["Centerline", "centerline", "tip_pose", "transported_normals", "ModelShape", "model_shape", "axial_strain",
           "curvature", "kinetic_energy", "elastic_energy", "gravitational_energy"]

_GAUSS_XI, _GAUSS_W = np.polynomial.legendre.leggauss(3)


@dataclass(frozen=True)
class Centerline:
    """Deformed centerline at n samples equally spaced in reference arc length: points (n, 3), unit tangents
    (n, 3), deformed arc length (n,) from A, reference arc length (n,)."""

    points: np.ndarray
    tangents: np.ndarray
    arc_length: np.ndarray
    reference_arc_length: np.ndarray


@lru_cache(maxsize=32)
def _sampling(model: NeedleModel, n_samples: int) -> tuple[Interpolation, Interpolation]:
    """Tables at the samples and at 3 Gauss points of each gap between samples."""
    s = np.linspace(0.0, model.props.length, n_samples)
    mid, half = 0.5 * (s[1:] + s[:-1]), 0.5 * (s[1:] - s[:-1])
    gauss = (mid[:, None] + half[:, None] * _GAUSS_XI[None, :]).ravel()
    return model.interpolation(s), model.interpolation(gauss)


def centerline(model: NeedleModel, q: np.ndarray, n_samples: int) -> Centerline:
    """The deformed centerline r(s) (eq. 3) with tangents r_x / |r_x| and deformed arc length int |r_x| ds."""
    if not (isinstance(n_samples, (int, np.integer)) and n_samples >= 2):
        raise ValueError(f"n_samples must be an integer >= 2, got {n_samples!r}")
    samples, gauss = _sampling(model, int(n_samples))
    points, tangents, arc = _centerline_arrays(samples.S, samples.S_x, samples.slots, gauss.S_x, gauss.slots,
                                               samples.arc_length, _GAUSS_W, np.ascontiguousarray(q, dtype=float))
    return Centerline(points, tangents, arc, samples.arc_length.copy())


@njit(cache=True)
def unit_tangents(S_x: np.ndarray, slots: np.ndarray, q: np.ndarray) -> np.ndarray:
    """r_x / |r_x| at each point of an interpolation table, (k, 3)."""
    tangents = interpolate(slots, S_x, q)
    for k in range(tangents.shape[0]):
        norm = np.sqrt(tangents[k, 0] ** 2 + tangents[k, 1] ** 2 + tangents[k, 2] ** 2)
        for i in range(3):
            tangents[k, i] /= norm
    return tangents


@njit(cache=True)
def _centerline_arrays(S, S_x, slots, gauss_S_x, gauss_slots, s, gauss_w, q):
    """Points r (n, 3), unit tangents (n, 3) at the samples and the deformed arc length from A (n,): the integral of
    |r_x| over each gap between samples by Gauss-Legendre with the weights ``gauss_w``."""
    n, m = S.shape[0], gauss_w.size
    gradients = interpolate(gauss_slots, gauss_S_x, q)
    arc = np.zeros(n)
    for j in range(n - 1):
        stretch = 0.0
        for g in range(m):
            p = j * m + g
            stretch += gauss_w[g] * np.sqrt(gradients[p, 0] ** 2 + gradients[p, 1] ** 2 + gradients[p, 2] ** 2)
        arc[j + 1] = arc[j] + 0.5 * (s[j + 1] - s[j]) * stretch
    return interpolate(slots, S, q), unit_tangents(S_x, slots, q), arc


def axial_strain(model: NeedleModel, q: np.ndarray, s) -> np.ndarray:
    """Green-Lagrange axial strain eps = (r_x.r_x - 1)/2 (eq. 8) at reference arc lengths s."""
    gradients = model.interpolation(s).gradients(q)
    return 0.5 * (np.einsum("ki,ki->k", gradients, gradients) - 1.0)


def curvature(model: NeedleModel, q: np.ndarray, s) -> np.ndarray:
    """kappa = |r_x x r_xx| / |r_x|^3 (eq. 8) [1/m] at reference arc lengths s."""
    table = model.interpolation(s)
    r_x, r_xx = table.gradients(q), table.second_derivatives(q)
    return np.linalg.norm(np.cross(r_x, r_xx), axis=1) / np.linalg.norm(r_x, axis=1) ** 3


def kinetic_energy(model: NeedleModel, qd: np.ndarray) -> float:
    """T = q'^T M q' / 2 [J] (eq. 7)."""
    slots = np.asarray(qd, dtype=float).reshape(-1, 3)
    return 0.5 * float(np.sum(slots * (model.mass_slots @ slots)))


_GRAVITY = Gravity()


def gravitational_energy(model: NeedleModel, q: np.ndarray) -> float:
    """V = -int rho A g . r ds = -Q_g . q [J] (zero at the world origin)."""
    return -float(_GRAVITY.evaluate(model, q, None, 0.0, None).Q @ q)


@njit(cache=True)
def transported_normals(tangents: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """A normal of tangents[0] carried along a polyline of unit tangents (k, 3) by the least rotation taking each
    tangent to the next, u <- u + c x u + c x (c x u) / (1 + a.b) with c = a x b (parallel transport: the frame
    does not twist about the curve); the normal at each tangent, (k, 3)."""
    normals = np.empty((tangents.shape[0], 3))
    u0, u1, u2 = normal[0], normal[1], normal[2]
    for k in range(tangents.shape[0]):
        normals[k, 0], normals[k, 1], normals[k, 2] = u0, u1, u2
        if k + 1 == tangents.shape[0]:
            break
        a0, a1, a2 = tangents[k, 0], tangents[k, 1], tangents[k, 2]
        b0, b1, b2 = tangents[k + 1, 0], tangents[k + 1, 1], tangents[k + 1, 2]
        c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        d0, d1, d2 = c1 * u2 - c2 * u1, c2 * u0 - c0 * u2, c0 * u1 - c1 * u0
        f = 1.0 / (1.0 + a0 * b0 + a1 * b1 + a2 * b2)
        u0, u1, u2 = (u0 + d0 + (c1 * d2 - c2 * d1) * f, u1 + d1 + (c2 * d0 - c0 * d2) * f,
                      u2 + d2 + (c0 * d1 - c1 * d0) * f)
    return normals


@njit(cache=True)
def _tip_rotation(S_x: np.ndarray, slots: np.ndarray, q: np.ndarray, base_rotation: np.ndarray) -> np.ndarray:
    """Rotation matrix of the tip frame (see :func:`tip_pose`) from the tangents at the points of an interpolation
    table along the whole needle; ``base_rotation`` (3, 3), or (0, 0) for the minimal rotation onto r_xA."""
    tangents = unit_tangents(S_x, slots, q)
    t0 = tangents[0]
    if base_rotation.size:
        normal = base_rotation[:, 1].copy()
    elif t0[0] > -1.0 + 1e-12:  # the minimal rotation e_x -> t0 applied to e_y
        normal = np.array([-t0[1], 1.0 - t0[1] ** 2 / (1.0 + t0[0]), -t0[1] * t0[2] / (1.0 + t0[0])])
    else:
        normal = np.array([0.0, 1.0, 0.0])
    x_axis = tangents[-1]
    y_axis = transported_normals(tangents, normal - dot3(normal, t0) * t0)[-1]
    y_axis = y_axis - dot3(y_axis, x_axis) * x_axis
    y_axis /= np.sqrt(dot3(y_axis, y_axis))
    rotation = np.empty((3, 3))
    rotation[:, 0], rotation[:, 1], rotation[:, 2] = x_axis, y_axis, np.array(cross(x_axis, y_axis))
    return rotation


_NO_ROTATION = np.zeros((0, 0))


def tip_pose(model: NeedleModel, q: np.ndarray, base_orientation=None,
             samples_per_element: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Tip position and orientation (x, y, z, w): x axis = tip tangent; y, z = the base frame's y, z axes
    parallel-transported along the centerline (a torsion-free cable's cross sections do not twist).
    Without base_orientation the base frame is the minimal rotation of the world frame onto r_xA."""
    q = np.ascontiguousarray(q, dtype=float)
    table = _sampling(model, samples_per_element * model.n_elements + 1)[0]
    base_rotation = _NO_ROTATION if base_orientation is None else quaternion_matrix(
        unit_quaternion(base_orientation, "base_orientation"))
    rotation = _tip_rotation(table.S_x, table.slots, q, base_rotation)
    return q[-6:-3].copy(), matrix_quaternion(rotation)


@dataclass(frozen=True)
class ModelShape:
    """The simulator's shape output at time ``t`` [s]: the centerline and the tip pose (:func:`tip_pose`, position
    [m] and orientation x, y, z, w). The node publishes it and the offline stage writes it (``needle/shape``)."""

    t: float
    line: Centerline
    tip_position: np.ndarray
    tip_orientation: np.ndarray


def model_shape(model: NeedleModel, q: np.ndarray, t: float, n_samples: int, base_orientation=None) -> ModelShape:
    """The shape output of state ``q`` at ``t``: ``n_samples`` centerline samples; the tip frame's y, z axes are the
    base frame's (``base_orientation``) carried along the needle."""
    return ModelShape(t, centerline(model, q, n_samples), *tip_pose(model, q, base_orientation))
