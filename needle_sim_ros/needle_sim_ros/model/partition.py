"""Partition q = [q_c, q_a] into prescribed (constrained) and active coordinates (seed 000 eqs. 18-19): q_c holds the
base node A (r_A and the holder's unit axis r_xA) and every clamped node, their values, velocities and
accelerations from the rigid motion of their frame. Only q_a is integrated.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fixtures import Fixture, FixtureFrame
from .kinematics import STATIC_WORLD, BaseMotion
from .mesh import Mesh


@dataclass(frozen=True, eq=False)
class ConstraintGroup:
    """Nodes attached to one frame: node indices (k,), their coordinates dofs (6k,), frame coordinates rho, tau
    (k, 3); for the world frame the constant [q, qd, qdd] (3, 6k) is precomputed."""

    frame: FixtureFrame
    nodes: np.ndarray
    dofs: np.ndarray
    local_r: np.ndarray
    local_rx: np.ndarray
    fixed: np.ndarray | None

    def impose(self, base: BaseMotion, t: float, target: np.ndarray, clamp: BaseMotion | None = None) -> None:
        """Write the group's [q, qd, qdd] into target (3, n_dof); ``clamp``: the pose of the frame "start" (None:
        the needle starts now, held where the base is)."""
        if self.fixed is not None:
            target[:, self.dofs] = self.fixed
            return
        if self.frame == "start":
            motion = held_at(base) if clamp is None else clamp
        else:
            motion = base if self.frame == "base" else self.frame(t)
        if not isinstance(motion, BaseMotion):
            raise TypeError(f"fixture frame callable must return a BaseMotion, got {type(motion).__name__}")
        motion.impose_nodes(self.local_r, self.local_rx, self.nodes, target)


def held_at(base: BaseMotion) -> BaseMotion:
    """The frame "start" of fixtures for a needle started at ``base``: that pose, at rest."""
    return BaseMotion(base.position, base.orientation)


def _dofs(nodes: np.ndarray) -> np.ndarray:
    return (6 * nodes[:, None] + np.arange(6)[None, :]).ravel()


def _world_values(nodes: np.ndarray, rho: np.ndarray, tau: np.ndarray) -> np.ndarray:
    target = np.zeros((3, 6 * (nodes.max() + 1)))
    STATIC_WORLD.impose_nodes(rho, tau, nodes, target)
    return target[:, _dofs(nodes)]


@dataclass(frozen=True, eq=False)
class Partition:
    """Constrained and active coordinates and the frames that drive the constrained ones."""

    groups: tuple[ConstraintGroup, ...]
    constrained_dofs: np.ndarray
    active_dofs: np.ndarray
    active: np.ndarray  # bool mask (n_dof,)

    @classmethod
    def build(cls, mesh: Mesh, fixtures: tuple[Fixture, ...]) -> Partition:
        """Base node 0 (attached to the base frame at rho = 0, tau = e_x) plus the fixtures' nodes."""
        per_frame: dict[int, tuple[FixtureFrame, list]] = {}  # the frame and its (nodes, rho, tau) parts
        entries = [("base", np.array([0]), np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]))]
        for fixture in fixtures:
            if not isinstance(fixture, Fixture):
                raise TypeError(f"fixtures must be Fixture objects, got {type(fixture).__name__}")
            entries.append((fixture.frame, *fixture.resolve(mesh)))
        seen: set[int] = set()
        for frame, nodes, rho, tau in entries:
            overlap = seen.intersection(nodes.tolist())
            if overlap:
                raise ValueError(f"node(s) {sorted(overlap)} clamped twice (node 0 is the base node A)")
            seen.update(nodes.tolist())
            key = hash(frame) if isinstance(frame, str) else id(frame)
            per_frame.setdefault(key, (frame, []))[1].append((nodes, rho, tau))
        groups = []
        for frame, parts in per_frame.values():
            nodes, rho, tau = (np.concatenate(column) for column in zip(*parts))
            fixed = _world_values(nodes, rho, tau) if frame == "world" else None
            groups.append(ConstraintGroup(frame, nodes, _dofs(nodes), rho, tau, fixed))
        n_dof = 6 * (mesh.n_elements + 1)
        active = np.ones(n_dof, dtype=bool)
        constrained = np.concatenate([g.dofs for g in groups])
        active[constrained] = False
        return cls(tuple(groups), np.sort(constrained), np.flatnonzero(active), active)

    def impose(self, base: BaseMotion, t: float, target: np.ndarray, clamp: BaseMotion | None = None) -> None:
        """Write the prescribed q_c, q_c', q_c'' at time t into the rows of target (3, n_dof), in place (``clamp``:
        see :meth:`ConstraintGroup.impose`)."""
        for group in self.groups:
            group.impose(base, t, target, clamp)

    @property
    def held(self) -> tuple[ConstraintGroup, ...]:
        """The groups of the frame "start" (held where the needle started)."""
        return tuple(group for group in self.groups if group.frame == "start")


def hermite_quintic(start: np.ndarray, end: np.ndarray, h: float, theta: float) -> np.ndarray:
    """Quintic Hermite interpolation of [y, y', y''] (3, m) between two instants h apart, at t0 + theta h: the
    prescribed coordinates of sub-steps, exact for motions polynomial up to degree 5 in time."""
    y0, v0, a0 = start
    y1, v1, a1 = end
    s = theta
    # basis functions and their derivatives (with respect to s) of quintic Hermite interpolation
    h00 = np.array([1 - 10 * s**3 + 15 * s**4 - 6 * s**5, -30 * s**2 + 60 * s**3 - 30 * s**4,
                    -60 * s + 180 * s**2 - 120 * s**3])
    h01 = np.array([10 * s**3 - 15 * s**4 + 6 * s**5, 30 * s**2 - 60 * s**3 + 30 * s**4,
                    60 * s - 180 * s**2 + 120 * s**3])
    h10 = np.array([s - 6 * s**3 + 8 * s**4 - 3 * s**5, 1 - 18 * s**2 + 32 * s**3 - 15 * s**4,
                    -36 * s + 96 * s**2 - 60 * s**3])
    h11 = np.array([-4 * s**3 + 7 * s**4 - 3 * s**5, -12 * s**2 + 28 * s**3 - 15 * s**4,
                    -24 * s + 84 * s**2 - 60 * s**3])
    h20 = np.array([0.5 * s**2 - 1.5 * s**3 + 1.5 * s**4 - 0.5 * s**5, s - 4.5 * s**2 + 6 * s**3 - 2.5 * s**4,
                    1 - 9 * s + 18 * s**2 - 10 * s**3])
    h21 = np.array([0.5 * s**3 - s**4 + 0.5 * s**5, 1.5 * s**2 - 4 * s**3 + 2.5 * s**4,
                    3 * s - 12 * s**2 + 10 * s**3])
    scale = np.array([1.0, 1.0 / h, 1.0 / h**2])[:, None]
    return scale * (h00[:, None] * y0 + h01[:, None] * y1 + h * (h10[:, None] * v0 + h11[:, None] * v1)
                    + h**2 * (h20[:, None] * a0 + h21[:, None] * a1))
