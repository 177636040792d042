"""Static equilibrium Q_el(q) + Q_f(q) = 0 on the active coordinates (eq. 17 without inertia and damping), solved
by full Newton with the analytic Jacobian and adaptive load stepping (the external forces are scaled by
lambda = 1/load_steps, 2/load_steps, ...; a failed increment is halved, a quick one lets the next grow)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .integrators import Work, bandwidth, constant_force, split_forces
from .kinematics import BaseMotion
from .mesh import shape_functions
from .model import NeedleModel, State
from .newton import CONVERGED, PREDICT_POSITION


class StaticSolveFailed(RuntimeError):
    """No equilibrium found (Newton failed even with the smallest load increment)."""


@dataclass(frozen=True)
class StaticResult:
    """Equilibrium state (q' = q'' = 0), total Newton iterations, accepted load increments."""

    state: State
    newton_iterations: int
    load_steps: int


def static_initial_guess(model: NeedleModel, base: BaseMotion, t: float = 0.0) -> np.ndarray:
    """Straight along the holder, except that free nodes between two clamped nodes lie on the cubic Hermite curve
    joining them (the shape of one cable element, eq. 4, across the free span)."""
    q = model.straight_state(base, t).q
    nodes = q.reshape(-1, 2, 3)
    s = model.mesh.node_arc_length
    clamped = np.flatnonzero(~model.partition.active[::6])
    for i0, i1 in zip(clamped[:-1], clamped[1:]):
        if i1 - i0 < 2:
            continue
        span = s[i1] - s[i0]
        sigma = (s[i0 + 1:i1] - s[i0]) / span
        xi = 2.0 * sigma - 1.0
        S, S_x, _ = shape_functions(xi, span)
        ends = np.stack([nodes[i0, 0], nodes[i0, 1], nodes[i1, 0], nodes[i1, 1]])
        nodes[i0 + 1:i1, 0] = S @ ends
        nodes[i0 + 1:i1, 1] = S_x @ ends
    last = clamped[-1]
    nodes[last + 1:, 0] = nodes[last, 0] + (s[last + 1:] - s[last])[:, None] * nodes[last, 1]
    nodes[last + 1:, 1] = nodes[last, 1]
    return q


def solve_static(model: NeedleModel, base: BaseMotion, forces=(), load_steps: int = 1, t: float = 0.0,
                 initial: State | None = None, newton_tol: float = 1e-10, max_newton_iterations: int = 25,
                 max_bisections: int = 12) -> StaticResult:
    """Equilibrium under ``forces`` with the base (and fixtures) at their pose at time t; ``initial``: a starting
    state (e.g. a sweep's previous equilibrium), default ``static_initial_guess``."""
    if not (isinstance(load_steps, (int, np.integer)) and load_steps >= 1):
        raise ValueError(f"load_steps must be an integer >= 1, got {load_steps!r}")
    n = model.n_dof
    values = np.zeros((4, n))
    values[0] = initial.q if initial is not None else static_initial_guess(model, base, t)
    model.partition.impose(base, t, values[:3])
    values[1:] = 0.0
    constant, varying = split_forces(forces)
    total_constant = constant_force(model, constant, t, base)
    work = Work(model)
    unused = np.zeros((4, n))
    rotation = np.ascontiguousarray(base.rotation)
    axis = rotation[:, 0].copy()
    kl = bandwidth(model, varying, values[0], values[1], t, base)
    load, increment = 0.0, 1.0 / load_steps
    iterations, accepted, bisections = 0, 0, 0
    while load < 1.0:
        target = min(1.0, load + increment)
        trial = values.copy()
        status, used, norm = work.newton(trial, unused, unused, np.ones(7), False, PREDICT_POSITION, axis, rotation,
                                         target * total_constant, (model, varying, t, base, target), kl, newton_tol,
                                         max_newton_iterations, True)
        iterations += used
        if status == CONVERGED:
            values, load, accepted = trial, target, accepted + 1
            if used <= 4:
                increment *= 2.0
            continue
        bisections += 1
        increment *= 0.5
        if bisections > max_bisections:
            raise StaticSolveFailed(f"static solve failed at load factor {target:.4g} after {bisections - 1} "
                                    f"increment halvings (last scaled Newton correction {norm:.3g})")
    q = values[0].copy()
    return StaticResult(State(q, np.zeros(n), np.zeros(n), float(t), None, base), iterations, accepted)
