"""Bending stiffness k_b of the seed 001 angular-spring needle from static tip-load tests (eqs. 6-8, least squares)."""
from __future__ import annotations

import numpy as np


def identify_bending_stiffness(gamma1, gamma2, tip_force, link1: float, link2: float):
    """Least-squares k_b of eqs. 7-8 from static tests with a tip force F_n perpendicular to the clamped link.

    gamma1, gamma2: joint angles [rad]; tip_force: F_n [N]; link1, link2: L1, L2 [m]. With Phi = (gamma1; gamma2) and
    Y = ((L1 c1 + L2 c12) F_n; L2 c12 F_n) (eq. 6, k_b1 = k_b2): k_b = (Phi^T Phi)^-1 Phi^T Y. Returns (k_b
    [N m/rad], mean-square error of k_b Phi - Y [(N m)^2])."""
    g1, g2, f = (np.asarray(a, dtype=float).ravel() for a in (gamma1, gamma2, tip_force))
    if not g1.shape == g2.shape == f.shape or g1.size == 0:
        raise ValueError("identify_bending_stiffness: gamma1, gamma2 and tip_force need the same non-zero length")
    phi = np.concatenate([g1, g2])
    if not np.any(phi):
        raise ValueError("identify_bending_stiffness: all joint angles are zero, k_b is unidentifiable")
    c1, c12 = np.cos(g1), np.cos(g1 + g2)
    y = np.concatenate([(link1 * c1 + link2 * c12) * f, link2 * c12 * f])
    k_b = float(phi @ y / (phi @ phi))
    return k_b, float(np.mean((y - k_b * phi) ** 2))
