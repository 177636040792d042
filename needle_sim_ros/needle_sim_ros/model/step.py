"""The compiled step loop: one run of time steps in one numba call, the same stages for every compiled path.

Per step, with fixed stages:
1. predict -- the base node kinematics imposed from the packed base motion (eqs. 18-19), the predictor of the
   attempt (``newton.predict``);
2. assemble -- the internal forces and the contribution's forces and Jacobians (``newton.newton``);
3. Newton with one retry policy: the extrapolating predictor first while it works, then q_n (predictor choice and
   budgets as :meth:`~needle_sim_ros.model.integrators.Integrator.step`); a step that does not converge ends the
   run, the caller integrates it with the general path (sub-stepping, errors) and continues;
4. commit -- the state accepted and the contribution's state advanced (``advance``);
5. reaction -- the base wrench (eq. 20) under the contribution's forces of the next step (evaluated only where
   they act on the base element's rows).

A contribution is its state (any numba value: a named tuple of arrays, or 0.0 for none) and four compiled
kernels, passed to :func:`run_steps` by the module-level entry that composes them (``run_steps`` is inlined
there, so the kernels are compile-time constants and the entry is cached like any other):
* ``acting(state) -> forces``: what acts over the step starting from the state (only what ``assemble`` reads:
  it is passed to every correction);
* ``assemble(forces, q, qd, rotation, Q, band, kl, c_q, c_qd) -> bool``: adds its generalized force to Q and, if
  ``band`` is not (0, 0), c_q dQ/dq + c_qd dQ/dq' to the band matrix; False if it cannot be assembled;
* ``advance(state, q, qd, t) -> state``: the state after a step accepted at (q, q', t);
* ``touches_base(forces) -> bool``: whether the forces act on the base element's rows (the reaction needs them).
With no state-dependent contribution (``keep_matrix``) the iteration matrix is kept across steps while the base
holds still and the steps converge in a single correction: then no matrix is assembled or factored at all (a
needle held still under a load: 22 instead of 40 us per step). Otherwise a step starts with a fresh matrix: chord
corrections on an older matrix converge slowly (released from a 10 g tip load: 4.2 corrections per step instead
of 2.1; pitching base: 3.0 instead of 1.1).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .kinematics import rigid_node_kinematics
from .newton import CONVERGED, keeps_extrapolating, newton, predictor_budget, predictor_for_attempt, unpack_tables
from .reaction import base_wrench_kernel

EXTRAPOLATE, FACTORED = 0, 1  # entries of the control flags


@njit(cache=True)
def impose_base(motion, rotation, base_local_r, base_local_rx, base_nodes, prescribed):
    """The base nodes' prescribed rows (q, q', q'') from a packed base motion (19,) and its rotation (eqs. 18-19);
    returns the base axis (the rotation's first column)."""
    rigid_node_kinematics(motion[0:3], rotation, motion[7:10], motion[10:13], motion[13:16], motion[16:19],
                          base_local_r, base_local_rx, base_nodes, prescribed)
    return rotation[:, 0].copy()


@njit(cache=True)
def base_tables(tables):
    """``reaction.base_rows`` from the model tables: element 0's quadrature tables and the base slots' rows."""
    (axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, mass_slots, damping_isotropic,
     damping_transverse, strain_rate_weights) = unpack_tables(tables)
    return (axial_S_x[:1], axial_weights[:1], bending_S_x[:1], bending_S_xx[:1], bending_weights[:1],
            strain_rate_weights[:1], mass_slots[:2, :4], damping_isotropic[:2, :4], damping_transverse[:2, :4])


@njit(inline="always")
def run_steps(history, times, motions, rotations, constant_Q, solver, base, work, control, last_motion, keep_matrix,
              state, acting, assemble, advance, touches_base, outputs):
    """Integrate from history (rows q, q', q'', a at t_n) one step per end time (k,) and packed base motion
    (k, 19) with rotations (k, 3, 3) (module docstring). ``solver``: (scheme coefficients, tolerance, iteration
    limit, active mask, scales, model tables, bandwidth); ``base``: (prescribed rows, base nodes, their local
    offsets r and r_x); ``work``: (residual, band, ext_band, pivots, factorization). ``control`` [extrapolate,
    factored] and ``last_motion`` (the motion the kept factorization in ``band`` was made for) carry over between
    runs. Writes each step's rows into the outputs' states (k, 4, n), its wrench on the holder [force, torque in
    the world frame, force, torque in the base frame] into wrenches (k, 12) and its Newton corrections into
    iterations (k,). Returns (steps done: k, or the index of the first step that did not converge; the
    contribution's state after them)."""
    coef, tol, max_iterations, active, scale, tables, kl = solver
    prescribed, base_nodes, base_local_r, base_local_rx = base
    residual, band, ext_band, pivots, factorization = work
    states, wrenches, iterations = outputs
    values = np.empty_like(history)
    current = history.copy()
    n = history.shape[1]
    ext_Q = np.empty(n)
    no_band = np.zeros((0, 0))
    rows = base_tables(tables)
    forces = acting(state)
    for i in range(times.size):
        motion, rotation = motions[i], rotations[i]
        axis = impose_base(motion, rotation, base_local_r, base_local_rx, base_nodes, prescribed)  # 1. predict
        moved = False
        if keep_matrix:
            moved = np.any(motion != last_motion)
            last_motion[:] = motion
        total = 0
        status = -1
        for attempt in range(2):  # 2.-3. assemble and Newton, one retry from q_n
            predictor = predictor_for_attempt(attempt, control[EXTRAPOLATE] == 1)
            budget = predictor_budget(predictor, max_iterations)
            fresh = not keep_matrix or control[FACTORED] == 0 or moved
            status, used, norm = newton(values, current, prescribed, coef, True, predictor, active, scale, tables,
                                        axis, constant_Q, ext_Q, residual, band, ext_band, pivots, factorization, kl,
                                        tol, budget, False, fresh, assemble, forces, rotation)
            total += used
            if keep_matrix:
                control[FACTORED] = 1 if status != -1 else 0
            if status == CONVERGED:
                control[EXTRAPOLATE] = 1 if keeps_extrapolating(predictor, used) else 0
                break
        if status != CONVERGED:
            control[FACTORED] = 0
            return i, state
        if total > 1:  # the matrix is kept for the next step only while a single correction sufficed
            control[FACTORED] = 0
        current[:, :] = values  # 4. commit
        states[i] = values
        iterations[i] = total
        q, qd = values[0], values[1]
        state = advance(state, q, qd, times[i])
        forces = acting(state)
        ext_Q[:] = constant_Q  # 5. reaction
        if n == 12 or touches_base(forces):
            assemble(forces, q, qd, rotation, ext_Q, no_band, 0, 0.0, 0.0)
        wrenches[i] = base_wrench_kernel(q, qd, values[2], *rows, rotation, ext_Q[:6].copy())
    return times.size, state


@njit(cache=True)
def keep(state, q, qd, t):
    """The advance kernel of a contribution without state."""
    return state


@njit(cache=True)
def itself(state):
    """The acting kernel of a contribution whose state is what its assemble kernel reads."""
    return state


@njit(cache=True)
def off_base(state):
    """The touches_base kernel of a contribution that never acts on the base element."""
    return False


def compiled_run(assemble, advance=keep, touches_base=off_base):
    """The compiled run of steps (:func:`run_steps`, a fresh matrix every step) with one contribution given by its
    kernels, whose state is one float64 array (its parameters and state in a named layout): a numba function of
    (history, times, motions, rotations, scheme coefficients, constant force, ``Integrator.run_arguments`` after
    the coefficients, control flags, state, states, wrenches, iterations) returning (steps done, state after)."""

    @njit(cache=True)
    def run(history, times, motions, rotations, coef, constant_Q, tol, max_iterations, prescribed, base_nodes,
            base_local_r, base_local_rx, active, scale, tables, residual, band, ext_band, pivots, factorization, kl,
            control, state, states, wrenches, iterations):
        return run_steps(history, times, motions, rotations, constant_Q,
                         (coef, tol, max_iterations, active, scale, tables, kl),
                         (prescribed, base_nodes, base_local_r, base_local_rx),
                         (residual, band, ext_band, pivots, factorization), control, np.empty(19), False, state,
                         itself, assemble, advance, touches_base, (states, wrenches, iterations))
    return run
