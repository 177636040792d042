"""Outputs of a needle state: centerline, tip pose, strain and curvature (eq. 8) along the needle, energies."""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from .elastic import elastic_energy
from .forces import Gravity
from .kinematics import cross, matrix_quaternion, quaternion_matrix, unit_quaternion
from .mesh import Interpolation
from .model import NeedleModel

__all__ = ["Centerline", "centerline", "tip_pose", "ModelShape", "model_shape", "axial_strain", "curvature",
           "kinetic_energy", "elastic_energy", "gravitational_energy"]

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
    slots = np.asarray(q, dtype=float).reshape(-1, 3)
    points = samples.P @ slots
    gradients = samples.P_x @ slots
    tangents = gradients / np.sqrt(np.einsum("ki,ki->k", gradients, gradients))[:, None]
    s = samples.arc_length
    gauss_gradients = gauss.P_x @ slots
    stretch = np.sqrt(np.einsum("ki,ki->k", gauss_gradients, gauss_gradients)).reshape(-1, 3) @ _GAUSS_W
    arc = np.concatenate([[0.0], np.cumsum(0.5 * (s[1:] - s[:-1]) * stretch)])
    return Centerline(points, tangents, arc, s.copy())


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
def _transport(tangents: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Parallel-transport a normal along a polyline of unit tangents (minimal rotation between neighbours)."""
    u = normal.copy()
    for k in range(tangents.shape[0] - 1):
        a, b = tangents[k], tangents[k + 1]
        c = np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
        cu = np.array([c[1] * u[2] - c[2] * u[1], c[2] * u[0] - c[0] * u[2], c[0] * u[1] - c[1] * u[0]])
        ccu = np.array([c[1] * cu[2] - c[2] * cu[1], c[2] * cu[0] - c[0] * cu[2], c[0] * cu[1] - c[1] * cu[0]])
        u = u + cu + ccu / (1.0 + a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
    return u


def tip_pose(model: NeedleModel, q: np.ndarray, base_orientation=None,
             samples_per_element: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Tip position and orientation (x, y, z, w): x axis = tip tangent; y, z = the base frame's y, z axes
    parallel-transported along the centerline (a torsion-free cable's cross sections do not twist).
    Without base_orientation the base frame is the minimal rotation of the world frame onto r_xA."""
    q = np.asarray(q, dtype=float)
    gradients = _sampling(model, samples_per_element * model.n_elements + 1)[0].gradients(q)
    tangents = gradients / np.sqrt(np.einsum("ki,ki->k", gradients, gradients))[:, None]
    t0 = tangents[0]
    if base_orientation is not None:
        normal = quaternion_matrix(unit_quaternion(base_orientation, "base_orientation"))[:, 1]
    elif t0[0] > -1.0 + 1e-12:
        # the minimal rotation e_x -> t0 applied to e_y
        normal = np.array([-t0[1], 1.0 - t0[1] ** 2 / (1.0 + t0[0]), -t0[1] * t0[2] / (1.0 + t0[0])])
    else:
        normal = np.array([0.0, 1.0, 0.0])
    x_axis = tangents[-1]
    y_axis = _transport(tangents, normal - (normal @ t0) * t0)
    y_axis = y_axis - (y_axis @ x_axis) * x_axis
    y_axis /= np.linalg.norm(y_axis)
    rotation = np.column_stack([x_axis, y_axis, cross(x_axis, y_axis)])
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
