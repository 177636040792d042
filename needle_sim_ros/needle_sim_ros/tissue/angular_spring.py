"""Angular-spring (pseudo-rigid-link) planar needle of seed 001 Sec. II-A, the cheaper alternative to the ANCF cable
(n_links - 1 degrees of freedom; its k_b identification, eqs. 6-8: :mod:`needle_sim_ros.identification.
bending_stiffness`).

A planar chain of rigid links, link 0 clamped, links i-1 and i joined by a torsional spring k_i at angle gamma_i, each
link's mass at its distal end (seed 001 Fig. 1a); base frame: x along the clamped link, y lateral. Eq. 1
``M(gamma) gamma'' + C(gamma, gamma') = F`` from the point masses, F = spring torques + J^T of the nodal forces.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AngularSpringNeedle:
    """link_lengths: (n,) [m], link 0 clamped; joint_stiffness: (n-1,) k_b [N m/rad]; node_masses: (n,) [kg]
    at the distal end of each link."""

    link_lengths: tuple[float, ...]
    joint_stiffness: tuple[float, ...]
    node_masses: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.link_lengths)
        if n < 2 or len(self.joint_stiffness) != n - 1 or len(self.node_masses) != n:
            raise ValueError("AngularSpringNeedle: need n >= 2 link_lengths, n-1 joint_stiffness, n node_masses")
        for name in ("link_lengths", "joint_stiffness", "node_masses"):
            values = np.asarray(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(values)) or np.any(values <= 0.0):
                raise ValueError(f"AngularSpringNeedle.{name} must be finite and > 0")

    @classmethod
    def from_beam(cls, length: float, bending_stiffness: float, mass_per_length: float, n_links: int):
        """Equal links with a uniform k_b chosen so that a small tip load gives the Euler-Bernoulli cantilever tip
        deflection F L^3 / (3 EI): the joints at x_j = j h give F h^2 sum_{m=1}^{n-1} m^2 / k_b, hence
        k_b = 3 EI h^2 sum m^2 / L^3.  The mass of each link goes to its distal node."""
        if n_links < 2:
            raise ValueError(f"AngularSpringNeedle.from_beam: n_links must be >= 2, got {n_links}")
        h = length / n_links
        k_b = 3.0 * bending_stiffness * h**2 * sum(m * m for m in range(1, n_links)) / length**3
        return cls((h,) * n_links, (k_b,) * (n_links - 1), (mass_per_length * h,) * n_links)

    @property
    def n_joints(self) -> int:
        return len(self.joint_stiffness)

    def _absolute_angles(self, gamma: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(gamma)])

    def node_positions(self, gamma) -> np.ndarray:
        """(n+1, 2) positions of the base, the joints and the tip in the base frame."""
        phi = self._absolute_angles(np.asarray(gamma, dtype=float))
        steps = np.asarray(self.link_lengths)[:, None] * np.column_stack([np.cos(phi), np.sin(phi)])
        return np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])

    def node_jacobians(self, gamma) -> np.ndarray:
        """(n+1, 2, n-1): d(node position)/d(gamma).  Node i moves with joint j (between links j-1 and j) iff
        j <= i - 1; the derivative is the 90-degree-rotated lever arm from the joint to the node."""
        positions = self.node_positions(gamma)
        n_nodes = positions.shape[0]
        jac = np.zeros((n_nodes, 2, self.n_joints))
        for j in range(self.n_joints):                 # joint j+1 sits at node j+1
            arm = positions[j + 2:] - positions[j + 1]
            jac[j + 2:, 0, j] = -arm[:, 1]
            jac[j + 2:, 1, j] = arm[:, 0]
        return jac

    def static_deflection(self, nodal_forces, gamma0=None, tol: float = 1e-12, max_iterations: int = 50):
        """Joint angles in equilibrium ``K gamma = sum_i J_i^T F_i`` (eq. 6 for a tip force) under dead nodal
        forces (n+1, 2) [N] in the base frame, by Newton's method (Jacobian by central differences)."""
        forces = np.asarray(nodal_forces, dtype=float)
        stiffness = np.diag(self.joint_stiffness)
        gamma = np.zeros(self.n_joints) if gamma0 is None else np.asarray(gamma0, dtype=float).copy()

        def residual(g):
            return stiffness @ g - np.einsum("nij,ni->j", self.node_jacobians(g), forces)

        for _ in range(max_iterations):
            r = residual(gamma)
            if np.linalg.norm(r) <= tol * max(1.0, np.linalg.norm(stiffness @ gamma)):
                return gamma
            eps = 1e-7
            jac = np.column_stack([(residual(gamma + eps * e) - residual(gamma - eps * e)) / (2 * eps)
                                   for e in np.eye(self.n_joints)])
            gamma = gamma - np.linalg.solve(jac, r)
        raise RuntimeError("AngularSpringNeedle.static_deflection: Newton did not converge")

    def acceleration(self, gamma, gamma_dot, nodal_forces) -> np.ndarray:
        """gamma'' from eq. 1 with M = sum m_i J_i^T J_i and the centripetal terms of the point masses."""
        gamma = np.asarray(gamma, dtype=float)
        gamma_dot = np.asarray(gamma_dot, dtype=float)
        jac = self.node_jacobians(gamma)[1:]                       # (n, 2, n-1), nodes at the link ends
        masses = np.asarray(self.node_masses)
        mass_matrix = np.einsum("n,nij,nik->jk", masses, jac, jac)
        phi = self._absolute_angles(gamma)
        phi_dot = np.concatenate([[0.0], np.cumsum(gamma_dot)])
        lengths = np.asarray(self.link_lengths)
        centripetal = -np.cumsum(lengths[:, None] * phi_dot[:, None] ** 2
                                 * np.column_stack([np.cos(phi), np.sin(phi)]), axis=0)   # J' gamma' per node
        generalized = (np.einsum("nij,ni->j", self.node_jacobians(gamma), np.asarray(nodal_forces, dtype=float))
                       - np.asarray(self.joint_stiffness) * gamma
                       - np.einsum("n,nij,ni->j", masses, jac, centripetal))
        return np.linalg.solve(mass_matrix, generalized)
