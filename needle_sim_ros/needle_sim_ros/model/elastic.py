"""Elastic forces of the gradient-deficient ANCF cable (seed 000 eqs. 8-13) and their analytic Jacobian.

Per element, with r_x = S_x e and r_xx = S_xx e (eq. 3 ff.):
    eps = (r_x.r_x - 1) / 2,   kappa = |r_x x r_xx| / |r_x|^3                                           (eq. 8)
    Pi  = 1/2 int E A eps^2 + E I kappa^2 dx                                                                (eq. 9)
    Q_el = -dPi/de = Q_a + Q_b,  Q_a = -int EA eps (d eps/de)^T,  Q_b = -int EI kappa (d kappa/de)^T   (eqs. 10-13)
The bending term is evaluated as -1/2 int EI d(kappa^2)/de: identical to eq. 13 wherever kappa > 0, and -- unlike
kappa itself -- smooth at the straight state, so the Jacobian is analytic there too.  With g = |r_x|^2,
h = |r_x x r_xx|^2 = g |r_xx|^2 - (r_x.r_xx)^2 (Lagrange's identity), kappa^2 = h / g^3 and all first and second
derivatives follow in closed form.  Gauss quadrature: ``axial`` points for the axial, ``bending`` points for the
bending integral (seed 000: 5 and 3).  E A and E I are folded into the quadrature weights.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .banded import ELEMENT_BANDWIDTH, FAST, band_to_dense, band_width_columns
from .mesh import Mesh, gauss_table
from .properties import NeedleProperties


class ElasticTables(NamedTuple):
    """Quadrature tables of eqs. 12-13: S_x at the axial points, S_x and S_xx at the bending points, (n_elements,
    n_points, 4); weights (n_elements, n_points) include l/2 and EA resp. EI."""

    axial_S_x: np.ndarray
    axial_weights: np.ndarray
    bending_S_x: np.ndarray
    bending_S_xx: np.ndarray
    bending_weights: np.ndarray


def elastic_tables(mesh: Mesh, props: NeedleProperties, axial_gauss: int, bending_gauss: int) -> ElasticTables:
    axial = gauss_table(mesh.element_lengths, axial_gauss)
    bending = gauss_table(mesh.element_lengths, bending_gauss)
    return ElasticTables(axial.S_x, props.EA * axial.weights, bending.S_x, bending.S_xx, props.EI * bending.weights)


@njit(cache=True, fastmath=FAST)
def add_elastic(q, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights,
                forces, band, kl, stiffness_factor, with_stiffness, rate_weights=None, rate_factor=0.0):
    """Add Q_el(q) to ``forces`` and, if with_stiffness, stiffness_factor * K (K = -dQ_el/dq) to ``band``
    (bandwidth kl >= 11). Returns the elastic energy Pi (eq. 9).

    Given the axial strain-rate weights of ``damping`` (beta EA w at the axial points), the matrix of that damping,
    rate_factor * int beta EA S_x^T S_x (x) r_x r_x^T (-dQ_d,a/dq', ``add_axial_damping``), is added too: it has
    the blocks of the axial stiffness at the same points, so it costs no loop of its own."""
    n_elements = axial_S_x.shape[0]
    energy = 0.0
    element_force = np.empty(12)
    element_stiffness = np.empty((12, 12))
    rx = np.empty(3)
    rxx = np.empty(3)
    f1 = np.empty(3)
    f2 = np.empty(3)
    h1 = np.empty(3)
    h2 = np.empty(3)
    f11 = np.empty((3, 3))
    f12 = np.empty((3, 3))
    f22 = np.empty((3, 3))
    for j in range(n_elements):
        first = 6 * j
        element_force[:] = 0.0
        if with_stiffness:
            element_stiffness[:, :] = 0.0
        # axial strain energy, eq. 12
        for point in range(axial_S_x.shape[1]):
            d = axial_S_x[j, point]
            w = axial_weights[j, point]
            for c in range(3):
                rx[c] = (d[0] * q[first + c] + d[1] * q[first + 3 + c]
                         + d[2] * q[first + 6 + c] + d[3] * q[first + 9 + c])
            eps = 0.5 * (rx[0] * rx[0] + rx[1] * rx[1] + rx[2] * rx[2] - 1.0)
            energy += 0.5 * w * eps * eps
            for a in range(4):
                for c in range(3):
                    element_force[3 * a + c] -= w * eps * d[a] * rx[c]
            if with_stiffness:
                w_k = stiffness_factor * w
                w_rx = w_k if rate_weights is None else w_k + rate_factor * rate_weights[j, point]
                for c in range(3):
                    for c2 in range(3):
                        f11[c, c2] = w_rx * rx[c] * rx[c2]
                    f11[c, c] += w_k * eps
                for a in range(4):
                    for b in range(a, 4):
                        dab = d[a] * d[b]
                        for c in range(3):
                            for c2 in range(3):
                                element_stiffness[3 * a + c, 3 * b + c2] += dab * f11[c, c2]
        # bending energy, eq. 13 through kappa^2 = h / g^3
        for point in range(bending_S_x.shape[1]):
            d = bending_S_x[j, point]
            dd = bending_S_xx[j, point]
            w = bending_weights[j, point]
            for c in range(3):
                rx[c] = (d[0] * q[first + c] + d[1] * q[first + 3 + c]
                         + d[2] * q[first + 6 + c] + d[3] * q[first + 9 + c])
                rxx[c] = (dd[0] * q[first + c] + dd[1] * q[first + 3 + c]
                          + dd[2] * q[first + 6 + c] + dd[3] * q[first + 9 + c])
            g = rx[0] * rx[0] + rx[1] * rx[1] + rx[2] * rx[2]
            p = rxx[0] * rxx[0] + rxx[1] * rxx[1] + rxx[2] * rxx[2]
            s = rx[0] * rxx[0] + rx[1] * rxx[1] + rx[2] * rxx[2]
            c0 = rx[1] * rxx[2] - rx[2] * rxx[1]
            c1 = rx[2] * rxx[0] - rx[0] * rxx[2]
            c2_ = rx[0] * rxx[1] - rx[1] * rxx[0]
            h = c0 * c0 + c1 * c1 + c2_ * c2_
            ig3 = 1.0 / (g * g * g)
            ig4 = ig3 / g
            energy += 0.5 * w * h * ig3
            for c in range(3):
                h1[c] = 2.0 * p * rx[c] - 2.0 * s * rxx[c]    # dh/dr_x
                h2[c] = 2.0 * g * rxx[c] - 2.0 * s * rx[c]    # dh/dr_xx
                f1[c] = h1[c] * ig3 - 6.0 * h * ig4 * rx[c]   # d(kappa^2)/dr_x
                f2[c] = h2[c] * ig3                           # d(kappa^2)/dr_xx
            half_w = 0.5 * w
            for a in range(4):
                for c in range(3):
                    element_force[3 * a + c] -= half_w * (d[a] * f1[c] + dd[a] * f2[c])
            if with_stiffness:
                ig5 = ig4 / g
                for c in range(3):
                    for c2 in range(3):
                        delta = 1.0 if c == c2 else 0.0
                        hh11 = 2.0 * p * delta - 2.0 * rxx[c] * rxx[c2]
                        hh12 = 4.0 * rx[c] * rxx[c2] - 2.0 * s * delta - 2.0 * rxx[c] * rx[c2]
                        hh22 = 2.0 * g * delta - 2.0 * rx[c] * rx[c2]
                        f11[c, c2] = (hh11 * ig3 - 6.0 * ig4 * (h1[c] * rx[c2] + rx[c] * h1[c2])
                                      + 48.0 * h * ig5 * rx[c] * rx[c2] - 6.0 * h * ig4 * delta)
                        f12[c, c2] = hh12 * ig3 - 6.0 * ig4 * rx[c] * h2[c2]
                        f22[c, c2] = hh22 * ig3
                w_k = stiffness_factor * half_w
                for a in range(4):
                    for b in range(a, 4):
                        k11 = w_k * d[a] * d[b]
                        k12 = w_k * d[a] * dd[b]
                        k21 = w_k * dd[a] * d[b]
                        k22 = w_k * dd[a] * dd[b]
                        for c in range(3):
                            for c2 in range(3):
                                element_stiffness[3 * a + c, 3 * b + c2] += (
                                    k11 * f11[c, c2] + k12 * f12[c, c2] + k21 * f12[c2, c] + k22 * f22[c, c2])
        if with_stiffness:  # K is symmetric: only blocks b >= a were accumulated
            for a in range(4):
                for b in range(a + 1, 4):
                    for c in range(3):
                        for c2 in range(3):
                            element_stiffness[3 * b + c2, 3 * a + c] = element_stiffness[3 * a + c, 3 * b + c2]
        for i in range(12):
            forces[first + i] += element_force[i]
        if with_stiffness:
            for i in range(12):
                for k in range(12):
                    band[first + i, k - i + kl] += element_stiffness[i, k]
    return energy


def evaluate_elastic(tables: ElasticTables, q: np.ndarray, with_stiffness: bool = True):
    """(Q_el (n,), K band (n, 34) with kl = 11 or None, Pi) at q."""
    q = np.ascontiguousarray(q, dtype=float)
    forces = np.zeros(q.size)
    band = np.zeros((q.size, band_width_columns(ELEMENT_BANDWIDTH)) if with_stiffness else (1, 1))
    energy = add_elastic(q, *tables, forces, band, ELEMENT_BANDWIDTH, 1.0, with_stiffness)
    return forces, (band if with_stiffness else None), energy


def elastic_forces(model, q: np.ndarray) -> np.ndarray:
    """Generalized elastic forces Q_el(q) (eqs. 11-13, assembled as in eq. 16), (n_dof,)."""
    return evaluate_elastic(model.elastic, q, with_stiffness=False)[0]


def tangent_stiffness(model, q: np.ndarray) -> np.ndarray:
    """Analytic tangent stiffness K = -dQ_el/dq at q, dense (n_dof, n_dof)."""
    return band_to_dense(evaluate_elastic(model.elastic, q)[1], ELEMENT_BANDWIDTH)


def elastic_energy(model, q: np.ndarray) -> float:
    """Elastic energy Pi (eq. 9) summed over the elements [J]."""
    return float(evaluate_elastic(model.elastic, q, with_stiffness=False)[2])
