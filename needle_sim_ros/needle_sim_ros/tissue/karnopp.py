"""Karnopp shaft friction of seed 001, eq. 2, as a distributed elasto-plastic traction law.

Seed 001 eq. 2 gives the friction on the inserted shaft while inserting (velocity v > 0) as
``F_f = (C_n + b_n v) d`` with d the insertion depth, i.e. a Coulomb part C_n and a viscous part b_n per unit
inserted length.  The seed prints the units garbled ("C_n = 6 Nm, b_n = 120 N/m^2"); the dimensionally
consistent reading, used here, is C_n in N/m and b_n in N s/m^2 (force per unit inserted length, and per unit
length per unit velocity).

Definitions this module adds to the seed (issue #5 asks for them):

* Retraction (v < 0): the same law mirrored, the force opposes the sliding: ``F_f = -(C_n sgn v + b_n v) d``
  (magnitude ``(C_n + b_n |v|) d``).
* Stick band: Karnopp's stick band is realised in displacement (pre-sliding) form.  Each shaft point is tied to a
  stick anchor in the tissue by an axial spring of stiffness ``k_a`` per unit length; while the elastic
  displacement u from the anchor stays inside the band ``|u| < C_n / k_a`` the shaft sticks (the Coulomb part is
  the elastic holding traction ``-k_a u``, which can be anything up to the static limit C_n); at the band edge the
  anchor slides with the shaft (plastic slip) and the Coulomb traction saturates at ``-C_n sgn(u)``.  The viscous
  part ``-b_n v`` acts in both regimes.  In steady sliding this reproduces eq. 2 exactly, per unit length.

All functions are vectorized over points (arrays of any shape broadcast together).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class KarnoppFriction:
    """Parameters of the shaft friction law (seed 001 eq. 2 plus the stick band above).

    coulomb: C_n, Coulomb (static = kinetic) friction per unit inserted length [N/m] (seed 001: 6).
    viscous: b_n, viscous friction per unit inserted length and unit sliding velocity [N s/m^2] (seed 001: 120).
    stick_stiffness: k_a, axial stiffness of the stick anchors per unit length [N/m^2]; the stick band is
        ``|u| < C_n / k_a``.
    """

    coulomb: float
    viscous: float
    stick_stiffness: float

    def __post_init__(self) -> None:
        for name in ("coulomb", "viscous"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0.0:
                raise ValueError(f"KarnoppFriction.{name} must be finite and >= 0, got {value!r}")
        if not np.isfinite(self.stick_stiffness) or self.stick_stiffness <= 0.0:
            raise ValueError(f"KarnoppFriction.stick_stiffness must be finite and > 0, got {self.stick_stiffness!r}")

    @property
    def stick_band(self) -> float:
        """Half-width C_n / k_a [m] of the pre-sliding band in which the shaft sticks to the tissue."""
        return self.coulomb / self.stick_stiffness

    def sliding_force(self, depth, velocity):
        """Eq. 2 (mirrored for retraction): axial friction force [N] on a shaft sliding at ``velocity`` [m/s]
        with ``depth`` [m] inserted, signed like the force ON the needle along the insertion direction."""
        depth = np.asarray(depth, dtype=float)
        velocity = np.asarray(velocity, dtype=float)
        return -(self.coulomb * np.sign(velocity) + self.viscous * velocity) * depth

    def traction(self, elastic_displacement, velocity, coulomb=None, viscous=None):
        """Axial traction per unit length on the shaft [N/m] and its derivatives.

        elastic_displacement: u = axial position of the shaft point minus its stick anchor [m].
        velocity: axial sliding velocity of the shaft point relative to the tissue [m/s].
        coulomb, viscous: optional per-point overrides of C_n and b_n (per-layer values); k_a is shared.
        Returns (t, dt_du, dt_dv): ``t = -(clip(k_a u, -C_n, C_n) + b_n v)`` (``axial_traction``).
        """
        u, v, c_n, b_n = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (
            elastic_displacement, velocity, self.coulomb if coulomb is None else coulomb,
            self.viscous if viscous is None else viscous)))
        out = np.empty((3,) + u.shape)
        flat = out.reshape(3, -1)
        for k, args in enumerate(zip(u.ravel(), v.ravel(), c_n.ravel(), b_n.ravel())):
            flat[:, k] = axial_traction(args[0], args[1], self.stick_stiffness, args[2], args[3], 0.0, 0.0, 0.0)
        return out[0], out[1], out[2]

    def slipped_displacement(self, elastic_displacement, coulomb=None):
        """Plastic return: the elastic displacement left after the anchors slid (clipped to the stick band)."""
        c_n = self.coulomb if coulomb is None else np.asarray(coulomb, dtype=float)
        band = c_n / self.stick_stiffness
        return np.clip(np.asarray(elastic_displacement, dtype=float), -band, band)


@njit(cache=True)
def axial_traction(u, v, stick_stiffness, coulomb, viscous, offset, sign_gain, velocity_scale):
    """Scalar axial traction [N/m] ``t = -(clip(k_a u, -C, C) + b v + A + B sgn_vs(v))`` and dt/du, dt/dv.

    The first two terms are the elasto-plastic Karnopp law above (C = C_n, b = b_n); A and B sgn_vs(v), with
    sgn_vs(v) = tanh(v / v_s) (exact sign for v_s = 0), carry a velocity-sign force per length such as the seed
    003 bracket (``shaft_laws.LuGreShaftForce``).  One implementation for the reference law and the 1 kHz loop.
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
