"""The tissue as one stateful force contribution: contact, track, shaft support, tip forces and their readout.

A :class:`TissueModel` is immutable (the block, the laws and their parameters); everything that changes as the
needle moves through the tissue is a :class:`TissueState` value kept in ``NeedleData`` (``force_states``).  Once
per accepted step :meth:`TissueModel.advance` returns the next state: contact and track updated, shaft points
anchored or slipped, the LuGre bristle state advanced, and the contributions that act over the next step with
their data frozen (``TissueState.forces``, what :meth:`TissueModel.at` hands to the integrator).  A state is
never changed in place, so a copy of the data is a copy of references and a failed step leaves it as it was.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from needle_sim_ros.model import centerline
from needle_sim_ros.model.forces import ForceContribution

from .bevel_tip import BevelTip
from .coupling import (NO_SHAFT_FORCES, BevelTipForce, ContactState, ShaftForces, ShaftState, ShaftSupport,
                       TipResistance, TissueContact, tip_coordinates)
from .geometry import inserted_interval
from .insertion_profile import InsertionForceProfile


class TissueState(NamedTuple):
    """The tissue's state after a step: the contact (puncture, tip depth and speed, track), the shaft points
    (anchors, active points, the axial law's state) and the contributions acting over the next step."""

    contact: ContactState
    shaft: ShaftState
    forces: tuple


@dataclass(frozen=True)
class TissueReadout:
    """What the simulator publishes: insertion_depth [m] (tip depth below the entry surface, >= 0),
    inserted_length [m] (needle arc length below the surface), tip_force [N] (world force of the tissue on the
    tip: bevel + cutting/capsule), axial_force [N] (total tissue force on the needle along the base x axis,
    positive when it resists insertion, i.e. what the holder's force sensor sees from the tissue)."""

    insertion_depth: float
    inserted_length: float
    tip_force: np.ndarray
    axial_force: float


class TissueModel(ForceContribution):
    """The tissue on the needle (seeds 001-003): ``contact`` (block, track spacing, capsule puncture), ``shaft``
    (lateral support and axial law), ``bevel`` (the unit-stiffness bevel tip and its side in the base frame, or
    None) and ``tip_resistance`` (the seed 002 profile and cutting speed scale, or None)."""

    state_dependent = True
    time_invariant = False
    stateful = True

    def __init__(self, contact: TissueContact, shaft: ShaftSupport,
                 bevel: tuple[BevelTip, np.ndarray] | None = None,
                 tip_resistance: tuple[InsertionForceProfile, float] | None = None) -> None:
        if bevel is not None:
            side = np.asarray(bevel[1], dtype=float)
            if side.shape != (3,) or abs(side[0]) > 0.999 * np.linalg.norm(side) or not np.linalg.norm(side) > 0:
                raise ValueError("bevel_tip.side must be a 3-vector in the base frame not along the needle (x) axis")
            bevel = (replace(bevel[0], tip_stiffness=1.0), side / np.linalg.norm(side))
        if tip_resistance is not None and not tip_resistance[1] > 0.0:
            raise ValueError(f"insertion_profile.cutting_speed_scale must be > 0, got {tip_resistance[1]!r}")
        self.contact = contact
        self.shaft = shaft
        self.bevel = bevel
        self.tip_resistance = tip_resistance

    def initial_state(self, model) -> TissueState:
        """Fresh tissue: not punctured, no track, no shaft point inside."""
        contact = self.contact.initial
        shaft = self.shaft.initial
        return TissueState(contact, shaft, self._forces(contact, shaft, NO_SHAFT_FORCES))

    def advance(self, model, state, base, tissue: TissueState) -> TissueState:
        """The tissue after the accepted step to ``state`` (see the module docstring)."""
        contact = self.contact.update(tissue.contact, state.q, state.qd, state.t)
        shaft, shaft_forces = self.shaft.advance(model, contact, state.q, tissue.shaft)
        return TissueState(contact, shaft, self._forces(contact, shaft, shaft_forces))

    def _forces(self, contact: ContactState, shaft: ShaftState, shaft_forces: ShaftForces) -> tuple:
        """The contributions of the next step: the shaft's, the bevel tip's (engaged at the cut front; eqs. 4-5
        scale with the squared edge lengths, so while the bevel enters the forces grow with the square of its
        embedded fraction, tip depth / axial bevel length a) and the seed 002 tip's."""
        forces: list = [shaft_forces]
        if self.bevel is not None:
            unit, side = self.bevel
            engaged = contact.punctured and contact.at_front
            embedded = min(contact.tip_depth / max(unit.edge_a, 1e-12), 1.0)
            scale = (float(self.contact.block.layer_value("tip_stiffness", contact.tip_depth)) * embedded**2
                     if engaged else 0.0)
            forces.append(BevelTipForce(unit, side, scale))
        if self.tip_resistance is not None:
            block = self.contact.block
            cutting = contact.punctured and contact.at_front and contact.tip_depth < block.thickness
            forces.append(TipResistance(block, *self.tip_resistance, contact.punctured, cutting))
        return tuple(forces)

    def at(self, tissue: TissueState) -> tuple:
        """The contributions acting over the step that starts from ``tissue``."""
        return tissue.forces

    def readout(self, model, tissue: TissueState, state, base) -> TissueReadout:
        """What the simulator publishes at ``state`` with the tissue in ``tissue``."""
        block = self.contact.block
        r_tip, _ = tip_coordinates(state.q)
        depth = max(float(block.depth(r_tip)), 0.0)
        line = centerline(model, state.q, max(4 * model.n_nodes, 16))
        s_entry, s_tip = inserted_interval(block, line.points, line.arc_length)
        tip_force = np.zeros(3)
        total = np.zeros(3)
        for force in tissue.forces:
            on_tip, on_needle = force.resultants(model, state, base)
            tip_force += on_tip
            total += on_needle
        return TissueReadout(depth, s_tip - s_entry, tip_force, float(-total @ base.rotation[:, 0]))
