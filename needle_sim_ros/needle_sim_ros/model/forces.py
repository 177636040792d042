"""External generalized forces (seed 000 eqs. 14-16): one protocol for gravity, loads and tissue models.

A point force F at the material point x of element j does the virtual work F^T S(x) delta e_j (eq. 14), hence
Q_f = sum_i S^T(x_i) F_i (eq. 15); nodal loads add Q_P directly (eq. 16); a line load f per length adds int S^T f ds.
Every contribution implements ``evaluate(model, q, qd, t, base) -> GeneralizedForce`` (``generalized_force``: Q
alone) and declares its capabilities (:class:`ForceContribution`, checked by :func:`check_forces`). Element-local
ones assemble their Jacobian blocks straight into the banded iteration matrix (``assemble_point_forces``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar, NamedTuple

import numpy as np
from numba import njit

from .banded import ELEMENT_BANDWIDTH, band_to_dense, band_width_columns
from .mesh import Interpolation


class GeneralizedForce(NamedTuple):
    """Q (n_dof,) and its Jacobians with respect to q and q' ((n_dof, n_dof) or None for zero)."""

    Q: np.ndarray
    dQ_dq: np.ndarray | None = None
    dQ_dqd: np.ndarray | None = None


class ForceContribution:
    """Base of the external force contributions; the capabilities are class attributes (a property where the answer
    depends on the instance, e.g. a load's frame):

    * ``state_dependent``: Q depends on q or q' (evaluated at every Newton iteration); False: on (t, base) only, both
      Jacobians zero (once per step).
    * ``time_invariant``: Q is one constant vector (not state dependent, not stateful, never mutated): summed once;
      when every force is so, the compiled step sequence applies.
    * ``stateful``: its state changes from step to step (kept immutable in ``NeedleData.force_states``); implements
      ``initial_state(model)``, ``advance(model, state, base, own) -> own'`` (once per accepted step, ``own``
      unchanged) and ``at(own)``: the non-stateful contributions acting over the step from ``own``. Never evaluated
      itself; a failed step keeps the old value.
    * ``element_local`` (default False): its Jacobians couple one element's coordinates (eq. 15); implements
      ``assemble_banded`` (Q and its Jacobian blocks into the band, compiled) and ``touches_element`` (the base
      wrench skips forces off the first element). False: Newton takes the dense Jacobians of ``evaluate``.
    * ``compiled_run`` (default False): state dependent, given by compiled kernels (``kernels``, ``constants``; if
      stateful ``packed_state``, ``unpacked_state``: ``contribution``) that the fast path composes into one compiled
      run: the tissue, a ``contribution.CompiledContribution``."""

    state_dependent: ClassVar[bool]
    time_invariant: ClassVar[bool]
    stateful: ClassVar[bool]
    element_local: ClassVar[bool] = False
    compiled_run: ClassVar[bool] = False

    def evaluate(self, model, q: np.ndarray, qd: np.ndarray, t: float, base) -> GeneralizedForce:
        raise NotImplementedError

    def generalized_force(self, model, q: np.ndarray, qd: np.ndarray, t: float, base) -> np.ndarray:
        """Q alone (n_dof,), the same values as ``evaluate(...).Q``: where no Jacobian is needed (Newton chord
        steps, the reaction wrench).  Contributions with costly Jacobians override it."""
        return self.evaluate(model, q, qd, t, base).Q

    def assemble_banded(self, model, q: np.ndarray, qd: np.ndarray, t: float, base, band: np.ndarray, kl: int,
                        c_q: float, c_qd: float) -> np.ndarray:
        """Q (n_dof,); adds c_q dQ/dq + c_qd dQ/dq' to ``band`` (row i, column j at band[i, j - i + kl], kl >=
        ELEMENT_BANDWIDTH). Only for ``element_local`` contributions."""
        raise NotImplementedError

    def touches_element(self, model, element: int) -> bool:
        """Whether one of its points lies in ``element`` (Q is zero on the coordinates of elements it does not
        touch). Only for ``element_local`` contributions."""
        raise NotImplementedError


class ElementLocalForce(ForceContribution):
    """Base of the element-local contributions: ``evaluate`` (dense Jacobians, for tools and tests) and
    ``generalized_force`` both come from ``assemble_banded``."""

    element_local: ClassVar[bool] = True

    def evaluate(self, model, q, qd, t, base) -> GeneralizedForce:
        kl = ELEMENT_BANDWIDTH
        stiffness, damping = (np.zeros((q.size, band_width_columns(kl))) for _ in range(2))
        Q = self.assemble_banded(model, q, qd, t, base, stiffness, kl, 1.0, 0.0)
        self.assemble_banded(model, q, qd, t, base, damping, kl, 0.0, 1.0)
        return GeneralizedForce(Q, band_to_dense(stiffness, kl), band_to_dense(damping, kl))

    def generalized_force(self, model, q, qd, t, base) -> np.ndarray:
        return self.assemble_banded(model, q, qd, t, base, _NO_BAND, 0, 0.0, 0.0)


_NO_BAND = np.zeros((0, 0))
_NO_DERIVATIVE = np.zeros((0, 3, 3))  # a derivative of the point forces that is zero (assemble_point_forces)


CAPABILITIES = ("state_dependent", "time_invariant", "stateful", "element_local", "compiled_run")
STATE_HOOKS = ("initial_state", "advance", "at")


_CHECKED_CLASSES: set[type] = set()  # classes that passed and declare every capability as a plain class attribute


def check_forces(forces) -> tuple:
    """The contributions as a tuple, each checked against the :class:`ForceContribution` protocol (TypeError naming
    the first class that breaks it); a class whose capabilities are plain class attributes is checked once."""
    forces = tuple(forces)
    for force in forces:
        if type(force) in _CHECKED_CLASSES:
            continue
        name = type(force).__name__
        if not getattr(force, "stateful", False) and not callable(getattr(force, "evaluate", None)):
            raise TypeError(f"force contribution {name} has no evaluate(model, q, qd, t, base)")
        for capability in CAPABILITIES:
            if not hasattr(type(force), capability) or not isinstance(getattr(force, capability), bool):
                raise TypeError(f"force contribution {name} must declare {capability} = True or False as a class "
                                f"attribute (ForceContribution)")
        hooks = [hook for hook in STATE_HOOKS if callable(getattr(force, hook, None))]
        if force.stateful and len(hooks) < len(STATE_HOOKS):
            missing = ", ".join(hook for hook in STATE_HOOKS if hook not in hooks)
            raise TypeError(f"force contribution {name} declares stateful = True but has no {missing}()")
        if not force.stateful and "advance" in hooks:
            raise TypeError(f"force contribution {name} has advance() but declares stateful = False: its state "
                            "would be neither advanced nor rolled back")
        if force.time_invariant and (force.state_dependent or force.stateful):
            raise TypeError(f"force contribution {name} declares time_invariant = True, which excludes "
                            "state_dependent and stateful")
        missing = [hook for hook in ("assemble_banded", "touches_element")
                   if getattr(type(force), hook) is getattr(ForceContribution, hook)]
        if force.element_local and missing:
            raise TypeError(f"force contribution {name} declares element_local = True but has no {missing[0]}()")
        if force.compiled_run and not (force.state_dependent and hasattr(force, "kernels")):
            raise TypeError(f"force contribution {name} declares compiled_run = True but is not state-dependent "
                            "with kernels")
        if all(isinstance(getattr(type(force), capability), bool) for capability in CAPABILITIES):
            _CHECKED_CLASSES.add(type(force))
    return forces


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


class _ConstantVectorLoad(ForceContribution):
    """A load of a constant vector f given in the world or the base frame (state independent): Q = G f with G of
    ``distribution``, or its own ``evaluate``."""

    state_dependent = False
    stateful = False

    def __init__(self, vector, frame: str, name: str) -> None:
        self.frame = frame
        self.vector = _frame_vector(vector, frame, name)

    @property
    def time_invariant(self) -> bool:
        """World-frame loads are constant; base-frame ones turn with the base."""
        return self.frame == "world"

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
        nodes = model.mesh.node_arc_length
        if self.s_start < -1e-9 * nodes[-1] or self.s_end > nodes[-1] * (1 + 1e-9):
            raise ValueError(f"LineLoad interval [{self.s_start}, {self.s_end}] m outside the needle "
                             f"[0, {nodes[-1]}] m")
        cuts = np.unique(np.clip(np.concatenate([[self.s_start, self.s_end], nodes]), self.s_start, self.s_end))
        lower, upper = cuts[:-1], cuts[1:]
        xi, w = np.polynomial.legendre.leggauss(3)
        points = (0.5 * (lower + upper))[:, None] + 0.5 * (upper - lower)[:, None] * xi[None, :]
        weights = 0.5 * (upper - lower)[:, None] * w[None, :]
        return distribution_matrix(model.interpolation(points.ravel()), weights.ravel(), model.n_dof)


class Gravity(ForceContribution):
    """Weight of the needle: the line load rho A g over [0, L] (g = NeedleProperties.gravity, world frame)."""

    state_dependent = False
    time_invariant = True
    stateful = False

    @staticmethod
    def distribution(model) -> np.ndarray:
        whole = LineLoad(0.0, model.props.length, np.zeros(3))
        return whole.distribution(model) * model.props.mass_per_length

    def evaluate(self, model, q, qd, t, base) -> GeneralizedForce:
        return _per_model(self, model, lambda m: GeneralizedForce(
            _read_only(self.distribution(m) @ np.asarray(m.props.gravity))))


class NodalLoad(_ConstantVectorLoad):
    """Generalized load Q_P on the coordinates of one node (eq. 16): ``force`` [N] on r, ``gradient_force`` [N m]
    on r_x (a moment M at the node corresponds to gradient_force = M x r_x / |r_x|^2, state dependent). Node
    indices may be negative (-1 = tip). World or base frame."""

    def __init__(self, node: int, force, gradient_force=(0.0, 0.0, 0.0), frame: str = "world") -> None:
        super().__init__(force, frame, "NodalLoad")
        self.node = int(node)
        self.generalized = np.concatenate([self.vector, _frame_vector(gradient_force, frame,
                                                                      "NodalLoad gradient_force")])

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
class MaterialPointForce(ElementLocalForce):
    """Forces from a per-point law at material points s_k with weights w_k (e.g. length shares for a force per
    length): Q = sum_k w_k S^T(s_k) F_k (eq. 15) with the chain-rule Jacobians
        dQ/dq  = sum_k w_k S_k^T (dF/dr S_k + dF/dr_x S_x,k),   dQ/dq' = sum_k w_k S_k^T dF/dv S_k.
    law(r, r_x, v, t, base) -> PointForces, all world frame, arrays (k, 3) in and out."""

    arc_lengths: np.ndarray
    weights: np.ndarray
    law: PointForceLaw
    state_dependent: ClassVar[bool] = True
    time_invariant: ClassVar[bool] = False
    stateful: ClassVar[bool] = False

    def __post_init__(self) -> None:
        self.arc_lengths = np.atleast_1d(np.asarray(self.arc_lengths, dtype=float))
        self.weights = np.broadcast_to(np.asarray(self.weights, dtype=float), self.arc_lengths.shape).copy()
        if not np.all(np.isfinite(self.weights)):
            raise ValueError("MaterialPointForce: weights must be finite")

    def assemble_banded(self, model, q, qd, t, base, band, kl, c_q, c_qd) -> np.ndarray:
        table = _per_model(self, model, lambda m: m.interpolation(self.arc_lengths))
        r, r_x, v = table.positions(q), table.gradients(q), table.positions(qd)
        forces = self.law(r, r_x, v, t, base)
        k = self.arc_lengths.size
        derivatives = [_NO_DERIVATIVE if d is None else np.ascontiguousarray(d, dtype=float)
                       for d in (forces.dF_dr, forces.dF_drx, forces.dF_dv)]
        F = np.ascontiguousarray(forces.F, dtype=float)
        if F.shape != (k, 3) or any(d is not _NO_DERIVATIVE and d.shape != (k, 3, 3) for d in derivatives):
            raise ValueError(f"MaterialPointForce law must return F (k, 3) and derivatives (k, 3, 3), k = {k}")
        Q = np.zeros(model.n_dof)
        assemble_point_forces(table.slots, table.S, table.S_x, self.weights, F, *derivatives, Q, band, kl, c_q, c_qd)
        return Q

    def touches_element(self, model, element: int) -> bool:
        return bool(np.any(_per_model(self, model, lambda m: m.interpolation(self.arc_lengths)).element == element))


@njit(cache=True)
def assemble_point_forces(slots, S, S_x, weights, F, dF_dr, dF_drx, dF_dv, Q, band, kl, c_q, c_qd):
    """Scatter sum_k w_k S_k^T F_k (eq. 15) into Q and c_q dQ/dq + c_qd dQ/dq' (MaterialPointForce's chain rule) into
    ``band`` (row i, column j at band[i, j - i + kl], kl >= 11), point by point (:func:`scatter_point`); a (0, 0)
    band: Q alone; a derivative of no points ((0, 3, 3)): zero."""
    with_matrix = band.shape[0] > 0
    with_position, with_gradient, with_velocity = dF_dr.shape[0] > 0, dF_drx.shape[0] > 0, dF_dv.shape[0] > 0
    position = np.zeros((3, 3))  # c_q dF/dr + c_qd dF/dv of the point
    for k in range(slots.shape[0]):
        if with_matrix:
            for c in range(3):
                for c2 in range(3):
                    entry = 0.0
                    if with_position:
                        entry += c_q * dF_dr[k, c, c2]
                    if with_velocity:
                        entry += c_qd * dF_dv[k, c, c2]
                    position[c, c2] = entry
        scatter_point(slots, S, S_x, k, weights[k], F[k], position, dF_drx[k] if with_gradient else position,
                      with_gradient, Q, band, kl, c_q)


@njit(cache=True, inline="always")  # a call per point, not inlined, cost ~0.3 us per shaft assembly
def scatter_point(slots, S, S_x, k, weight, force, position, gradient, with_gradient, Q, band, kl, c_q):
    """Add the force (3,) of interpolation point k with weight w, w S_k^T F (eq. 15), to Q and, unless ``band`` is
    (0, 0), its Jacobian blocks w S_a^T (``position`` S_b + c_q ``gradient`` S_x,b) (3, 3 each; ``position``: c_q
    dF/dr + c_qd dF/dv, ``gradient``: dF/dr_x, read only ``with_gradient``) to the band matrix (row i, column j at
    band[i, j - i + kl]). The one scatter of every point force (``assemble_point_forces``, the tissue's shaft)."""
    with_matrix = band.shape[0] > 0
    for a in range(4):
        ia = 3 * slots[k, a]
        wa = weight * S[k, a]
        for c in range(3):
            Q[ia + c] += wa * force[c]
        if not with_matrix:
            continue
        for b in range(4):
            ib = 3 * slots[k, b]
            cr = wa * S[k, b]
            if with_gradient:  # the branch outside the inner loops (the shaft's scatter has no gradient)
                cx = c_q * wa * S_x[k, b]
                for c in range(3):
                    row = ia + c
                    for c2 in range(3):
                        band[row, ib + c2 - row + kl] += cr * position[c, c2] + cx * gradient[c, c2]
            else:
                for c in range(3):
                    row = ia + c
                    for c2 in range(3):
                        band[row, ib + c2 - row + kl] += cr * position[c, c2]
