"""Implicit fixed-step time integration of the active coordinates (seed 000 eq. 19) with Newton on the analytic
Jacobian, and automatic sub-stepping.

Schemes (all in the Arnold-Bruels form of generalized-alpha: the equations of motion hold exactly at t_{n+1}, so
the returned q'' is the true acceleration of the step and eq. 20 gives a consistent base wrench):
* ``generalized_alpha`` (Chung-Hulbert parameters): alpha_m = (2 rho - 1)/(rho + 1), alpha_f = rho/(rho + 1),
  gamma = 1/2 - alpha_m + alpha_f, beta = (1 - alpha_m + alpha_f)^2 / 4; second order, rho_inf in [0, 1] is the
  spectral radius at infinite frequency (1: no numerical damping -- the trapezoidal rule; 0: asymptotic
  annihilation).  rho_inf = 1 conserves energy only for linear(ized) motion: when large deformations meet unresolved
  high-frequency content (e.g. a tip load released at once, 10 elements, dt = 1 ms) it is unstable -- the energy
  grew 40-fold within 0.5 s (0.98: +39 % in 1 s).  rho_inf <= 0.95 is stable there (-0.14 % energy in 1 s).
* ``hht``: the HHT-alpha parameter set alpha_m = 0, alpha_f = (1 - rho)/(1 + rho), rho_inf in [0.5, 1] (for linear
  systems identical to Hilber-Hughes-Taylor).
* ``backward_euler``: q' = q'_n + h q'', q = q_n + h q' -- first order, strongly dissipative, the robust fallback.
Newton starts from the constant-acceleration predictor and, if that has not converged after
``newton.EXTRAPOLATION_ITERATIONS``, once more from q_{n+1} = q_n (robust when unresolved high-frequency content makes
extrapolation useless); after such a fallback the following steps start from q_n until it converges within two
iterations again.  A step that still fails (Newton not converged within ``max_newton_iterations``, singular
matrix, non-finite values) is retried as 2, 4, ... sub-steps (prescribed coordinates interpolated by quintic Hermite
polynomials from their values, velocities and accelerations at both ends) up to ``max_substep_halvings`` times,
then ``StepFailed`` is raised.  The input state is never modified.
"""
from __future__ import annotations

import math
import operator
from typing import NamedTuple

import numpy as np

from .kinematics import BaseMotion
from .model import NeedleModel, State
from .newton import (CONVERGED, NewtonSolver, assemble_system, keeps_extrapolating, predictor_budget,
                     predictor_for_attempt)
from .banded import ELEMENT_BANDWIDTH, band_cholesky, cholesky_solve
from .forces import check_forces
from .partition import hermite_quintic
from .sequence import IntegratorMemory, SequenceBuffers, integrate_sequence
from .step import EXTRAPOLATE

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


class StepResult(NamedTuple):
    """The new state, total Newton corrections, number of sub-steps used (1 = none), convergence flag and the
    last scaled Newton correction (max |dq| / L for positions, |dr_x| for gradients)."""

    state: State
    newton_iterations: int
    substeps: int
    converged: bool
    residual_norm: float


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
        self.solver = NewtonSolver(model)
        self._constant_cache: tuple[tuple, np.ndarray] = ((), np.zeros(model.n_dof))
        self._split_cache: tuple[tuple, list, list, bool] = ((), [], [], True)
        self._coef_cache: tuple[float, np.ndarray] = (0.0, np.zeros(7))
        self._run_cache: tuple[tuple, tuple] = ((), ())
        self._sequence_cache: tuple = (None, 0.0, None, ())  # see sequence_arguments
        self.memory = IntegratorMemory(model.n_dof)
        self._sequence: SequenceBuffers | None = None
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
        solver = self.solver
        band = solver.band(ELEMENT_BANDWIDTH)
        assemble_system(state.q, state.qd, qdd, solver.tables, np.ascontiguousarray(base.axis), ext_Q,
                        np.zeros((0, 0)), 0.0, 1.0, 0.0, solver.active, solver.residual, band, ELEMENT_BANDWIDTH, True)
        if not band_cholesky(band, ELEMENT_BANDWIDTH):
            raise StepFailed("initial accelerations: mass matrix not positive definite")
        cholesky_solve(band, ELEMENT_BANDWIDTH, solver.residual)
        qdd -= solver.residual
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
        memory.invalidate()  # the sequence's kept factorization is of another motion now
        model = self.model
        n = model.n_dof
        constant, varying, _ = self._split(forces)
        t_next = state.t + dt
        end = np.zeros((3, n))
        if memory.clamp is None and model.partition.held:
            raise ValueError("a fixture of the frame 'start' needs the pose the needle started at (memory.clamp)")
        model.partition.impose(base_next, t_next, end, memory.clamp)
        history = np.empty((4, n))
        history[0], history[1] = state.q, state.qd
        if state.aux is None:
            history[2] = history[3] = self.initial_accelerations(state, forces, state.base or base_next)
        else:
            history[2], history[3] = state.qdd, state.aux
        axis = np.ascontiguousarray(base_next.axis)
        failure = ""
        for halvings in range(self.max_substep_halvings + 1):
            n_sub = 2**halvings
            outcome = self._attempt(history, end, dt, n_sub, state.t, base_next, axis, constant, varying,
                                    memory.control)
            if isinstance(outcome, str):
                failure = outcome
                continue
            values, iterations, norm = outcome
            new_state = State(values[0], values[1], values[2], t_next, values[3], base_next)
            return StepResult(new_state, iterations, n_sub, True, norm)
        raise StepFailed(f"step {state.t:.6g} -> {t_next:.6g} s failed with up to {2**self.max_substep_halvings} "
                         f"sub-steps ({self.method}, dt = {dt:g} s): {failure}")

    def supports_sequence(self, forces) -> bool:
        """Whether :meth:`step_sequence` applies: the constrained coordinates follow the base or are fixed in the
        world, and every force is time-invariant (gravity, world-frame point loads)."""
        return self._sequence_buffers().supported and self._split(forces)[2]

    def step_sequence(self, state: State, dt: float, motions: np.ndarray, rotations: np.ndarray,
                      forces=(), memory: IntegratorMemory | None = None) -> SequenceResult:
        """Up to k steps of dt from ``state`` (which must carry ``aux``), the base at each step's end given packed
        (k, 19) with rotations (k, 3, 3) (:meth:`BaseMotion.from_packed`); compiled, see
        :mod:`needle_sim_ros.model.sequence`. Only where :meth:`supports_sequence`. The run ends early at a step
        that does not converge: integrate that one with :meth:`step`."""
        k = motions.shape[0]
        before, after = self.sequence_arguments(dt, forces, state.t + dt, k, memory)
        history = before[0]
        history[0], history[1], history[2], history[3] = state.q, state.qd, state.qdd, state.aux
        times = state.t + dt * np.arange(1, k + 1)
        done = integrate_sequence(history, times, motions, rotations, *before[1:], *after)
        return SequenceResult.of_run(done, after)

    def sequence_arguments(self, dt: float, forces, t_next: float, steps: int,
                           memory: IntegratorMemory | None = None) -> tuple[tuple, tuple]:
        """The arguments of :func:`integrate_sequence` for ``steps`` steps of ``dt`` under ``forces`` (see
        :meth:`step_sequence`; ``t_next``: the first step's end time): those around the packed base motions and
        rotations (the history buffer for the start state's rows first, then the scheme, model and memory
        arrays; made once per step length and memory), and the outputs (states, wrenches, iterations), new."""
        memory = memory or self.memory
        if memory.h != dt:
            memory.h = dt
            memory.invalidate()
        cached = self._sequence_cache  # (memory, dt, forces, arguments): the same time-invariant forces
        if not (cached[0] is memory and cached[1] == dt and cached[2] is not None
                and same_objects(forces, cached[2])):
            constant, _, time_invariant = self._split(forces)
            ext_Q = self._constant_force(constant, t_next, None)
            buffers = self._sequence_buffers()
            cached = (memory, dt, tuple(forces) if time_invariant else None, (
                buffers.history, self._coefficients(dt), ext_Q, self.newton_tol, self.max_newton_iterations,
                buffers.prescribed, buffers.base_nodes, buffers.base_local_r, buffers.base_local_rx, buffers.active,
                buffers.scale, buffers.tables, buffers.residual, memory.band, memory.pivots,
                memory.factorization, ELEMENT_BANDWIDTH, memory.control, memory.last_motion))
            self._sequence_cache = cached
        if self._held:
            self._sequence_buffers().hold(memory.clamp)
        return cached[3], run_outputs(steps, self.model.n_dof)

    def run_arguments(self, forces, dt: float, t_next: float,
                      memory: IntegratorMemory | None = None) -> tuple[tuple, np.ndarray]:
        """The needle's part of a compiled run with state-dependent contributions besides ``forces`` (which must be
        time-invariant, :meth:`supports_sequence`), e.g. ``tissue.sequence``: (coefficients, tolerance, iteration
        limit, base node buffers, active mask, scales, model tables, work arrays, bandwidth) and the constant
        external force. A fresh matrix every step, as :meth:`step`: the memory's kept
        factorization is invalidated."""
        memory = memory or self.memory
        memory.invalidate()
        if self._held:
            self._sequence_buffers().hold(memory.clamp)
        key = (dt, self.newton_tol, self.max_newton_iterations)
        if self._run_cache[0] != key:  # the same work arrays every call: the tuple is made once per key
            buffers, solver = self._sequence_buffers(), self.solver
            self._run_cache = (key, (
                self._coefficients(dt), self.newton_tol, self.max_newton_iterations, buffers.prescribed,
                buffers.base_nodes, buffers.base_local_r, buffers.base_local_rx, buffers.active, buffers.scale,
                buffers.tables, buffers.residual, solver.band(ELEMENT_BANDWIDTH),
                solver.band(ELEMENT_BANDWIDTH, "external"), solver.pivots, solver.factorization, ELEMENT_BANDWIDTH))
        return self._run_cache[1], self._constant_force(self._split(forces)[0], t_next, None)

    def _sequence_buffers(self) -> SequenceBuffers:
        if self._sequence is None:
            self._sequence = SequenceBuffers(self.model)
        return self._sequence

    def _split(self, forces) -> tuple[list, list, bool]:
        """(state-independent, state-dependent, all time-invariant) contributions: checked and split once while
        the same force objects are passed."""
        forces = tuple(forces)
        cached = self._split_cache
        if same_objects(forces, cached[0]):
            return cached[1:]
        constant, varying = split_forces(forces)
        self._split_cache = (forces, constant, varying, all(force.time_invariant for force in forces))
        return self._split_cache[1:]

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

    def _attempt(self, history, end, dt, n_sub, t0, base, axis, constant, varying, control):
        """Integrate n_sub equal sub-steps; (values (4, n), iterations, norm) or a failure message. ``control``:
        the memory's flags (the predictor choice is updated in place)."""
        h = dt / n_sub
        coef = self._coefficients(h)
        constrained = self.model.partition.constrained_dofs
        current, total, norm = history, 0, 0.0
        for k in range(1, n_sub + 1):
            t = t0 + k * h
            prescribed = end
            if k < n_sub:
                prescribed = np.zeros_like(end)
                prescribed[:, constrained] = hermite_quintic(history[:3, constrained], end[:, constrained], dt,
                                                             k / n_sub)
            ext_Q = self._constant_force(constant, t, base)
            for attempt in range(2):
                predictor = predictor_for_attempt(attempt, control[EXTRAPOLATE] == 1)
                budget = predictor_budget(predictor, self.max_newton_iterations)
                values = np.empty_like(history)
                status, iterations, norm = self.solver.solve(values, current, prescribed, coef, True, axis, ext_Q,
                                                             varying, t, base, self.newton_tol, budget, False,
                                                             predictor=predictor)
                total += iterations
                if status == CONVERGED:
                    # extrapolate again once q_n converges quickly (smooth motion); keep q_n after a failure
                    control[EXTRAPOLATE] = int(keeps_extrapolating(predictor, iterations))
                    break
            if status != CONVERGED:
                reason = "singular or non-finite" if status < 0 else f"no convergence in {iterations} iterations"
                return f"Newton {reason} at t = {t:.6g} s (last scaled correction {norm:.3g})"
            current = values
        return current, total, norm
