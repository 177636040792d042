"""Compiled Newton iterations on the active coordinates (seed 000 eqs. 17-19), shared by dynamics and statics.

Residual of the equations of motion (eq. 17) on the active rows,
    R(q) = M q'' - Q_d(q, q') - Q_el(q) - Q_ext,       (Q_d = -C q', see ``damping``)
with q' and q'' affine functions of q (generalized-alpha / Newmark update, or q' = q'' = 0 for statics), and the
iteration matrix  J = dR/dq = (K - dQ_ext/dq) + c_M M + c_C (C - dQ_ext/dq')  with c_M = dq''/dq, c_C = dq'/dq.
Constrained rows and columns are replaced by the identity, so the solve runs on the full, banded coordinate vector
and the constrained coordinates keep their prescribed values.  ``newton_control`` decides after each correction:
converged (scaled correction <= tol), keep the factorization (chord step, close to the solution) or refactor with a
fresh analytic Jacobian.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .banded import FAST, NO_REFCOUNTS, band_cholesky, band_factor, band_solve, band_symmetric, cholesky_solve
from .elastic import ELEMENT_WORK, add_elastic

CONVERGED, CHORD, REFACTOR, FAILED = 0, 1, 2, -1
DIVERGED_CORRECTION = 100.0  # a correction of 100 needle lengths (or 100 in a gradient) means divergence
CHORD_RANGE = 1e-4  # scaled correction (27 um on the seed's needle) below which a factorization may be reused
CHORD_CONTRACTION = 0.1  # ... as long as each correction is at most this fraction of the previous one


TABLES_HEADER = 4  # n_elements, axial points, bending points, slots


def model_tables(model) -> np.ndarray:
    """The model's constant arrays the kernels read (elastic quadrature tables, mass and damping slot matrices) in
    one float64 array: a header of their sizes, each array's values (:func:`unpack_tables` gives them back), then
    the element kernels' work area (``elastic.ELEMENT_WORK``; written by every assembly: one integrator per thread).

    One array, not a tuple of nine: numba 0.59 (Ubuntu 24.04's) types a tuple argument in Python on every call from
    Python, ~10-60 us per call of a kernel (newer numba in C); an array is typed in C by both."""
    elastic, damping = model.elastic, model.damping
    n_elements, axial, _ = elastic.axial_S_x.shape
    sizes = [n_elements, axial, elastic.bending_S_x.shape[1], model.mass_slots.shape[0]]
    arrays = (*elastic, model.mass_slots, *damping)
    return np.concatenate([np.array(sizes, dtype=float), *(np.ascontiguousarray(a, dtype=float).ravel()
                                                           for a in arrays), np.zeros(ELEMENT_WORK)])


@njit(cache=True, inline="always")  # inlined: the views need no reference counts in the kernels below (NO_REFCOUNTS)
def unpack_tables(tables):
    """(axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, mass_slots, damping_isotropic,
    damping_transverse, strain_rate_weights): views into ``model_tables``' array."""
    n_elements, axial, bending, slots = int(tables[0]), int(tables[1]), int(tables[2]), int(tables[3])
    start = TABLES_HEADER
    axial_S_x = tables[start:start + n_elements * axial * 4].reshape((n_elements, axial, 4))
    start += n_elements * axial * 4
    axial_weights = tables[start:start + n_elements * axial].reshape((n_elements, axial))
    start += n_elements * axial
    bending_S_x = tables[start:start + n_elements * bending * 4].reshape((n_elements, bending, 4))
    start += n_elements * bending * 4
    bending_S_xx = tables[start:start + n_elements * bending * 4].reshape((n_elements, bending, 4))
    start += n_elements * bending * 4
    bending_weights = tables[start:start + n_elements * bending].reshape((n_elements, bending))
    start += n_elements * bending
    mass_slots = tables[start:start + slots * slots].reshape((slots, slots))
    start += slots * slots
    damping_isotropic = tables[start:start + slots * slots].reshape((slots, slots))
    start += slots * slots
    damping_transverse = tables[start:start + slots * slots].reshape((slots, slots))
    start += slots * slots
    strain_rate_weights = tables[start:start + n_elements * axial].reshape((n_elements, axial))
    return (axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, mass_slots, damping_isotropic,
            damping_transverse, strain_rate_weights)


@njit(cache=True, inline="always")  # inlined like unpack_tables: a view without reference counts
def element_work(tables):
    """The element kernels' work area at the end of ``model_tables``' array (``elastic.ELEMENT_WORK``)."""
    return tables[tables.size - ELEMENT_WORK:]


@njit(cache=True, fastmath=FAST, **NO_REFCOUNTS)
def assemble_system(q, qd, qdd, tables, axis, ext_Q, ext_band, c_K, c_M, c_C, active, residual, band, kl,
                    with_matrix, lower=False):
    """residual <- R (zero on constrained rows); if with_matrix, band <- J (identity on constrained rows/cols), with
    ``lower`` its lower triangle and diagonal only (what ``band_cholesky`` reads of a symmetric J; the band's other
    entries are left as they were). tables: ``model_tables``; ext_band: the external forces' part of J,
    -(c_K dQ_ext/dq + c_C dQ_ext/dq'), in the layout of ``band`` (same kl), or a (0, 0) array for zero."""
    (axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, mass_slots, damping_isotropic,
     damping_transverse, strain_rate_weights) = unpack_tables(tables)
    n = q.size
    residual[:] = 0.0
    if with_matrix:
        band[:, :kl + 1 if lower else band.shape[1]] = 0.0
    add_elastic(q, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, residual, band, kl, c_K,
                with_matrix, element_work(tables), strain_rate_weights, c_C, qd, lower)  # with the axial damping
    for i in range(n):
        residual[i] = -residual[i] - ext_Q[i]
    n_slots = mass_slots.shape[0]
    a0, a1, a2 = axis[0], axis[1], axis[2]
    t00, t01, t02, t11, t12, t22 = a0 * a0, a0 * a1, a0 * a2, a1 * a1, a1 * a2, a2 * a2
    for s in range(n_slots):
        node = s // 2
        m0 = m1 = m2 = 0.0
        last = s + 1 if with_matrix and lower else min(n_slots, 2 * node + 4)
        for s2 in range(max(0, 2 * node - 2), min(n_slots, 2 * node + 4)):  # the slots of the nodes beside
            m = mass_slots[s, s2]
            ci = damping_isotropic[s, s2]
            ca = damping_transverse[s, s2]
            v0, v1, v2 = qd[3 * s2], qd[3 * s2 + 1], qd[3 * s2 + 2]
            transverse = ca * (a0 * v0 + a1 * v1 + a2 * v2)
            m0 += m * qdd[3 * s2] + ci * v0 + transverse * a0
            m1 += m * qdd[3 * s2 + 1] + ci * v1 + transverse * a1
            m2 += m * qdd[3 * s2 + 2] + ci * v2 + transverse * a2
            if with_matrix and s2 < last:  # the 3 x 3 block (c_M m + c_C ci) I + c_C ca t t^T at rows 3 s, columns 3 s2
                isotropic = c_M * m + c_C * ci
                along = c_C * ca
                offset = 3 * (s2 - s) + kl
                first = band[3 * s]  # matrix column 3 s2 + c2 of row 3 s + c at band[3 s + c, offset + c2 - c]
                second = band[3 * s + 1]
                third = band[3 * s + 2]
                first[offset] += isotropic + along * t00
                second[offset - 1] += along * t01
                second[offset] += isotropic + along * t11
                third[offset - 2] += along * t02
                third[offset - 1] += along * t12
                third[offset] += isotropic + along * t22
                if s2 < s or not lower:
                    first[offset + 1] += along * t01
                    first[offset + 2] += along * t02
                    second[offset + 1] += along * t12
        residual[3 * s] += m0
        residual[3 * s + 1] += m1
        residual[3 * s + 2] += m2
    if with_matrix and ext_band.shape[0] > 0:
        for i in range(n):
            for column in range(kl + 1 if lower else 2 * kl + 1):
                band[i, column] += ext_band[i, column]
    for i in range(n):
        if not active[i]:
            residual[i] = 0.0
            if with_matrix:
                for j in range(max(0, i - kl), i if lower else min(n, i + kl + 1)):  # row i (left of the diagonal)
                    band[i, j - i + kl] = 0.0
                for j in range(i + 1 if lower else max(0, i - kl), min(n, i + kl + 1)):  # column i (below it)
                    band[j, i - j + kl] = 0.0
                band[i, kl] = 1.0


@njit(cache=True, **NO_REFCOUNTS)
def update_rates(values, history, coef, active):
    """q', q'' and a of the active coordinates from q (generalized-alpha, Arnold-Bruels form):
    q = q_n + h q'_n + h^2 (b0 a_n + b1 a),  q' = q'_n + h (g0 a_n + g1 a),
    (1 - alpha_m) a + alpha_m a_n = (1 - alpha_f) q'' + alpha_f q''_n.
    values, history: rows [q, q', q'', a] (4, n); coef = [h, alpha_m, alpha_f, b0, b1, g0, g1]."""
    h, am, af, b0, b1, g0, g1 = coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6]
    for i in range(values.shape[1]):
        if active[i]:
            a_new = (values[0, i] - history[0, i] - h * history[1, i] - h * h * b0 * history[3, i]) / (h * h * b1)
            values[3, i] = a_new
            values[1, i] = history[1, i] + h * (g0 * history[3, i] + g1 * a_new)
            values[2, i] = ((1.0 - am) * a_new + am * history[3, i] - af * history[2, i]) / (1.0 - af)


PREDICT_ACCELERATION, PREDICT_POSITION = 0, 1
# Newton iterations granted to the extrapolating predictor before restarting from q_n: smooth motion converges in
# 1-2; after a sudden load change the consistent accelerations are dominated by unresolved modes and extrapolation
# is useless (measured: no convergence in 25 iterations where q_n converges in 6).
EXTRAPOLATION_ITERATIONS = 3


@njit(cache=True)
def predictor_for_attempt(attempt, extrapolate):
    """Predictor of a step's first (0) and second (1) Newton attempt: extrapolation first while it works; after it
    failed, q_n first until that converges quickly (``keeps_extrapolating``)."""
    if (attempt == 0) == extrapolate:
        return PREDICT_ACCELERATION
    return PREDICT_POSITION


@njit(cache=True)
def predictor_budget(predictor, max_iterations):
    """Newton iterations granted to an attempt with this predictor."""
    if predictor == PREDICT_ACCELERATION:
        return min(EXTRAPOLATION_ITERATIONS, max_iterations)
    return max_iterations


@njit(cache=True)
def keeps_extrapolating(predictor, iterations):
    """After a converged attempt: extrapolate again once q_n converges quickly (smooth motion)."""
    return predictor == PREDICT_ACCELERATION or iterations <= 2


@njit(cache=True, **NO_REFCOUNTS)
def predict(values, history, prescribed, coef, active, predictor):
    """Start of a step: constrained coordinates from ``prescribed`` (rows q, q', q''); active ones from the
    predictor q''_{n+1} = q''_n (PREDICT_ACCELERATION: accurate for smooth motion) or q_{n+1} = q_n
    (PREDICT_POSITION: robust when unresolved high-frequency content makes extrapolation useless)."""
    h, am, b0, b1 = coef[0], coef[1], coef[3], coef[4]
    for i in range(values.shape[1]):
        if active[i]:
            if predictor == PREDICT_ACCELERATION:
                a0 = (history[2, i] - am * history[3, i]) / (1.0 - am)
                values[0, i] = history[0, i] + h * history[1, i] + h * h * (b0 * history[3, i] + b1 * a0)
            else:
                values[0, i] = history[0, i]
        else:
            values[0, i] = prescribed[0, i]
            values[1, i] = prescribed[1, i]
            values[2, i] = prescribed[2, i]
            values[3, i] = prescribed[2, i]
    update_rates(values, history, coef, active)


@njit(cache=True)
def rate_coefficients(coef, dynamic):
    """(c_M, c_C) = (dq''/dq, dq'/dq); zero for statics."""
    if not dynamic:
        return 0.0, 0.0
    h, am, af, b1, g1 = coef[0], coef[1], coef[2], coef[4], coef[6]
    return (1.0 - am) / ((1.0 - af) * h * h * b1), g1 / (h * b1)


CHOLESKY, LU = 0, 1


@njit(cache=True, **NO_REFCOUNTS)
def iterate(values, history, coef, dynamic, active, scale, tables, axis, ext_Q, ext_band, residual, band, pivots,
            factorization, kl, refactor, symmetric):
    """One Newton (refactor) or chord correction; updates values (rows q, q', q'', a).

    A symmetric matrix is factored by Cholesky, falling back to pivoted LU if it is not positive definite
    (e.g. under axial compression); factorization[0] records which one the chord steps reuse.
    Returns the scaled correction max_i |dq_i| / scale_i, or -1 for a singular matrix or non-finite values."""
    c_M, c_C = rate_coefficients(coef, dynamic)
    q, qd, qdd = values[0], values[1], values[2]
    assemble_system(q, qd, qdd, tables, axis, ext_Q, ext_band, 1.0, c_M, c_C, active, residual, band, kl, refactor,
                    symmetric)
    if refactor:
        factorization[0] = CHOLESKY
        if not (symmetric and band_cholesky(band, kl)):
            if symmetric:  # the failed Cholesky overwrote the matrix
                assemble_system(q, qd, qdd, tables, axis, ext_Q, ext_band, 1.0, c_M, c_C, active, residual, band, kl,
                                True)
            factorization[0] = LU
            if not band_factor(band, pivots, kl):
                return -1.0
    if factorization[0] == CHOLESKY:
        cholesky_solve(band, kl, residual)
    else:
        band_solve(band, pivots, kl, residual)
    norm = 0.0
    total = 0.0  # NaN-safe: max() would drop a NaN correction, a sum keeps it
    for i in range(q.size):
        if active[i]:
            correction = residual[i]
            q[i] -= correction
            total += abs(correction)
            norm = max(norm, abs(correction) / scale[i])
    if not total < np.inf:
        return -1.0
    if dynamic:
        update_rates(values, history, coef, active)
    return norm


@njit(cache=True)
def newton_control(norm, previous, tol, always_refactor):
    """CONVERGED, CHORD, REFACTOR or FAILED after a correction of scaled size norm (previous: the one before).
    The factorization is kept (chord step) only close to the solution (correction below CHORD_RANGE, where the
    Jacobian barely changes) and while corrections shrink by CHORD_CONTRACTION or better; otherwise full Newton."""
    if norm < 0.0 or norm > DIVERGED_CORRECTION:
        return FAILED
    if norm <= tol:
        return CONVERGED
    if always_refactor or norm > CHORD_RANGE or norm > CHORD_CONTRACTION * previous:
        return REFACTOR
    return CHORD


@njit(inline="always")
def newton(values, history, prescribed, coef, dynamic, predictor, active, scale, tables, axis, constant_Q, ext_Q,
           residual, band, ext_band, pivots, factorization, kl, tol, max_iterations, always_refactor, fresh_matrix,
           assemble, forces, rotation):
    """The Newton loop of every compiled path (:mod:`needle_sim_ros.model.step`'s contributions' forces assembled
    before every correction): dynamics starts from the predictor, statics from the given values. ext_Q <- the
    constant external force plus ``assemble(forces, q, q', rotation, ext_Q, ext_band, kl, c_q, c_q')`` (the
    contributions' Q, and whenever the matrix is refactored their part of it, -(dQ/dq + c_C dQ/dq'), into
    ``ext_band``; a (0, 0) ``ext_band`` for none). ``fresh_matrix=False`` starts with chord steps on the
    factorization already in ``band`` (modified Newton across steps; ``newton_control`` refactors as soon as they
    contract too slowly). Inlined into its callers, so ``assemble`` is a compile-time constant there.
    Returns (status CONVERGED / FAILED / 1 = not converged, iterations, last scaled correction)."""
    if dynamic:
        predict(values, history, prescribed, coef, active, predictor)
    c_qd = rate_coefficients(coef, dynamic)[1]
    no_band = ext_band[:0]  # (0, ...): no matrix
    refactor, previous, norm, symmetric = fresh_matrix, np.inf, np.inf, True
    for iteration in range(max_iterations):
        q, qd = values[0], values[1]
        ext_Q[:] = constant_Q
        if refactor:
            ext_band[:, :] = 0.0
            ok = assemble(forces, q, qd, rotation, ext_Q, ext_band, kl, -1.0, -c_qd)
            symmetric = band_symmetric(ext_band, kl)
        else:  # a chord step reuses the factorization: Q alone
            ok = assemble(forces, q, qd, rotation, ext_Q, no_band, 0, 0.0, 0.0)
        if not ok:
            return FAILED, iteration + 1, norm
        norm = iterate(values, history, coef, dynamic, active, scale, tables, axis, ext_Q, ext_band, residual, band,
                       pivots, factorization, kl, refactor, symmetric)
        action = newton_control(norm, previous, tol, always_refactor)
        if action == CONVERGED or action == FAILED:
            return action, iteration + 1, norm
        refactor, previous = action == REFACTOR, norm
    return 1, max_iterations, norm


@njit(cache=True)
def no_forces(forces, q, qd, rotation, Q, band, kl, c_q, c_qd):
    """The assemble kernel of no contribution (a constant external force only)."""
    return True
