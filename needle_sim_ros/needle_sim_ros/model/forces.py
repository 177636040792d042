"""External generalized forces (seed 000 eqs. 14-16): one interface for gravity, loads and tissue models.

A point force F at the material point x of element j does the virtual work F^T S(x) delta e_j (eq. 14), hence
Q_f = sum_i S^T(x_i) F_i (eq. 15); nodal loads add Q_P directly (eq. 16); a line load f per length adds
int S^T f ds.  Every contribution implements

    evaluate(model, q, qd, t, base) -> GeneralizedForce(Q, dQ_dq, dQ_dqd)       (Jacobians dense or None = zero)
    advance(model, state, base) -> None        (optional; the caller runs it once per accepted step)

and may set ``state_independent = True`` when Q depends on (t, base) only and both Jacobians are zero: the
integrator then evaluates it once per step and runs its compiled fast path; ``time_invariant = True`` in addition
(Q constant, the object never mutated) lets it reuse the value across steps.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple, Protocol, runtime_checkable

import numpy as np
from numba import njit

from .mesh import Interpolation


class GeneralizedForce(NamedTuple):
    """Q (n_dof,) and its Jacobians with respect to q and q' ((n_dof, n_dof) or None for zero)."""

    Q: np.ndarray
    dQ_dq: np.ndarray | None = None
    dQ_dqd: np.ndarray | None = None


@runtime_checkable
class ForceContribution(Protocol):
    def evaluate(self, model, q: np.ndarray, qd: np.ndarray, t: float, base) -> GeneralizedForce: ...


class PointForces(NamedTuple):
    """Forces at k material points (world frame) and their derivatives with respect to the point's position r,
    gradient r_x and velocity v: F (k, 3); dF_dr, dF_drx, dF_dv (k, 3, 3) (None = zero)."""

    F: np.ndarray
    dF_dr: np.ndarray | None = None
    dF_drx: np.ndarray | None = None
    dF_dv: np.ndarray | None = None


def _frame_vector(value, frame: str, name: str) -> np.ndarray:
    if frame not in ("world", "base"):
        raise ValueError(f"{name}: frame must be 'world' or 'base', got {frame!r}")
    vector = np.asarray(value, dtype=float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"{name}: force must be 3 finite numbers, got {value!r}")
    return vector


def _per_model(owner, model, build: Callable):
    """Cache of model-dependent tables on a load object (rebuilt when used with another model)."""
    cached = owner.__dict__.get("_tables")
    if cached is None or cached[0] is not model:
        cached = (model, build(model))
        owner.__dict__["_tables"] = cached
    return cached[1]


def _read_only(array: np.ndarray) -> np.ndarray:
    """Cached generalized forces are shared: protect them against in-place changes by callers."""
    array.flags.writeable = False
    return array


def distribution_matrix(interpolation: Interpolation, weights: np.ndarray, n_dof: int) -> np.ndarray:
    """G (n_dof, 3) with Q = G f for the same world-frame vector f at all points: G = sum_k w_k S^T(x_k)."""
    G = np.zeros((n_dof // 3, 3, 3))
    np.add.at(G, interpolation.slots, (weights[:, None] * interpolation.S)[:, :, None, None] * np.eye(3))
    return G.reshape(n_dof, 3)


class _ConstantVectorLoad:
    """A load Q = G f with a constant vector f given in the world or the base frame (state independent)."""

    state_independent = True

    def __init__(self, vector, frame: str, name: str) -> None:
        self.frame = frame
        self.vector = _frame_vector(vector, frame, name)
        self.time_invariant = frame == "world"

    def distribution(self, model) -> np.ndarray:
        raise NotImplementedError

    def _tables(self, model) -> tuple[np.ndarray, GeneralizedForce]:
        G = self.distribution(model)
        return G, GeneralizedForce(_read_only(G @ self.vector))

    def evaluate(self, model, q, qd, t, base) -> GeneralizedForce:
        G, world = _per_model(self, model, self._tables)
        return world if self.frame == "world" else GeneralizedForce(G @ (base.rotation @ self.vector))


class PointLoad(_ConstantVectorLoad):
    """Force [N] at the material point with reference arc length s (eqs. 14-15); direction fixed in the world or
    the base frame (it does not follow the needle's deformation)."""

    def __init__(self, arc_length: float, force, frame: str = "world") -> None:
        super().__init__(force, frame, "PointLoad")
        self.arc_length = float(arc_length)

    def distribution(self, model) -> np.ndarray:
        return distribution_matrix(model.interpolation([self.arc_length]), np.ones(1), model.n_dof)


class LineLoad(_ConstantVectorLoad):
    """Uniform force per length [N/m] on the reference arc-length interval [s_start, s_end]: Q = int S^T f ds,
    integrated exactly (3 Gauss points per covered element piece; S is cubic)."""

    def __init__(self, s_start: float, s_end: float, force_per_length, frame: str = "world") -> None:
        super().__init__(force_per_length, frame, "LineLoad")
        self.s_start, self.s_end = float(s_start), float(s_end)
        if not self.s_start <= self.s_end:
            raise ValueError(f"LineLoad: s_start {s_start!r} must not exceed s_end {s_end!r}")

    def distribution(self, model) -> np.ndarray:
        nodes = model.node_arc_length
        if self.s_start < -1e-9 * nodes[-1] or self.s_end > nodes[-1] * (1 + 1e-9):
            raise ValueError(f"LineLoad interval [{self.s_start}, {self.s_end}] m outside the needle "
                             f"[0, {nodes[-1]}] m")
        cuts = np.unique(np.clip(np.concatenate([[self.s_start, self.s_end], nodes]), self.s_start, self.s_end))
        lower, upper = cuts[:-1], cuts[1:]
        xi, w = np.polynomial.legendre.leggauss(3)
        points = (0.5 * (lower + upper))[:, None] + 0.5 * (upper - lower)[:, None] * xi[None, :]
        weights = 0.5 * (upper - lower)[:, None] * w[None, :]
        return distribution_matrix(model.interpolation(points.ravel()), weights.ravel(), model.n_dof)


class Gravity:
    """Weight of the needle: the line load rho A g over [0, L] (g = NeedleProperties.gravity, world frame)."""

    state_independent = True
    time_invariant = True

    @staticmethod
    def distribution(model) -> np.ndarray:
        whole = LineLoad(0.0, model.props.length, np.zeros(3))
        return whole.distribution(model) * model.props.mass_per_length

    def evaluate(self, model, q, qd, t, base) -> GeneralizedForce:
        return _per_model(self, model, lambda m: GeneralizedForce(
            _read_only(self.distribution(m) @ np.asarray(m.props.gravity))))


class NodalLoad:
    """Generalized load Q_P on the coordinates of one node (eq. 16): ``force`` [N] on r, ``gradient_force`` [N m]
    on r_x (a moment M at the node corresponds to gradient_force = M x r_x / |r_x|^2, state dependent). Node
    indices may be negative (-1 = tip). World or base frame."""

    state_independent = True

    def __init__(self, node: int, force, gradient_force=(0.0, 0.0, 0.0), frame: str = "world") -> None:
        self.node = int(node)
        self.frame = frame
        self.time_invariant = frame == "world"
        self.generalized = np.concatenate([_frame_vector(force, frame, "NodalLoad"),
                                           _frame_vector(gradient_force, frame, "NodalLoad gradient_force")])

    def evaluate(self, model, q, qd, t, base) -> GeneralizedForce:
        if not -model.n_nodes <= self.node < model.n_nodes:
            raise ValueError(f"NodalLoad node {self.node} outside the {model.n_nodes}-node mesh")
        values = self.generalized.reshape(2, 3)
        if self.frame == "base":
            values = values @ base.rotation.T
        Q = np.zeros(model.n_dof)
        first = 6 * (self.node % model.n_nodes)
        Q[first:first + 6] = values.ravel()
        return GeneralizedForce(Q)


PointForceLaw = Callable[[np.ndarray, np.ndarray, np.ndarray, float, object], PointForces]


@dataclass(eq=False)
class MaterialPointForce:
    """Forces from a per-point law at material points s_k with weights w_k (e.g. length shares for a force per
    length): Q = sum_k w_k S^T(s_k) F_k (eq. 15) with the chain-rule Jacobians
        dQ/dq  = sum_k w_k S_k^T (dF/dr S_k + dF/dr_x S_x,k),   dQ/dq' = sum_k w_k S_k^T dF/dv S_k.
    law(r, r_x, v, t, base) -> PointForces, all world frame, arrays (k, 3) in and out."""

    arc_lengths: np.ndarray
    weights: np.ndarray
    law: PointForceLaw

    def __post_init__(self) -> None:
        self.arc_lengths = np.atleast_1d(np.asarray(self.arc_lengths, dtype=float))
        self.weights = np.broadcast_to(np.asarray(self.weights, dtype=float), self.arc_lengths.shape).copy()
        if not np.all(np.isfinite(self.weights)):
            raise ValueError("MaterialPointForce: weights must be finite")

    def evaluate(self, model, q, qd, t, base) -> GeneralizedForce:
        table = _per_model(self, model, lambda m: m.interpolation(self.arc_lengths))
        r, r_x, v = table.positions(q), table.gradients(q), table.positions(qd)
        forces = self.law(r, r_x, v, t, base)
        k = self.arc_lengths.size
        zero = np.zeros((k, 3, 3))
        derivatives = [zero if d is None else np.ascontiguousarray(d, dtype=float)
                       for d in (forces.dF_dr, forces.dF_drx, forces.dF_dv)]
        F = np.ascontiguousarray(forces.F, dtype=float)
        if F.shape != (k, 3) or any(d.shape != (k, 3, 3) for d in derivatives):
            raise ValueError(f"MaterialPointForce law must return F (k, 3) and derivatives (k, 3, 3), k = {k}")
        n = model.n_dof
        Q, dQ_dq = np.zeros(n), np.zeros((n, n))
        dQ_dqd = np.zeros((n, n)) if forces.dF_dv is not None else None
        assemble_point_forces(table.slots, table.S, table.S_x, self.weights, F, *derivatives, Q, dQ_dq,
                              dQ_dqd if dQ_dqd is not None else np.zeros((0, 0)))
        no_stiffness = forces.dF_dr is None and forces.dF_drx is None
        return GeneralizedForce(Q, None if no_stiffness else dQ_dq, dQ_dqd)


@njit(cache=True)
def assemble_point_forces(slots, S, S_x, weights, F, dF_dr, dF_drx, dF_dv, Q, dQ_dq, dQ_dqd):
    """Scatter sum_k w_k S_k^T F_k and its Jacobians (MaterialPointForce) into Q and dense matrices."""
    with_velocity = dQ_dqd.shape[0] > 0
    for k in range(slots.shape[0]):
        for a in range(4):
            ia = 3 * slots[k, a]
            wa = weights[k] * S[k, a]
            for c in range(3):
                Q[ia + c] += wa * F[k, c]
            for b in range(4):
                ib = 3 * slots[k, b]
                cr = wa * S[k, b]
                cx = wa * S_x[k, b]
                for c in range(3):
                    for c2 in range(3):
                        dQ_dq[ia + c, ib + c2] += cr * dF_dr[k, c, c2] + cx * dF_drx[k, c, c2]
                        if with_velocity:
                            dQ_dqd[ia + c, ib + c2] += cr * dF_dv[k, c, c2]
