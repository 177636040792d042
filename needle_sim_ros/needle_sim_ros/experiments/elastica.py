"""Independent reference (no ANCF code) for the tests and the bag generator: the exact inextensible elastica of a
horizontal cantilever under a uniform load w [N/m] (own weight) and a tip load P [N], both downwards; theta(s) the
tangent angle:
    EI theta'' = (P + w (L - s)) cos(theta),  theta(0) = 0,  theta'(L) = 0,  x' = cos(theta),  z' = sin(theta),
solved by shooting on theta'(0) (DOP853, tolerances 1e-12) with Brent's method.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq


def elastica(EI: float, length: float, w: float, P: float) -> tuple[np.ndarray, float]:
    """Tip position (x, z) [m] and root bending moment EI theta'(0) [N m] of the exact elastica."""
    def rhs(s, y):
        theta, curvature, _, _ = y
        return [curvature, (P + w * (length - s)) * np.cos(theta) / EI, np.cos(theta), np.sin(theta)]

    def end(initial_curvature: float) -> np.ndarray:
        solution = solve_ivp(rhs, (0.0, length), [0.0, initial_curvature, 0.0, 0.0], method="DOP853",
                             rtol=1e-12, atol=1e-14)
        return solution.y[:, -1]

    if P == 0.0 and w == 0.0:
        return np.array([length, 0.0]), 0.0
    # the root moment is bounded by that of the loads on the undeformed needle
    bound = (P * length + 0.5 * w * length**2) / EI
    root = brentq(lambda k: end(k)[1], -1.001 * bound, 0.0, xtol=1e-15, rtol=1e-14)
    return end(root)[2:], EI * root
