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

from .banded import ELEMENT_BANDWIDTH, FAST, NO_REFCOUNTS, band_to_dense, band_width_columns
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


ELEMENT_WORK = 12 + 144 + 36  # the work area of add_elastic: an element's force, its 3 x 3 blocks, a point's f


@njit(cache=True, fastmath=FAST, **NO_REFCOUNTS)
def add_elastic(q, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights,
                forces, band, kl, stiffness_factor, with_stiffness, work, rate_weights=None, rate_factor=0.0, qd=None,
                lower=False):
    """Add Q_el(q) to ``forces`` and, if with_stiffness, stiffness_factor * K (K = -dQ_el/dq) to ``band``
    (bandwidth kl >= 11; ``lower``: its lower triangle and diagonal only), with ``work`` (ELEMENT_WORK,) as its work
    area. Returns the elastic energy Pi (eq. 9).

    Given the axial strain-rate weights of ``damping`` (beta EA w at the axial points), that damping's matrix
    rate_factor * int beta EA S_x^T S_x (x) r_x r_x^T (-dQ_d,a/dq') is added with the axial stiffness blocks at the
    same points; given ``qd`` too, so is its force Q_d,a = -int beta EA (r_x . r_x') S_x^T r_x (``damping``).
    Per element the 3 x 3 blocks (a, b >= a) of K are summed over the points in scalar arithmetic, the bending blocks
    as d_b G_a + dd_b H_a with G_a = d_a f11 + dd_a f12^T, H_a = d_a f12 + dd_a f22 (f: the second derivatives of
    w kappa^2 / 2 by r_x and r_xx), then written into the band once (timings: docs/design_notes.md)."""
    n_elements = axial_S_x.shape[0]
    energy = 0.0
    element_force = work[:12]
    blocks = work[12:156]  # block (a, b), entry (c, c2) at 9 (4 a + b) + 3 c + c2
    f = work[156:]  # the bending point's f11, f12, f12^T, f22 (times the weight), row-major, 9 each
    for j in range(n_elements):
        first = 6 * j
        e = q[first:first + 12]
        element_force[:] = 0.0
        if with_stiffness:
            blocks[:] = 0.0
        # axial strain energy, eq. 12
        for point in range(axial_S_x.shape[1]):
            d = axial_S_x[j, point]
            w = axial_weights[j, point]
            x0 = d[0] * e[0] + d[1] * e[3] + d[2] * e[6] + d[3] * e[9]
            x1 = d[0] * e[1] + d[1] * e[4] + d[2] * e[7] + d[3] * e[10]
            x2 = d[0] * e[2] + d[1] * e[5] + d[2] * e[8] + d[3] * e[11]
            eps = 0.5 * (x0 * x0 + x1 * x1 + x2 * x2 - 1.0)
            energy += 0.5 * w * eps * eps
            along = w * eps  # the force's factor of S_x^T r_x, with the strain rate's below
            if qd is not None and rate_weights is not None:
                v = qd[first:first + 12]
                v0 = d[0] * v[0] + d[1] * v[3] + d[2] * v[6] + d[3] * v[9]
                v1 = d[0] * v[1] + d[1] * v[4] + d[2] * v[7] + d[3] * v[10]
                v2 = d[0] * v[2] + d[1] * v[5] + d[2] * v[8] + d[3] * v[11]
                along += rate_weights[j, point] * (x0 * v0 + x1 * v1 + x2 * v2)
            for a in range(4):
                da = along * d[a]
                element_force[3 * a] -= da * x0
                element_force[3 * a + 1] -= da * x1
                element_force[3 * a + 2] -= da * x2
            if with_stiffness:
                w_k = stiffness_factor * w
                w_rx = w_k if rate_weights is None else w_k + rate_factor * rate_weights[j, point]
                diagonal = w_k * eps
                s00, s11, s22 = w_rx * x0 * x0 + diagonal, w_rx * x1 * x1 + diagonal, w_rx * x2 * x2 + diagonal
                s01, s02, s12 = w_rx * x0 * x1, w_rx * x0 * x2, w_rx * x1 * x2
                for a in range(4):
                    for b in range(a, 4):
                        dab = d[a] * d[b]
                        k = 9 * (4 * a + b)
                        blocks[k] += dab * s00
                        blocks[k + 1] += dab * s01
                        blocks[k + 2] += dab * s02
                        blocks[k + 3] += dab * s01
                        blocks[k + 4] += dab * s11
                        blocks[k + 5] += dab * s12
                        blocks[k + 6] += dab * s02
                        blocks[k + 7] += dab * s12
                        blocks[k + 8] += dab * s22
        # bending energy, eq. 13 through kappa^2 = h / g^3
        for point in range(bending_S_x.shape[1]):
            d = bending_S_x[j, point]
            dd = bending_S_xx[j, point]
            w = bending_weights[j, point]
            r0 = d[0] * e[0] + d[1] * e[3] + d[2] * e[6] + d[3] * e[9]  # r_x
            r1 = d[0] * e[1] + d[1] * e[4] + d[2] * e[7] + d[3] * e[10]
            r2 = d[0] * e[2] + d[1] * e[5] + d[2] * e[8] + d[3] * e[11]
            u0 = dd[0] * e[0] + dd[1] * e[3] + dd[2] * e[6] + dd[3] * e[9]  # r_xx
            u1 = dd[0] * e[1] + dd[1] * e[4] + dd[2] * e[7] + dd[3] * e[10]
            u2 = dd[0] * e[2] + dd[1] * e[5] + dd[2] * e[8] + dd[3] * e[11]
            g = r0 * r0 + r1 * r1 + r2 * r2
            p = u0 * u0 + u1 * u1 + u2 * u2
            s = r0 * u0 + r1 * u1 + r2 * u2
            c0 = r1 * u2 - r2 * u1
            c1 = r2 * u0 - r0 * u2
            c2 = r0 * u1 - r1 * u0
            h = c0 * c0 + c1 * c1 + c2 * c2  # = g p - s^2
            ig3 = 1.0 / (g * g * g)
            ig4 = ig3 / g
            energy += 0.5 * w * h * ig3
            # d(kappa^2)/dr_x = a_r r_x + a_u r_xx, d(kappa^2)/dr_xx = b_u r_xx + a_u r_x
            # (dh/dr_x = 2 p r_x - 2 s r_xx, dh/dr_xx = 2 g r_xx - 2 s r_x)
            a_r = 2.0 * p * ig3 - 6.0 * h * ig4
            a_u = -2.0 * s * ig3
            b_u = 2.0 * g * ig3
            f10, f11, f12 = a_r * r0 + a_u * u0, a_r * r1 + a_u * u1, a_r * r2 + a_u * u2
            f20, f21, f22 = b_u * u0 + a_u * r0, b_u * u1 + a_u * r1, b_u * u2 + a_u * r2
            half_w = 0.5 * w
            for a in range(4):
                da = half_w * d[a]
                dda = half_w * dd[a]
                element_force[3 * a] -= da * f10 + dda * f20
                element_force[3 * a + 1] -= da * f11 + dda * f21
                element_force[3 * a + 2] -= da * f12 + dda * f22
            if with_stiffness:
                w_k = stiffness_factor * half_w
                # the second derivatives of kappa^2 as identity and dyads of r_x, r_xx:
                # f11 = (2 p / g^3 - 6 h / g^4) I - 2 / g^3 r_xx r_xx^T + (48 h / g^5 - 24 p / g^4) r_x r_x^T
                #       + 12 s / g^4 (r_xx r_x^T + r_x r_xx^T);
                # f12 = -2 s / g^3 I - 8 / g^3 r_x r_xx^T - 2 / g^3 r_xx r_x^T + 12 s / g^4 r_x r_x^T;
                # f22 = 2 g / g^3 I - 2 / g^3 r_x r_x^T
                uu = -2.0 * w_k * ig3
                rr11 = w_k * (48.0 * h * ig4 / g - 24.0 * p * ig4)
                ru = 12.0 * w_k * s * ig4
                ru12 = 4.0 * uu
                identity = (w_k * a_r, w_k * a_u, w_k * b_u)  # of f11, f12, f22
                r = (r0, r1, r2)
                u = (u0, u1, u2)
                for c in range(3):
                    for c2 in range(3):
                        rr = r[c] * r[c2]
                        v11 = uu * u[c] * u[c2] + rr11 * rr + ru * (u[c] * r[c2] + r[c] * u[c2])
                        v12 = ru12 * r[c] * u[c2] + uu * u[c] * r[c2] + ru * rr
                        v22 = uu * rr
                        if c == c2:
                            v11 += identity[0]
                            v12 += identity[1]
                            v22 += identity[2]
                        f[3 * c + c2] = v11
                        f[9 + 3 * c + c2] = v12
                        f[18 + 3 * c2 + c] = v12
                        f[27 + 3 * c + c2] = v22
                for a in range(4):  # G_a = d_a f11 + dd_a f12^T (with d_b), H_a = d_a f12 + dd_a f22 (with dd_b)
                    da = d[a]
                    dda = dd[a]
                    g0, g1, g2 = da * f[0] + dda * f[18], da * f[1] + dda * f[19], da * f[2] + dda * f[20]
                    g3, g4, g5 = da * f[3] + dda * f[21], da * f[4] + dda * f[22], da * f[5] + dda * f[23]
                    g6, g7, g8 = da * f[6] + dda * f[24], da * f[7] + dda * f[25], da * f[8] + dda * f[26]
                    k0, k1, k2 = da * f[9] + dda * f[27], da * f[10] + dda * f[28], da * f[11] + dda * f[29]
                    k3, k4, k5 = da * f[12] + dda * f[30], da * f[13] + dda * f[31], da * f[14] + dda * f[32]
                    k6, k7, k8 = da * f[15] + dda * f[33], da * f[16] + dda * f[34], da * f[17] + dda * f[35]
                    for b in range(a, 4):
                        db = d[b]
                        ddb = dd[b]
                        k = 9 * (4 * a + b)
                        blocks[k] += db * g0 + ddb * k0
                        blocks[k + 1] += db * g1 + ddb * k1
                        blocks[k + 2] += db * g2 + ddb * k2
                        blocks[k + 3] += db * g3 + ddb * k3
                        blocks[k + 4] += db * g4 + ddb * k4
                        blocks[k + 5] += db * g5 + ddb * k5
                        blocks[k + 6] += db * g6 + ddb * k6
                        blocks[k + 7] += db * g7 + ddb * k7
                        blocks[k + 8] += db * g8 + ddb * k8
        for i in range(12):
            forces[first + i] += element_force[i]
        if with_stiffness:  # K is symmetric: block (b, a) is block (a, b) transposed
            for a in range(4):
                for c in range(3):
                    row = band[first + 3 * a + c]  # matrix column first + 3 b + c2 at row[3 (b - a) + c2 - c + kl]
                    for b in range(a + 1 if lower else 4):
                        k = 9 * (4 * a + b) + 3 * c if b >= a else 9 * (4 * b + a) + c
                        step = 1 if b >= a else 3
                        for c2 in range(c + 1 if lower and b == a else 3):
                            row[np.uint64(3 * (b - a) + c2 - c + kl)] += blocks[k + step * c2]
    return energy


def evaluate_elastic(tables: ElasticTables, q: np.ndarray, with_stiffness: bool = True):
    """(Q_el (n,), K band (n, 34) with kl = 11 or None, Pi) at q."""
    q = np.ascontiguousarray(q, dtype=float)
    forces = np.zeros(q.size)
    band = np.zeros((q.size, band_width_columns(ELEMENT_BANDWIDTH)) if with_stiffness else (1, 1))
    energy = add_elastic(q, *tables, forces, band, ELEMENT_BANDWIDTH, 1.0, with_stiffness, np.empty(ELEMENT_WORK))
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
