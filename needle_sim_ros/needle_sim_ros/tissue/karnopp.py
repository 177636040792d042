"""Karnopp shaft friction of seed 001, eq. 2, as a distributed elasto-plastic traction law.

``F_f = (C_n + b_n v) d`` per inserted depth d while inserting (C_n [N/m], b_n [N s/m^2]: the dimensionally
consistent reading of the seed's garbled units); mirrored on retraction, ``F_f = -(C_n sgn v + b_n v) d``. The stick
band is in displacement form: each shaft point is tied to a stick anchor by an axial spring k_a per unit length; the
Coulomb part is ``-k_a u`` inside the band |u| < C_n / k_a and saturates at ``-C_n sgn(u)`` at its edge, where the
anchor slips with the shaft; ``-b_n v`` acts in both regimes. Steady sliding gives eq. 2 exactly. Definitions and
their reasons (issue #5): docs/design_notes.md. Test oracle: ``KarnoppFriction`` (test_tissue_karnopp.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")  # numba 0.59's LLVM keeps a call per point: 2.4x the shaft assembly
def axial_traction(u, v, stick_stiffness, coulomb, viscous, offset, sign_gain, velocity_scale):
    """Scalar axial traction [N/m] ``t = -(clip(k_a u, -C, C) + b v + A + B sgn_vs(v))`` and dt/du, dt/dv: the
    elasto-plastic Karnopp law (C = C_n, b = b_n) plus a velocity-sign force per length A + B tanh(v / v_s) (exact
    sign for v_s = 0) such as seed 003's bracket (``shaft_laws.LUGRE``). One implementation for the reference law
    and the 1 kHz loop."""
    holding = stick_stiffness * u
    if holding > coulomb:
        coulomb_part, d_du = coulomb, 0.0
    elif holding < -coulomb:
        coulomb_part, d_du = -coulomb, 0.0
    else:
        coulomb_part, d_du = holding, stick_stiffness
    if velocity_scale > 0.0:
        s = np.tanh(v / velocity_scale)
        ds = (1.0 - s * s) / velocity_scale
    else:
        s, ds = np.sign(v), 0.0
    return -(coulomb_part + viscous * v + offset + sign_gain * s), -d_du, -(viscous + sign_gain * ds)
