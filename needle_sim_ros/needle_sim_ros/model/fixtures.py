"""Fixtures: clamp nodes of the needle (all six coordinates [r, r_x]) to the world, the holder, or a moving frame.
Seed 000 Sec. III (Fig. 8) clamps the distal 40 %: ``Fixture(interval=(0.6 * L, L))``, the needle straight along
the world x axis from the origin when clamped.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

import numpy as np

from needle_common.transforms import quaternion_matrix, unit_quaternion

from .kinematics import BaseMotion
from .mesh import Mesh

FixtureFrame = Union[str, Callable[[float], BaseMotion]]


@dataclass(frozen=True, eq=False)
class Fixture:
    """Clamp a set of nodes and/or the nodes of an arc-length interval.

    nodes: node indices (negative from the tip); interval: (s_start, s_end) [m], every node with reference arc length in
    the closed interval; its ends must be mesh nodes (``element_lengths``): an element cannot be clamped in part.
    frame: "world", "base" (moves with the holder), "start" (held where the needle's base frame was at the (re)start:
    the pose is the needle's data, ``IntegratorMemory.clamp``) or a callable t -> BaseMotion of a moving frame.
    needle_pose: (position, orientation xyzw) of the straight needle's base frame in the fixture frame when clamped;
    node i is held at rho = p + R s_i e_x, gradient tau = R e_x (default: along the frame's x axis from its origin)."""

    nodes: tuple[int, ...] = ()
    interval: tuple[float, float] | None = None
    frame: FixtureFrame = "world"
    needle_pose: tuple = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))

    def __post_init__(self) -> None:
        if not (self.frame in ("world", "base", "start") or callable(self.frame)):
            raise ValueError("Fixture.frame must be 'world', 'base', 'start' or a callable t -> BaseMotion, got "
                             f"{self.frame!r}")
        if not self.nodes and self.interval is None:
            raise ValueError("Fixture needs nodes or an interval")

    def resolve(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(node indices (k,), rho (k, 3), tau (k, 3)) on ``mesh``."""
        n_nodes = mesh.n_elements + 1
        nodes = []
        for node in self.nodes:
            if not isinstance(node, (int, np.integer)) or not -n_nodes <= node < n_nodes:
                raise ValueError(f"Fixture node {node!r} is not a node index of the {n_nodes}-node mesh")
            nodes.append(int(node) % n_nodes)
        if self.interval is not None:
            start, end = (float(v) for v in self.interval)
            tol = 1e-9 * mesh.length
            if not (np.isfinite(start) and np.isfinite(end) and -tol <= start <= end <= mesh.length + tol):
                raise ValueError(f"Fixture.interval {self.interval!r} must satisfy 0 <= s_start <= s_end <= L")
            for s in (start, end):
                if np.min(np.abs(mesh.node_arc_length - s)) > tol:
                    raise ValueError(f"Fixture.interval end {s} m is not a mesh node (nodes at "
                                     f"{np.round(mesh.node_arc_length, 6).tolist()} m); pass element_lengths "
                                     "with a node there")
            inside = (mesh.node_arc_length >= start - tol) & (mesh.node_arc_length <= end + tol)
            nodes.extend(np.flatnonzero(inside).tolist())
        nodes = np.array(sorted(set(nodes)), dtype=np.int64)
        position = np.asarray(self.needle_pose[0], dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise ValueError(f"Fixture.needle_pose position must be 3 finite numbers, got {self.needle_pose[0]!r}")
        rotation = quaternion_matrix(unit_quaternion(self.needle_pose[1], "Fixture.needle_pose orientation"))
        rho = position[None, :] + mesh.node_arc_length[nodes, None] * rotation[:, 0][None, :]
        tau = np.tile(rotation[:, 0], (nodes.size, 1))
        return nodes, rho, tau
