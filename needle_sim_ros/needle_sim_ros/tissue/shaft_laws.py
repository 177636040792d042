"""Axial laws for the inserted shaft: what resists sliding along the track, per unit inserted length.

Every law is expressed, for one step, by the coefficients of one traction law (``karnopp.axial_traction``):

    t = -( clip(k_a u, -C, C) + b v + A + B sgn_vs(v) )      [N/m], t < 0 resists insertion

u: elastic axial displacement of a shaft point from its stick anchor [m]; v: its axial velocity [m/s]; k_a: stick
anchor stiffness; C: Coulomb limit (the anchors slip to keep |k_a u| <= C after each step); b: viscous
coefficient; A, B: velocity-independent and velocity-sign parts.  ``anchor_depth`` is the depth of each point's
anchor (layer lookup), ``insertion_depth`` the depth of the tip.

* ``KarnoppShaftFriction``: seed 001 eq. 2, C = C_n and b = b_n of each point's layer.
* ``ProfileShaftFriction``: seed 002 eq. 2, the Fourier friction F_f(x) of the insertion depth x spread evenly
  over the inserted length: C = max(F_f(x), 0) / x, b = 0, with the same stick band.
* ``LuGreShaftForce``: seed 003 eqs. 1-2; the bracket of eq. 1b is a force per inserted length,
  A + B sgn_vs(v) with A = sigma0 z (1 - sigma1 exp(-alpha l)/g(l)) and B = sigma1 exp(-alpha l) + sigma2, each
  point using its own axial velocity; the bristle state z is advanced by RK3 once per step from the insertion depth
  and the tip's axial speed.  The bristle provides the stick, so C = 0 and the anchors follow the shaft.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .geometry import TissueBlock
from .insertion_profile import InsertionForceProfile
from .lugre import ModifiedLuGre, force_per_length


class AxialCoefficients(NamedTuple):
    """Coefficients of the traction law above for n points: coulomb C (n,) [N/m], viscous b (n,) [N s/m^2],
    offset A [N/m], sign_gain B [N/m], velocity_scale v_s [m/s]."""

    coulomb: np.ndarray
    viscous: np.ndarray
    offset: float
    sign_gain: float
    velocity_scale: float


class StatelessLaw:
    """An axial law without state of its own (its state in the tissue state is None)."""

    initial_state = None

    def advance(self, law_state: None, insertion_depth: float, insertion_speed: float, dt: float) -> None:
        """Stateless."""
        return None


class KarnoppShaftFriction(StatelessLaw):
    """Seed 001 eq. 2 with the stick band of ``karnopp.KarnoppFriction``; C_n, b_n per layer."""

    def __init__(self, block: TissueBlock, stick_stiffness: float) -> None:
        if not stick_stiffness > 0.0:
            raise ValueError(f"tissue.shaft.stick_stiffness must be > 0, got {stick_stiffness!r}")
        self.block = block
        self.stick_stiffness = stick_stiffness

    def coefficients(self, law_state: None, anchor_depth: np.ndarray, insertion_depth: float) -> AxialCoefficients:
        coulomb, viscous = self.block.layer_values(("friction_coulomb", "friction_viscous"), anchor_depth)
        return AxialCoefficients(coulomb, viscous, 0.0, 0.0, 0.0)


class ProfileShaftFriction(StatelessLaw):
    """Seed 002 eq. 2 friction F_f(x) spread over the inserted length x, with a stick band of stiffness k_a."""

    def __init__(self, profile: InsertionForceProfile, stick_stiffness: float) -> None:
        if not stick_stiffness > 0.0:
            raise ValueError(f"tissue.shaft.stick_stiffness must be > 0, got {stick_stiffness!r}")
        self.profile = profile
        self.stick_stiffness = stick_stiffness

    def coefficients(self, law_state: None, anchor_depth: np.ndarray, insertion_depth: float) -> AxialCoefficients:
        limit = 0.0
        if insertion_depth > 0.0:
            limit = max(float(self.profile.friction_force(insertion_depth)), 0.0) / insertion_depth
        return AxialCoefficients(np.full(anchor_depth.shape, limit), np.zeros(anchor_depth.shape), 0.0, 0.0, 0.0)


class LuGreShaftForce:
    """Seed 003 eqs. 1-2 as a traction per inserted length (reading in ``lugre``); its state is the bristle
    state z [m]."""

    stick_stiffness = 1.0      # unused: C = 0, the bristle state carries the stick
    initial_state = 0.0

    def __init__(self, model: ModifiedLuGre) -> None:
        self.model = model
        self.theta = model.parameters.as_array()

    def coefficients(self, z: float, anchor_depth: np.ndarray, insertion_depth: float) -> AxialCoefficients:
        depth = max(insertion_depth, 0.0)
        at_rest = float(force_per_length(z, self.theta, depth, 0.0, self.model.velocity_scale)[0])
        sliding = float(force_per_length(z, self.theta, depth, np.inf, self.model.velocity_scale)[0])
        zero = np.zeros(anchor_depth.shape)
        return AxialCoefficients(zero, zero, at_rest, sliding - at_rest, self.model.velocity_scale)

    def advance(self, z: float, insertion_depth: float, insertion_speed: float, dt: float) -> float:
        """z advanced over the step (RK3) with l = insertion depth and l' = the tip's axial speed."""
        if dt > 0.0:
            return self.model.step(z, max(insertion_depth, 0.0), insertion_speed, dt)
        return z
