"""Bevel-tip forces P and Q of seed 001 eqs. 4-5 (Misra et al.'s macroscopic model) and the bevel frame.

Eq. 4:  P = K_T b^2/2 sin(lambda) (tan(lambda) - tan(beta)) / (1 + tan(lambda) tan(beta))
Eq. 5:  Q = K_T b^2/2 cos(lambda) (tan(lambda) - tan(beta)) / (1 + tan(lambda) tan(beta)) - K_T a^2/2 tan(beta)

K_T [N/m^2]: tissue tip stiffness (seed 001: 9.42e3); a, b [m]: bevel edge lengths; lambda: bevel angle; beta:
acting-point angle (seed 001: beta/lambda = 0.2). P acts along the shaft against the insertion; Q > 0 pushes the tip
toward the bevel side (the sharp point's). The bevel side is fixed in the needle: the configured base-frame
direction rotated to the world and projected perpendicular to the tip tangent (the cable has no torsion), so
spinning the base by 180 degrees reverses Q. The frame's reasoning: docs/design_notes.md.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

from needle_sim_ros.model.kinematics import dot3


SIDE_ALONG_TANGENT = "bevel side direction is parallel to the needle tip tangent"


@dataclass(frozen=True)
class BevelTip:
    """Bevel geometry and tissue tip stiffness (seed 001 Sec. IV, Fig. 2): tip_stiffness K_T [N/m^2]; bevel_angle
    lambda [rad]; acting_angle beta [rad] (0 <= beta < lambda); edge_a, edge_b: bevel edge lengths a, b [m] (a needle
    of diameter D: b = D / sin(lambda), the bevel face, and a = D / tan(lambda); ``for_diameter``)."""

    tip_stiffness: float
    bevel_angle: float
    acting_angle: float
    edge_a: float
    edge_b: float

    def __post_init__(self) -> None:
        for name in ("tip_stiffness", "edge_a", "edge_b"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0.0:
                raise ValueError(f"BevelTip.{name} must be finite and >= 0, got {value!r}")
        if not 0.0 < self.bevel_angle < 0.5 * np.pi:
            raise ValueError(f"BevelTip.bevel_angle must be in (0, pi/2) rad, got {self.bevel_angle!r}")
        if not 0.0 <= self.acting_angle < self.bevel_angle:
            raise ValueError(f"BevelTip.acting_angle must be in [0, bevel_angle), got {self.acting_angle!r}")

    @classmethod
    def for_diameter(cls, tip_stiffness: float, bevel_angle: float, acting_fraction: float, diameter: float):
        """Bevel of a needle of outer ``diameter`` [m]: b = D / sin(lambda), a = D / tan(lambda),
        beta = acting_fraction * lambda (seed 001 reports beta/lambda between 0.03 and 0.3)."""
        return cls(tip_stiffness, bevel_angle, acting_fraction * bevel_angle,
                   diameter / np.tan(bevel_angle), diameter / np.sin(bevel_angle))

    @cached_property
    def axial_force(self) -> float:
        """P of eq. 4 [N]."""
        lam, beta = self.bevel_angle, self.acting_angle
        fraction = (np.tan(lam) - np.tan(beta)) / (1.0 + np.tan(lam) * np.tan(beta))
        return 0.5 * self.tip_stiffness * self.edge_b**2 * np.sin(lam) * fraction

    @cached_property
    def transverse_force(self) -> float:
        """Q of eq. 5 [N]."""
        lam, beta = self.bevel_angle, self.acting_angle
        fraction = (np.tan(lam) - np.tan(beta)) / (1.0 + np.tan(lam) * np.tan(beta))
        return (0.5 * self.tip_stiffness * self.edge_b**2 * np.cos(lam) * fraction
                - 0.5 * self.tip_stiffness * self.edge_a**2 * np.tan(beta))

    def tip_force(self, tip_gradient: np.ndarray, bevel_side_world: np.ndarray):
        """World force on the tip ``F = -P t + Q n`` and its Jacobian dF/dr_x (3, 3). tip_gradient: r_x at the tip
        (3,), along the tip tangent t; bevel_side_world: the bevel-side direction (3,), any length, not parallel to t
        (n: its unit component perpendicular to t)."""
        rx = np.ascontiguousarray(tip_gradient, dtype=float)
        side = np.ascontiguousarray(bevel_side_world, dtype=float)
        force, jacobian, ok = tip_force_kernel(rx, side, self.axial_force, self.transverse_force)
        if not ok:
            raise ValueError(SIDE_ALONG_TANGENT)
        return force, jacobian


@njit(cache=True)
def tip_force_kernel(rx, side, p, q):
    """F = -P t + Q n with t = r_x/|r_x|, n = unit part of ``side`` normal to t, and dF/dr_x (runs per Newton
    iteration in the 1 kHz loop, hence compiled, in scalar loops: no small-matrix products or temporaries).
    dF/dr_x = (-P I + Q dn/dm dm/dt) dt/dr_x with dt/dr_x = (I - t t^T)/|r_x|, m = side - (side.t) t,
    dm/dt = -(t side^T + (side.t) I), dn/dm = (I - n n^T)/|m|."""
    rx_norm = np.sqrt(dot3(rx, rx))
    frame = np.empty((3, 3))
    t, m, n = frame[0], frame[1], frame[2]
    for i in range(3):
        t[i] = rx[i] / rx_norm
    along = dot3(side, t)
    for i in range(3):
        m[i] = side[i] - along * t[i]
    m_norm = np.sqrt(dot3(m, m))
    force = np.zeros(3)
    jacobian = np.zeros((3, 3))
    if m_norm < 1e-9 * np.sqrt(dot3(side, side)) or m_norm == 0.0:
        return force, jacobian, False
    for i in range(3):
        n[i] = m[i] / m_norm
    n_t = dot3(n, t)
    for i in range(3):
        force[i] = -p * t[i] + q * n[i]
    for i in range(3):  # row i of B = -P I + Q dn/dm dm/dt, then of B dt/dr_x in its place
        row = jacobian[i]
        for j in range(3):
            dn_dt = -(t[i] * side[j] + (along if i == j else 0.0) - n[i] * n_t * side[j] - along * n[i] * n[j])
            row[j] = (-p if i == j else 0.0) + q * dn_dt / m_norm
        b_t = row[0] * t[0] + row[1] * t[1] + row[2] * t[2]
        for j in range(3):
            row[j] = (row[j] - b_t * t[j]) / rx_norm
    return force, jacobian, True
