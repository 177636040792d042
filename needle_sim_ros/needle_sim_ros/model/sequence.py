"""A run of time steps in one compiled call: the fast path of the simulator's fixed-rate loop.

For the common case -- the constrained coordinates driven by the base frame (eqs. 18-19) or fixed in the world,
and only state-independent, time-invariant external forces (gravity, world-frame point loads) -- a sequence of k
steps needs no Python between the steps: per step the base node kinematics are imposed from the packed base
motion, Newton runs as in :meth:`needle_sim_ros.model.integrators.Integrator.step` (predictor choice and budgets
alike), and the base reaction wrench (eq. 20) is evaluated. The iteration matrix is kept across steps (modified
Newton) only while the base holds still and the steps converge in a single correction: then no matrix is
assembled or factored at all (a needle held still under a load: 22 instead of 40 us per step). Otherwise a step
starts with a fresh matrix, as the general path does every step: chord corrections on an older matrix converge
slowly (released from a 10 g tip load: 4.2 corrections per step instead of 2.1; pitching base: 3.0 instead of 1.1).
A step that does not converge ends the run; the caller integrates it with the general path (sub-stepping) and
continues.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .banded import ELEMENT_BANDWIDTH, band_width_columns
from .kinematics import rigid_node_kinematics
from .newton import (CONVERGED, keeps_extrapolating, model_tables, newton_solve, predictor_budget,
                     predictor_for_attempt)
from .reaction import base_constraint_kernel, base_rows, holder_wrench

EXTRAPOLATE, FACTORED = 0, 1  # entries of the control flags


class SequenceBuffers:
    """Work arrays of the compiled step sequence of one model (the factorization kept across steps is in the
    ``IntegratorMemory`` of the needle's data)."""

    def __init__(self, model) -> None:
        n = model.n_dof
        self.tables = model_tables(model)
        self.base_rows = base_rows(model)
        self.active = model.partition.active
        self.scale = model.increment_scale
        self.history = np.empty((4, n))  # rows q, q', q'', a of the start state
        self.residual = np.empty(n)
        groups = model.partition.groups
        self.supported = all(g.fixed is not None or g.frame == "base" for g in groups)
        moving = [g for g in groups if g.fixed is None]
        self.base_nodes = np.concatenate([g.nodes for g in moving]).astype(np.int64)
        self.base_local_r = np.ascontiguousarray(np.concatenate([g.local_r for g in moving]))
        self.base_local_rx = np.ascontiguousarray(np.concatenate([g.local_rx for g in moving]))
        self.prescribed = np.zeros((3, n))  # world-fixed coordinates once; the base nodes are written per step
        for group in groups:
            if group.fixed is not None:
                self.prescribed[:, group.dofs] = group.fixed


class IntegratorMemory:
    """What the integrator carries from one step to the next (part of the needle's data, changed in place by the
    integrator): ``control`` [extrapolate, factored]: whether Newton starts from the extrapolating predictor and
    whether the kept factorization is valid; the kept factorization of the compiled sequence (``band``, ``pivots``,
    ``factorization``), the step length ``h`` and the packed base motion ``last_motion`` it was made for."""

    def __init__(self, n_dof: int) -> None:
        self.control = np.array([1, 0], dtype=np.int64)
        self.band = np.zeros((n_dof, band_width_columns(ELEMENT_BANDWIDTH)))
        self.pivots = np.zeros(n_dof, dtype=np.int64)
        self.factorization = np.zeros(1, dtype=np.int64)
        self.last_motion = np.full(19, np.nan)
        self.h = 0.0

    @property
    def extrapolate(self) -> bool:
        return bool(self.control[EXTRAPOLATE])

    def invalidate(self) -> None:
        """The kept factorization no longer belongs to the current motion (e.g. after a general step)."""
        self.control[FACTORED] = 0

    def copy(self) -> IntegratorMemory:
        memory = IntegratorMemory.__new__(IntegratorMemory)
        memory.__dict__.update({name: value.copy() if isinstance(value, np.ndarray) else value
                                for name, value in self.__dict__.items()})
        return memory


@njit(cache=True)
def impose_base(motion, rotation, base_local_r, base_local_rx, base_nodes, prescribed):
    """The base nodes' prescribed rows (q, q', q'') from a packed base motion (19,) and its rotation (eqs. 18-19);
    returns the base axis (the rotation's first column)."""
    rigid_node_kinematics(motion[0:3], rotation, motion[7:10], motion[10:13], motion[13:16], motion[16:19],
                          base_local_r, base_local_rx, base_nodes, prescribed)
    return rotation[:, 0].copy()


@njit(cache=True)
def integrate_sequence(history, motions, rotations, coef, ext_Q, tol, max_iterations, prescribed, base_nodes,
                       base_local_r, base_local_rx, active, scale, tables, rows, residual, band, pivots,
                       factorization, kl, control, last_motion, states, wrenches, iterations):
    """Integrate from history (rows q, q', q'', a at t_n) one step per packed base motion (k, 19) with rotations
    (k, 3, 3). Writes each step's rows into states (k, 4, n), its wrench on the holder [force, torque in the world
    frame, force, torque in the base frame] into wrenches (k, 12) and its Newton corrections into iterations (k,).
    Returns the number of steps done: k, or the index of the first step that did not converge."""
    values = np.empty_like(history)
    current = history.copy()
    (axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, strain_rate_weights, mass_rows,
     isotropic_rows, transverse_rows) = rows
    external = ext_Q[:6].copy()
    for i in range(motions.shape[0]):
        m = motions[i]
        rotation = rotations[i]
        axis = impose_base(m, rotation, base_local_r, base_local_rx, base_nodes, prescribed)
        moved = np.any(m != last_motion)
        last_motion[:] = m
        total = 0
        status = -1
        for attempt in range(2):
            predictor = predictor_for_attempt(attempt, control[EXTRAPOLATE] == 1)
            budget = predictor_budget(predictor, max_iterations)
            status, used, norm = newton_solve(values, current, prescribed, coef, True, predictor, active, scale,
                                              tables, axis, ext_Q, residual, band, pivots, factorization, kl, tol,
                                              budget, False, control[FACTORED] == 0 or moved)
            total += used
            control[FACTORED] = 1 if status != -1 else 0
            if status == CONVERGED:
                control[EXTRAPOLATE] = 1 if keeps_extrapolating(predictor, used) else 0
                break
        if status != CONVERGED:
            control[FACTORED] = 0
            return i
        if total > 1:  # the matrix is kept for the next step only while a single correction sufficed
            control[FACTORED] = 0
        current[:, :] = values
        states[i] = values
        iterations[i] = total
        constraint = base_constraint_kernel(values[0, :12].copy(), values[1, :12].copy(), values[2, :12].copy(),
                                            axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights,
                                            strain_rate_weights, mass_rows, isotropic_rows, transverse_rows, axis,
                                            external)
        wrenches[i] = holder_wrench(values[0, 3:6].copy(), constraint, rotation)
    return motions.shape[0]
