"""Karnopp shaft friction of seed 001, eq. 2, as a distributed elasto-plastic traction law.

Seed 001 eq. 2 gives the friction on the inserted shaft while inserting (velocity v > 0) as ``F_f = (C_n + b_n v) d``
with d the insertion depth, i.e. a Coulomb part C_n and a viscous part b_n per unit inserted length.  The seed prints
the units garbled ("C_n = 6 Nm, b_n = 120 N/m^2"); the dimensionally consistent reading, used here, is C_n in N/m and
b_n in N s/m^2 (force per unit inserted length, and per unit length per unit velocity).

Definitions this module adds to the seed (issue #5 asks for them):

* Retraction (v < 0): the same law mirrored, the force opposes the sliding: ``F_f = -(C_n sgn v + b_n v) d``
  (magnitude ``(C_n + b_n |v|) d``).
* Stick band: Karnopp's stick band is realised in displacement (pre-sliding) form.  Each shaft point is tied to a
  stick anchor in the tissue by an axial spring of stiffness ``k_a`` per unit length; while the elastic
  displacement u from the anchor stays inside the band ``|u| < C_n / k_a`` the shaft sticks (the Coulomb part is
  the elastic holding traction ``-k_a u``, which can be anything up to the static limit C_n); at the band edge the
  anchor slides with the shaft (plastic slip) and the Coulomb traction saturates at ``-C_n sgn(u)``.  The viscous
  part ``-b_n v`` acts in both regimes.  In steady sliding this reproduces eq. 2 exactly, per unit length.

The test oracle ``KarnoppFriction`` (needle_sim_ros/test/test_tissue_karnopp.py) drives this law on a rigid shaft.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")  # numba 0.59's LLVM keeps a call per point: 2.4x the shaft assembly
def axial_traction(u, v, stick_stiffness, coulomb, viscous, offset, sign_gain, velocity_scale):
    """Scalar axial traction [N/m] ``t = -(clip(k_a u, -C, C) + b v + A + B sgn_vs(v))`` and dt/du, dt/dv.

    The first two terms are the elasto-plastic Karnopp law above (C = C_n, b = b_n); A and B sgn_vs(v), with
    sgn_vs(v) = tanh(v / v_s) (exact sign for v_s = 0), carry a velocity-sign force per length such as the seed
    003 bracket (``shaft_laws.LUGRE``).  One implementation for the reference law and the 1 kHz loop.
    """
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
