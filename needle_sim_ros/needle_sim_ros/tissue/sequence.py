"""A run of time steps through the tissue in one compiled call: the simulator's fast path with the tissue on.

Per step, as the general path does it (``model.data.step`` with ``Integrator.step`` and ``TissueModel.advance``):
the base node kinematics imposed from the packed base motion; Newton (predictor choice and budgets alike, a fresh
matrix every step) with the tissue's contributions of the step -- the shaft's lateral and axial point forces, the
bevel tip and the seed 002 tip -- assembled before every correction in the order of ``TissueModel.at`` and their
Jacobians whenever the matrix is refactored; then the tissue advanced (``advance``) and the base wrench (eq. 20)
under the next step's contributions (evaluated only if one acts on the base element, as ``reaction_wrench``).
The tissue state travels through the run as arrays: the contact and the track, the shaft anchors, active points
and law state, and the next step's frozen shaft data.
A step that does not converge ends the run (as a bevel side along the tip tangent does); the caller integrates it
with the general path (sub-stepping, errors) and continues.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.model.banded import band_symmetric
from needle_sim_ros.model.newton import (CONVERGED, FAILED, REFACTOR, iterate, keeps_extrapolating, newton_control,
                                         predict, predictor_budget, predictor_for_attempt, rate_coefficients)
from needle_sim_ros.model.reaction import base_wrench_kernel
from needle_sim_ros.model.sequence import EXTRAPOLATE, impose_base

from .advance import advance_contact, advance_shaft, tip_parameters
from .coupling import (bevel_tip_assembly, first_slot_in, shaft_arguments, shaft_forces_assembly,
                       tip_resistance_assembly)


@njit(cache=True)
def tissue_forces(q, qd, constant_Q, lateral, axial, rotation, tip, scale, punctured, cutting, ext_Q, band, kl, c_q,
                  c_qd):
    """ext_Q <- constant_Q + the tissue's generalized forces at (q, qd), each contribution on its own Q then added
    (shaft, bevel, tip resistance: the general path's order); c_q dQ/dq + c_qd dQ/dq' added to band unless it is
    (0, 0). ``tip``: ``TissueModel.tip_arguments``. False if the bevel side lies along the tip tangent."""
    (bevel_on, axial_force, transverse_force, side_base, _, resistance_on, entry_point, entry_normal, a1, a2,
     cutting_force, speed_scale) = tip
    ext_Q[:] = constant_Q
    Q = np.zeros(q.size)
    shaft_forces_assembly(q, qd, shaft_arguments(lateral), shaft_arguments(axial), Q, band, kl, c_q, c_qd)
    ext_Q += Q
    if bevel_on:
        Q[:] = 0.0
        if scale != 0.0 and not bevel_tip_assembly(q, rotation, side_base, axial_force, transverse_force, scale, Q,
                                                   band, kl, c_q, c_qd):
            return False
        ext_Q += Q
    if resistance_on:
        Q[:] = 0.0
        tip_resistance_assembly(q, qd, punctured, cutting, entry_point, entry_normal, a1, a2, cutting_force,
                                speed_scale, Q, band, kl, c_q, c_qd)
        ext_Q += Q
    return True


@njit(cache=True)
def tissue_newton(values, history, prescribed, coef, predictor, active, scale, tables, axis, constant_Q, residual,
                  band, ext_band, pivots, factorization, kl, tol, max_iterations, lateral, axial, rotation, tip,
                  bevel_scale, punctured, cutting):
    """Newton with the tissue's contributions (``NewtonSolver.solve`` with state-dependent forces): the forces
    before every correction, their Jacobians into ``ext_band`` whenever the matrix is refactored. Returns (status
    CONVERGED / FAILED / 1 = not converged, iterations, last scaled correction)."""
    predict(values, history, prescribed, coef, active, predictor)
    c_qd = rate_coefficients(coef, True)[1]
    ext_Q = np.empty(constant_Q.size)
    no_band = np.zeros((0, 0))
    refactor, previous, norm, symmetric = True, np.inf, np.inf, True
    for iteration in range(max_iterations):
        q, qd = values[0], values[1]
        if refactor:
            ext_band[:, :] = 0.0
            ok = tissue_forces(q, qd, constant_Q, lateral, axial, rotation, tip, bevel_scale, punctured, cutting,
                               ext_Q, ext_band, kl, -1.0, -c_qd)
            symmetric = band_symmetric(ext_band, kl)
        else:  # a chord step reuses the factorization: Q alone
            ok = tissue_forces(q, qd, constant_Q, lateral, axial, rotation, tip, bevel_scale, punctured, cutting,
                               ext_Q, no_band, 0, 0.0, 0.0)
        if not ok:
            return FAILED, iteration + 1, norm
        norm = iterate(values, history, coef, True, active, scale, tables, axis, ext_Q, ext_band, residual, band,
                       pivots, factorization, kl, refactor, symmetric)
        action = newton_control(norm, previous, tol, False)
        if action == CONVERGED or action == FAILED:
            return action, iteration + 1, norm
        refactor, previous = action == REFACTOR, norm
    return 1, max_iterations, norm


@njit(cache=True)
def integrate_tissue_sequence(history, times, motions, rotations, needle, constant_Q, control, contact, contact_time,
                              shaft, lateral, axial, contact_arguments, shaft_constants, tip, states, wrenches,
                              iterations):
    """Integrate from history (rows q, q', q'', a) one step per end time (k,) and packed base motion (k, 19) with
    rotations (k, 3, 3), the tissue advanced after each. ``needle``: ``Integrator.run_arguments``; ``contact``:
    ``advance_contact``'s tuple, ``contact_time`` its time (NaN: never); ``shaft``: (law state, anchors, active);
    ``lateral``, ``axial``: the frozen parts of the first step; ``contact_arguments``: (entry point, entry normal,
    puncture depth, track spacing); ``shaft_constants``: ``ShaftSupport.kernel_arguments``. Writes each step's
    rows, wrench (``holder_wrench``) and Newton corrections into states, wrenches, iterations. Returns (steps done:
    k, or the index of the first step that did not converge; the tissue state after them as passed in)."""
    (coef, tol, max_iterations, prescribed, base_nodes, base_local_r, base_local_rx, active, scale, tables, rows,
     residual, band, ext_band, pivots, factorization, kl) = needle
    entry_point, entry_normal, puncture_depth, spacing = contact_arguments
    edge_a, bottoms, table = tip[4], shaft_constants[12], shaft_constants[13]
    law_state, anchor, was_active = shaft
    values = np.empty_like(history)
    current = history.copy()
    single_element = history.shape[1] == 12  # the tip forces act on the base element's rows too
    external = np.empty(6)
    Q = np.zeros(constant_Q.size)
    no_band = np.zeros((0, 0))
    bevel_scale, cutting = tip_parameters(contact[0], contact[4], contact[1], edge_a, bottoms, table)
    for i in range(times.size):
        rotation = rotations[i]
        axis = impose_base(motions[i], rotation, base_local_r, base_local_rx, base_nodes, prescribed)
        total = 0
        status = -1
        for attempt in range(2):
            predictor = predictor_for_attempt(attempt, control[EXTRAPOLATE] == 1)
            budget = predictor_budget(predictor, max_iterations)
            status, used, norm = tissue_newton(values, current, prescribed, coef, predictor, active, scale, tables,
                                               axis, constant_Q, residual, band, ext_band, pivots, factorization, kl,
                                               tol, budget, lateral, axial, rotation, tip, bevel_scale, contact[0],
                                               cutting)
            total += used
            if status == CONVERGED:
                control[EXTRAPOLATE] = 1 if keeps_extrapolating(predictor, used) else 0
                break
        if status != CONVERGED:
            return i, contact, contact_time, (law_state, anchor, was_active), lateral, axial
        current[:, :] = values
        states[i] = values
        iterations[i] = total
        q, qd = values[0], values[1]
        contact = advance_contact(contact[0], contact_time, contact[5], contact[6], contact[7], contact[8],
                                  contact[9], q, qd, times[i], entry_point, entry_normal, puncture_depth, spacing)
        contact_time = times[i]
        law_state, anchor, was_active, lateral, axial = advance_shaft(
            q, contact[5], contact[6], contact[9], contact[1], contact[2], contact[3], anchor, was_active, law_state,
            *shaft_constants)
        bevel_scale, cutting = tip_parameters(contact[0], contact[4], contact[1], edge_a, bottoms, table)
        external[:] = constant_Q[:6]
        if single_element or first_slot_in(lateral[2], 0) or first_slot_in(axial[2], 0):  # touches the base's rows
            tissue_forces(q, qd, constant_Q, lateral, axial, rotation, tip, bevel_scale, contact[0], cutting, Q,
                          no_band, 0, 0.0, 0.0)
            external[:] = Q[:6]
        wrenches[i] = base_wrench_kernel(q, qd, values[2], *rows, rotation, external)
    return times.size, contact, contact_time, (law_state, anchor, was_active), lateral, axial
