"""Axial laws for the inserted shaft: what resists sliding along the track, per unit inserted length.

Every law is expressed, for one step, by the coefficients of one traction law (``karnopp.axial_traction``):

    t = -( clip(k_a u, -C, C) + b v + A + B sgn_vs(v) )      [N/m], t < 0 resists insertion

u: elastic axial displacement of a shaft point from its stick anchor [m]; v: its axial velocity [m/s]; k_a: stick
anchor stiffness; C: Coulomb limit (the anchors slip to keep |k_a u| <= C after each step); b: viscous
coefficient; A, B: velocity-independent and velocity-sign parts.  ``anchor_depth`` is the depth of each point's
anchor (layer lookup), ``insertion_depth`` the depth of the tip.

* ``KARNOPP``: seed 001 eq. 2, C = C_n and b = b_n of each point's layer (the block's layer tables).
* ``PROFILE``: seed 002 eq. 2, the Fourier friction F_f(x) of the insertion depth x spread evenly
  over the inserted length: C = max(F_f(x), 0) / x, b = 0, with the same stick band.
* ``LUGRE``: seed 003 eqs. 1-2 (reading in ``lugre``); the bracket of eq. 1b is a force per inserted length,
  A + B sgn_vs(v) with A = sigma0 z (1 - sigma1 exp(-alpha l)/g(l)) and B = sigma1 exp(-alpha l) + sigma2, each
  point using its own axial velocity; the bristle state z is advanced by RK3 once per step from the insertion depth
  and the tip's axial speed.  The bristle provides the stick, so C = 0 and the anchors follow the shaft.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .geometry import FRICTION_ROWS, layer_rows
from .insertion_profile import fourier_series
from .lugre import bracket_kernel, bristle_step

NO_LAW, KARNOPP, PROFILE, LUGRE = 0, 1, 2, 3  # ``kind`` of each law: how the compiled kernels below read it


@njit(cache=True)
def law_coefficients(kind, parameters, law_state, anchor_depth, insertion_depth, bottoms, table):
    """The traction law's coefficients (coulomb C (n,) [N/m], viscous b (n,) [N s/m^2], offset A [N/m], sign_gain
    B [N/m], velocity_scale v_s [m/s]) of a law ``kind`` with its ``parameters``
    and state for points with anchors at ``anchor_depth`` (n,) while the tip is at ``insertion_depth``; ``bottoms``
    and ``table``: the block's layer tables (``TissueBlock.kernel_tables``)."""
    n = anchor_depth.size
    if kind == KARNOPP:
        values = layer_rows(bottoms, table, anchor_depth, FRICTION_ROWS)
        return values[0].copy(), values[1].copy(), 0.0, 0.0, 0.0
    if kind == PROFILE:
        limit = 0.0
        if insertion_depth > 0.0:
            limit = max(fourier_series(parameters, insertion_depth), 0.0) / insertion_depth
        return np.full(n, limit), np.zeros(n), 0.0, 0.0, 0.0
    if kind == LUGRE:
        theta, depth = parameters[:6], max(insertion_depth, 0.0)
        at_rest = bracket_kernel(law_state, theta, depth, 0.0)
        sliding = bracket_kernel(law_state, theta, depth, 1.0)
        return np.zeros(n), np.zeros(n), at_rest, sliding - at_rest, parameters[6]
    return np.zeros(n), np.zeros(n), 0.0, 0.0, 0.0


@njit(cache=True)
def law_advance(kind, parameters, law_state, insertion_depth, insertion_speed, dt):
    """The law's state after a step of dt [s] (LuGre: z by RK3 with l = insertion depth and l' = the tip's axial
    speed; the other laws have none)."""
    if kind == LUGRE and dt > 0.0:
        return bristle_step(law_state, parameters[:6], max(insertion_depth, 0.0), insertion_speed, dt, parameters[6],
                            np.empty(0))
    return law_state


class ShaftLaw(NamedTuple):
    """An axial law as the compiled kernels ``law_coefficients`` and ``law_advance`` read it (module docstring): its
    ``kind``, ``parameters`` (array) and stick anchor stiffness k_a [N/m^2]; its state (LuGre: z [m]) starts at 0."""

    kind: int = NO_LAW
    parameters: np.ndarray = np.zeros(0)
    stick_stiffness: float = 1.0
