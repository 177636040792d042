"""Implicit fixed-step integration of the active coordinates (seed 000 eq. 19): Newton on the analytic Jacobian,
automatic sub-stepping.

Schemes, all in the Arnold-Bruels form of generalized-alpha (eq. 19 holds at t_{n+1}, so q'' is the step's true
acceleration and eq. 20 a consistent base wrench); design notes and measurements: docs/design_notes.md:
* ``generalized_alpha`` (Chung-Hulbert): alpha_m = (2 rho - 1)/(rho + 1), alpha_f = rho/(rho + 1),
  gamma = 1/2 - alpha_m + alpha_f, beta = (1 - alpha_m + alpha_f)^2 / 4; rho_inf in [0, 1] (1: trapezoidal rule,
  no numerical damping; unstable under large deformations with unresolved high frequencies: use <= 0.95).
* ``hht``: alpha_m = 0, alpha_f = (1 - rho)/(1 + rho), rho_inf in [0.5, 1].
* ``backward_euler``: q' = q'_n + h q'', q = q_n + h q'; first order, the robust fallback.
Newton starts from the constant-acceleration predictor, after ``newton.EXTRAPOLATION_ITERATIONS`` once more from
q_n (kept until it converges within two iterations again). A failed step (no convergence, singular matrix,
non-finite values) is retried as 2, 4, ... sub-steps (prescribed coordinates by quintic Hermite interpolation) up to
``max_substep_halvings`` times, then ``StepFailed`` is raised. The input state is never modified.
"""
from __future__ import annotations

import math
import operator
from typing import NamedTuple

import numpy as np
from numba import njit

from .kinematics import BaseMotion
from .model import NeedleModel, State
from .newton import CONVERGED, assemble_system, model_tables, newton
from .banded import (ELEMENT_BANDWIDTH, add_dense_to_band, band_cholesky, band_structure, band_width_columns,
                     cholesky_solve)
from .forces import check_forces
from .partition import hermite_quintic
from .reaction import BaseWrench
from .step import EXTRAPOLATE, FACTORED, general_step, integrate_sequence, interpreted, solve_step

METHODS = ("generalized_alpha", "hht", "backward_euler")


class StepFailed(RuntimeError):
    """The integrator could not advance the state, even with sub-stepping."""


class SequenceResult(NamedTuple):
    """Steps done by :meth:`Integrator.step_sequence` and, per step, the rows [q, q', q'', a] (done, 4, n_dof),
    the wrench on the holder [force, torque world; force, torque base frame] (done, 12) and Newton corrections."""

    done: int
    states: np.ndarray
    wrenches: np.ndarray
    iterations: np.ndarray

    @classmethod
    def of_run(cls, done: int, outputs: tuple) -> SequenceResult:
        """The first ``done`` steps of a run's outputs (:func:`run_outputs`)."""
        states, wrenches, iterations = outputs
        return cls(done, states[:done], wrenches[:done], iterations[:done])


def run_outputs(steps: int, n_dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """New output arrays of a compiled run of ``steps`` steps: states (steps, 4, n_dof), wrenches (steps, 12),
    Newton corrections (steps,)."""
    return np.empty((steps, 4, n_dof)), np.empty((steps, 12)), np.zeros(steps, dtype=np.int64)


@njit(cache=True)
def step_to(q, qd, qdd, aux, t_next, packed, rotation, history, coef, ext_Q, tol, max_iterations, prescribed,
            base_nodes, base_local_r, base_local_rx, active, scale, tables, residual, band, pivots, factorization, kl,
            control, last_motion):
    """One step from (q, qd, qdd, aux) to ``t_next`` with the base motion ``packed`` (:attr:`BaseMotion.packed`)
    and its rotation, on a fresh matrix: :func:`integrate_sequence` for one step (history ... last_motion: its
    arguments after the motions and rotations, :meth:`Integrator.sequence_arguments`), the start rows, motion, end
    time and outputs made here rather than by numpy calls from Python. Returns (rows [q, q', q'', a] (4, n_dof),
    wrench (12,), Newton corrections), the rows None where Newton did not converge."""
    motion = np.empty((1, 19))
    motion[0] = packed
    rotations = np.empty((1, 3, 3))
    rotations[0] = rotation
    history[0], history[1], history[2], history[3] = q, qd, qdd, aux
    control[FACTORED] = 0  # the fresh matrix replaces the factorization a run kept
    states, wrenches, iterations = np.empty((1, 4, q.size)), np.empty((1, 12)), np.zeros(1, dtype=np.int64)
    done = integrate_sequence(history, np.full(1, t_next), motion, rotations, coef, ext_Q, tol, max_iterations,
                              prescribed, base_nodes, base_local_r, base_local_rx, active, scale, tables, residual,
                              band, pivots, factorization, kl, control, False, last_motion, states, wrenches,
                              iterations)
    return (states[0] if done else None), wrenches[0], iterations[0]


class StepResult(NamedTuple):
    """The new state, total Newton corrections, number of sub-steps used (1 = none), convergence flag and, from
    the compiled run, the wrench on the holder under the step's forces (None: not computed)."""

    state: State
    newton_iterations: int
    substeps: int
    converged: bool
    wrench: BaseWrench | None = None


def scheme_coefficients(method: str, rho_inf: float) -> tuple[float, ...]:
    """(alpha_m, alpha_f, b0, b1, g0, g1) of q = q_n + h q'_n + h^2 (b0 a_n + b1 a), q' = q'_n + h (g0 a_n + g1 a)."""
    if method == "backward_euler":
        return 0.0, 0.0, 0.0, 1.0, 0.0, 1.0
    if method == "generalized_alpha":
        if not 0.0 <= rho_inf <= 1.0:
            raise ValueError(f"rho_inf must lie in [0, 1] for generalized_alpha, got {rho_inf!r}")
        alpha_m, alpha_f = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0), rho_inf / (rho_inf + 1.0)
    elif method == "hht":
        if not 0.5 <= rho_inf <= 1.0:
            raise ValueError(f"rho_inf must lie in [0.5, 1] for hht, got {rho_inf!r}")
        alpha_m, alpha_f = 0.0, (1.0 - rho_inf) / (1.0 + rho_inf)
    else:
        raise ValueError(f"integrator method must be one of {METHODS}, got {method!r}")
    gamma = 0.5 - alpha_m + alpha_f
    beta = 0.25 * (1.0 - alpha_m + alpha_f) ** 2
    return alpha_m, alpha_f, 0.5 - beta, beta, 1.0 - gamma, gamma


def same_objects(forces, cached) -> bool:
    """Whether ``forces`` are the very objects of ``cached``, in order (the key of the integrator's caches)."""
    return len(forces) == len(cached) and all(map(operator.is_, forces, cached))


def split_forces(forces) -> tuple[list, list]:
    """(state-independent, state-dependent) contributions, checked against the force protocol."""
    constant, varying = [], []
    for force in check_forces(forces):
        if force.stateful:
            raise TypeError(f"force contribution {type(force).__name__} is stateful: integrate its contributions "
                            "at(state) of the step (model.data.acting_forces)")
        (varying if force.state_dependent else constant).append(force)
    return constant, varying


def constant_force(model: NeedleModel, forces, t: float, base: BaseMotion) -> np.ndarray:
    """Sum of the state-independent generalized forces at (t, base)."""
    total = np.zeros(model.n_dof)
    for force in forces:
        total += force.evaluate(model, None, None, t, base).Q
    return total


def assemble_python(forces, q, qd, rotation, Q, band, kl, c_q, c_qd) -> bool:
    """The assemble kernel (:mod:`needle_sim_ros.model.step`) of contributions written in Python: ``forces`` is
    (model, contributions, t, base motion, load factor); their forces times the load factor into Q and, with a band,
    the load factor times c_q dQ/dq + c_qd dQ/dq' into it (dense Jacobians copied in)."""
    model, varying, t, base, factor = forces
    for force in varying:
        if not band.shape[0]:  # a chord step: Q alone
            Q += factor * np.asarray(force.generalized_force(model, q, qd, t, base), dtype=float)
        elif force.element_local:
            Q += factor * force.assemble_banded(model, q, qd, t, base, band, kl, factor * c_q, factor * c_qd)
        else:
            generalized = force.evaluate(model, q, qd, t, base)
            Q += factor * np.asarray(generalized.Q, dtype=float)
            for matrix, weight in zip(generalized[1:], (c_q, c_qd)):
                if matrix is not None:
                    add_dense_to_band(np.asarray(matrix, dtype=float), factor * weight, band, kl)
    return True


def bandwidth(model, varying, q, qd, t: float, base) -> int:
    """The iteration matrix's bandwidth under the contributions ``varying`` at (q, q'): an element's, or wider where
    a dense Jacobian couples coordinates farther apart."""
    kl = ELEMENT_BANDWIDTH
    for force in varying:
        if not force.element_local:
            for matrix in force.evaluate(model, q, qd, t, base)[1:]:
                if matrix is not None:
                    kl = max(kl, band_structure(np.asarray(matrix, dtype=float))[0])
    return kl


class IntegratorMemory:
    """What the integrator carries from one step to the next (part of the needle's data, changed in place by the
    integrator): ``control`` [extrapolate, factored]: whether Newton starts from the extrapolating predictor and
    whether the kept factorization is valid; the kept factorization of the compiled sequence (``band``, ``pivots``,
    ``factorization``), the step length ``h`` and the packed base motion ``last_motion`` it was made for; ``clamp``:
    the pose of the fixtures of the frame "start", where the needle was (re)started (None: none yet)."""

    def __init__(self, n_dof: int) -> None:
        self.control = np.array([1, 0], dtype=np.int64)
        self.band = np.zeros((n_dof, band_width_columns(ELEMENT_BANDWIDTH)))
        self.pivots = np.zeros(n_dof, dtype=np.int64)
        self.factorization = np.zeros(1, dtype=np.int64)
        self.last_motion = np.full(19, np.nan)
        self.h = 0.0
        self.clamp = None

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


class Work:
    """The step's work arrays of one model: the model tables, active mask and scales, the residual, pivots and
    factorization kind, the band buffers of each bandwidth (``band``), and the compiled runs' start rows
    (``history``) and prescribed rows: world-fixed ones once, the base nodes' per step, the held ones per clamp
    (``hold``)."""

    def __init__(self, model) -> None:
        n = self.n_dof = model.n_dof
        self.tables = model_tables(model)
        self.active = model.partition.active
        self.scale = model.increment_scale
        self.history = np.empty((4, n))
        self.residual = np.empty(n)
        self.pivots = np.empty(n, dtype=np.int64)
        self.factorization = np.zeros(1, dtype=np.int64)
        self._bands: dict[tuple[str, int], np.ndarray] = {}
        groups = model.partition.groups
        self.supported = all(g.fixed is not None or g.frame in ("base", "start") for g in groups)
        moving = [g for g in groups if g.frame == "base"]
        self.base_nodes = np.concatenate([g.nodes for g in moving]).astype(np.int64)
        self.base_local_r = np.ascontiguousarray(np.concatenate([g.local_r for g in moving]))
        self.base_local_rx = np.ascontiguousarray(np.concatenate([g.local_rx for g in moving]))
        self.prescribed = np.zeros((3, n))
        for group in groups:
            if group.fixed is not None:
                self.prescribed[:, group.dofs] = group.fixed
        self.held, self.clamp = model.partition.held, None  # the groups held where the needle started, their pose

    def hold(self, clamp) -> None:
        """Write the rows of the groups held where the needle started at ``clamp`` (``IntegratorMemory.clamp``)."""
        if clamp is self.clamp or not self.held:
            return
        if clamp is None:
            raise ValueError("a fixture of the frame 'start' needs the pose the needle started at (memory.clamp)")
        for group in self.held:
            clamp.impose_nodes(group.local_r, group.local_rx, group.nodes, self.prescribed)
        self.clamp = clamp

    def band(self, kl: int, name: str = "matrix") -> np.ndarray:
        """The iteration matrix's band buffer (``name`` "external": the external forces' part) for bandwidth kl."""
        key = (name, kl)
        if key not in self._bands:
            self._bands[key] = np.zeros((self.n_dof, band_width_columns(kl)))
        return self._bands[key]

    def newton(self, values, history, prescribed, coef, dynamic: bool, predictor: int, axis, rotation, constant_Q,
               assembled, kl: int, tol: float, max_iterations: int, always_refactor: bool):
        """:func:`~needle_sim_ros.model.newton.newton` (its loop interpreted, its kernels compiled) with the
        contributions ``assembled`` (the ``forces`` of :func:`assemble_python`); (status, iterations, last scaled
        correction)."""
        return newton.py_func(values, history, prescribed, coef, dynamic, predictor, self.active, self.scale,
                              self.tables, axis, constant_Q, np.empty(self.n_dof), self.residual, self.band(kl),
                              self.band(kl, "external"), self.pivots, self.factorization, kl, tol, max_iterations,
                              always_refactor, True, assemble_python, assembled, rotation)


_python_step = interpreted(solve_step, newton=newton.py_func)  # the one step, interpreted for laws in Python


class Integrator:
    """Fixed-step implicit integrator (module docstring). newton_tol: bound on the scaled Newton correction.
    Keeps work buffers: use one integrator per thread. What carries from one step to the next is an
    :class:`IntegratorMemory` (the needle's data holds it); without one the steps use the integrator's own
    ``memory``."""

    def __init__(self, model: NeedleModel, method: str = "generalized_alpha", rho_inf: float = 0.8,
                 newton_tol: float = 1e-6, max_newton_iterations: int = 10, max_substep_halvings: int = 4) -> None:
        self.model = model
        self.method = method
        self.rho_inf = float(rho_inf)
        self.coefficients = np.array(scheme_coefficients(method, self.rho_inf))
        if not (np.isfinite(newton_tol) and newton_tol > 0):
            raise ValueError(f"newton_tol must be > 0, got {newton_tol!r}")
        for name, value, low in (("max_newton_iterations", max_newton_iterations, 1),
                                 ("max_substep_halvings", max_substep_halvings, 0)):
            if not (isinstance(value, (int, np.integer)) and value >= low):
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        self.newton_tol = float(newton_tol)
        self.max_newton_iterations = int(max_newton_iterations)
        self.max_substep_halvings = int(max_substep_halvings)
        self.work = Work(model)
        self._constant_cache: tuple[tuple, np.ndarray] = ((), np.zeros(model.n_dof))
        self._split_cache: tuple[tuple, tuple[list, list, bool]] = ((), ([], [], True))
        self._coef_cache: tuple[float, np.ndarray] = (0.0, np.zeros(7))
        self._run_cache: tuple[tuple, tuple] = ((), ())
        self._sequence_cache: tuple = (None, 0.0, None, ())  # see sequence_arguments
        self.memory = IntegratorMemory(model.n_dof)
        self._held = bool(model.partition.held)  # fixtures held where the needle started: their rows per clamp

    def initial_accelerations(self, state: State, forces=(), base: BaseMotion | None = None) -> np.ndarray:
        """q'' consistent with the equations of motion at the state (eq. 19), prescribed q''_c kept."""
        model = self.model
        base = base or state.base
        qdd = np.array(state.qdd, dtype=float)
        constant, varying, _ = self._split(forces)
        ext_Q = constant_force(model, constant, state.t, base)
        for force in varying:
            ext_Q += force.evaluate(model, state.q, state.qd, state.t, base).Q
        work = self.work
        band = work.band(ELEMENT_BANDWIDTH)
        assemble_system(state.q, state.qd, qdd, work.tables, np.ascontiguousarray(base.axis), ext_Q,
                        np.zeros((0, 0)), 0.0, 1.0, 0.0, work.active, work.residual, band, ELEMENT_BANDWIDTH, True)
        if not band_cholesky(band, ELEMENT_BANDWIDTH):
            raise StepFailed("initial accelerations: mass matrix not positive definite")
        cholesky_solve(band, ELEMENT_BANDWIDTH, work.residual)
        qdd -= work.residual
        if not np.all(np.isfinite(qdd)):
            raise StepFailed(f"initial accelerations are not finite at t = {state.t}")
        return qdd

    def step(self, state: State, dt: float, base_next: BaseMotion, forces=(),
             memory: IntegratorMemory | None = None) -> StepResult:
        """Advance from state.t to state.t + dt with the base at base_next (pose, twist, acceleration at t + dt),
        updating ``memory``. Stateful contributions are the caller's job (``model.data.step``)."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be finite and > 0, got {dt!r}")
        memory = memory or self.memory
        constant, varying, time_invariant = self._split(forces)
        t_next = state.t + dt
        if memory.clamp is None and self._held:
            raise ValueError("a fixture of the frame 'start' needs the pose the needle started at (memory.clamp)")
        first, failure = 0, ""  # sub-step halvings: from 1 where the compiled run's step did not converge
        if state.aux is not None and time_invariant and self.work.supported:  # the compiled run's step
            rows, wrench, iterations = step_to(state.q, state.qd, state.qdd, state.aux, t_next, base_next.packed,
                                               base_next.rotation, *self.sequence_arguments(dt, forces, t_next, memory),
                                               memory.last_motion)
            if rows is not None:
                return StepResult(State(rows[0], rows[1], rows[2], t_next, rows[3], base_next), iterations, 1, True,
                                  BaseWrench(wrench))
            first, failure = 1, f"Newton did not converge at t = {t_next:.6g} s"
        memory.invalidate()  # the sequence's kept factorization is of another motion now
        model, n = self.model, self.work.n_dof
        end = np.zeros((3, n))
        model.partition.impose(base_next, t_next, end, memory.clamp)
        history = np.empty((4, n))
        history[0], history[1] = state.q, state.qd
        if state.aux is None:
            history[2] = history[3] = self.initial_accelerations(state, forces, state.base or base_next)
        else:
            history[2], history[3] = state.qdd, state.aux
        rotation = np.ascontiguousarray(base_next.rotation)
        axis = rotation[:, 0].copy()
        kl = bandwidth(model, varying, state.q, state.qd, t_next, base_next)
        for halvings in range(first, self.max_substep_halvings + 1):
            n_sub = 2**halvings
            outcome = self._attempt(history, end, dt, n_sub, state.t, base_next, axis, rotation, constant, varying,
                                    kl, memory.control)
            if isinstance(outcome, str):
                failure = outcome
                continue
            values, iterations = outcome
            return StepResult(State(values[0], values[1], values[2], t_next, values[3], base_next), iterations, n_sub,
                              True)
        raise StepFailed(f"step {state.t:.6g} -> {t_next:.6g} s failed with up to {2**self.max_substep_halvings} "
                         f"sub-steps ({self.method}, dt = {dt:g} s): {failure}")

    def supports_sequence(self, forces) -> bool:
        """Whether :meth:`step_sequence` applies: the constrained coordinates follow the base or are fixed in the
        world, and every force is time-invariant (gravity, world-frame point loads)."""
        return self.work.supported and self._split(forces)[2]

    def step_sequence(self, state: State, dt: float, motions: np.ndarray, rotations: np.ndarray,
                      forces=(), memory: IntegratorMemory | None = None, keep_matrix: bool = True) -> SequenceResult:
        """Up to k steps of dt from ``state`` (which must carry ``aux``), the base at each step's end given packed
        (k, 19) with rotations (k, 3, 3) (:meth:`BaseMotion.from_packed`); compiled
        (:func:`~needle_sim_ros.model.step.integrate_sequence`; ``keep_matrix``: the memory's factorization kept
        across steps where it may be). Only where :meth:`supports_sequence`. The run ends early at a step that does
        not converge: integrate that one with :meth:`step`."""
        k = motions.shape[0]
        before, after = self.sequence_arguments(dt, forces, state.t + dt, memory), run_outputs(k, self.work.n_dof)
        history = before[0]
        history[0], history[1], history[2], history[3] = state.q, state.qd, state.qdd, state.aux
        times = state.t + dt * np.arange(1, k + 1)
        memory = memory or self.memory
        done = integrate_sequence(history, times, motions, rotations, *before[1:], keep_matrix, memory.last_motion,
                                  *after)
        return SequenceResult.of_run(done, after)

    def sequence_arguments(self, dt: float, forces, t_next: float, memory: IntegratorMemory | None = None) -> tuple:
        """The arguments of :func:`integrate_sequence` for steps of ``dt`` under ``forces`` (see
        :meth:`step_sequence`; ``t_next``: the first step's end time) around the packed base motions and rotations:
        the history buffer for the start state's rows first, then the scheme, model and memory arrays up to the
        control flags (made once per step length and memory)."""
        memory = memory or self.memory
        if memory.h != dt:
            memory.h = dt
            memory.invalidate()
        constant, _, time_invariant = self._split(forces)
        cached = self._sequence_cache  # (memory, dt, constant forces of _split, arguments): time-invariant forces
        if not (cached[0] is memory and cached[1] == dt and cached[2] is constant):
            ext_Q = self._constant_force(constant, t_next, None)
            buffers = self.work
            cached = (memory, dt, constant if time_invariant else None, (
                buffers.history, self._coefficients(dt), ext_Q, self.newton_tol, self.max_newton_iterations,
                buffers.prescribed, buffers.base_nodes, buffers.base_local_r, buffers.base_local_rx, buffers.active,
                buffers.scale, buffers.tables, buffers.residual, memory.band, memory.pivots,
                memory.factorization, ELEMENT_BANDWIDTH, memory.control))
            self._sequence_cache = cached
        if self._held:
            self.work.hold(memory.clamp)
        return cached[3]

    def run_arguments(self, forces, dt: float, t_next: float,
                      memory: IntegratorMemory | None = None) -> tuple[tuple, np.ndarray]:
        """The needle's part of a compiled run with state-dependent contributions besides ``forces`` (which must be
        time-invariant, :meth:`supports_sequence`), e.g. the tissue: (coefficients, tolerance, iteration
        limit, base node buffers, active mask, scales, model tables, work arrays, bandwidth) and the constant
        external force. A fresh matrix every step, as :meth:`step`: the memory's kept
        factorization is invalidated."""
        memory = memory or self.memory
        memory.invalidate()
        if self._held:
            self.work.hold(memory.clamp)
        key = (dt, self.newton_tol, self.max_newton_iterations)
        if self._run_cache[0] != key:  # the same work arrays every call: the tuple is made once per key
            buffers = work = self.work
            self._run_cache = (key, (
                self._coefficients(dt), self.newton_tol, self.max_newton_iterations, buffers.prescribed,
                buffers.base_nodes, buffers.base_local_r, buffers.base_local_rx, buffers.active, buffers.scale,
                buffers.tables, buffers.residual, work.band(ELEMENT_BANDWIDTH),
                work.band(ELEMENT_BANDWIDTH, "external"), work.pivots, work.factorization, ELEMENT_BANDWIDTH))
        return self._run_cache[1], self._constant_force(self._split(forces)[0], t_next, None)

    def _split(self, forces) -> tuple[list, list, bool]:
        """(state-independent, state-dependent, all time-invariant) contributions: checked and split once while
        the same force objects are passed."""
        forces = tuple(forces)
        cached = self._split_cache
        if same_objects(forces, cached[0]):
            return cached[1]
        self._split_cache = (forces, (*split_forces(forces), all(force.time_invariant for force in forces)))
        return self._split_cache[1]

    def _coefficients(self, h: float) -> np.ndarray:
        if self._coef_cache[0] != h:
            self._coef_cache = (h, np.concatenate([[h], self.coefficients]))
        return self._coef_cache[1]

    def _constant_force(self, forces: list, t: float, base: BaseMotion) -> np.ndarray:
        """Sum of the state-independent forces; cached while the same time-invariant load objects are passed."""
        cached_forces, cached = self._constant_cache
        if same_objects(forces, cached_forces):
            return cached
        total = constant_force(self.model, forces, t, base)
        if all(force.time_invariant for force in forces):
            self._constant_cache = (tuple(forces), total)
        return total

    def _attempt(self, history, end, dt, n_sub, t0, base, axis, rotation, constant, varying, kl, control):
        """Integrate n_sub equal sub-steps, each by the one compiled step (:func:`~needle_sim_ros.model.step.
        solve_step`; interpreted where contributions are written in Python); (values (4, n), iterations) or a failure
        message. ``control``: the memory's flags (the predictor choice is updated in place)."""
        h = dt / n_sub
        coef = self._coefficients(h)
        constrained = self.model.partition.constrained_dofs
        work = self.work
        current, total = history, 0
        for k in range(1, n_sub + 1):
            t = t0 + k * h
            prescribed = end
            if k < n_sub:
                prescribed = np.zeros_like(end)
                prescribed[:, constrained] = hermite_quintic(history[:3, constrained], end[:, constrained], dt,
                                                             k / n_sub)
            ext_Q = self._constant_force(constant, t, base)
            values = np.empty_like(history)
            if varying:
                status, iterations, norm = _python_step(
                    values, current, prescribed, axis, rotation, ext_Q, np.empty(ext_Q.size),
                    (coef, self.newton_tol, self.max_newton_iterations, work.active, work.scale, work.tables, kl),
                    (work.residual, work.band(kl), work.band(kl, "external"), work.pivots, work.factorization),
                    control, False, False, (self.model, varying, t, base, 1.0), assemble_python)
            else:
                status, iterations, norm = general_step(
                    values, current, prescribed, ext_Q, axis, rotation, coef, self.newton_tol,
                    self.max_newton_iterations, work.active, work.scale, work.tables, kl, work.residual,
                    work.band(kl), work.pivots, work.factorization, control)
            total += iterations
            if status != CONVERGED:
                reason = "singular or non-finite" if status < 0 else "no convergence"
                return f"Newton {reason} at t = {t:.6g} s (last scaled correction {norm:.3g})"
            current = values
        return current, total
