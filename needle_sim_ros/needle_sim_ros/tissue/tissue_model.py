"""The tissue as one stateful force contribution: contact, track, shaft support, tip forces and their readout.

A :class:`TissueModel` is immutable (the block, the laws and their parameters); everything that changes as the
needle moves through the tissue is a :class:`TissueState` value kept in ``NeedleData`` (``force_states``).  Once
per accepted step :meth:`TissueModel.advance` returns the next state: contact and track updated, shaft points
anchored or slipped, the LuGre bristle state advanced, and the contributions that act over the next step with
their data frozen (``TissueState.forces``, what :meth:`TissueModel.at` hands to the integrator).  A state is
never changed in place, so a copy of the data is a copy of references and a failed step leaves it as it was.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from needle_sim_ros.model import centerline
from needle_sim_ros.model.forces import ForceContribution

from .advance import tip_parameters
from .bevel_tip import BevelTip
from .coupling import (NO_SHAFT_FORCES, BevelTipForce, ContactState, ShaftForces, ShaftState, ShaftSupport,
                       TipResistance, TissueContact, _Frozen, tip_coordinates)
from .track import Track
from .geometry import inserted_interval
from .insertion_profile import InsertionForceProfile
from .sequence import (TISSUE_KERNELS, Contact, TissueRecord, advance_packed, pack_parameters, pack_record,
                       unpack_record)


class TissueState:
    """The tissue's state after a step: its ``sequence.TissueRecord`` packed into one array (``record``), as the
    compiled advance returns it and the next compiled run takes it.

    The objects the general path and the readout use -- ``contact``, ``shaft`` and ``forces`` (the contributions
    acting over the next step) -- are built from it on first use. A value: never changed in place."""

    __slots__ = ("tissue", "record", "_views")

    def __init__(self, tissue: TissueModel, record: np.ndarray) -> None:
        self.tissue = tissue
        self.record = record
        self._views: tuple | None = None

    def __reduce__(self):
        return TissueState, (self.tissue, self.record)

    @property
    def contact(self) -> ContactState:
        return self._built()[0]

    @property
    def shaft(self) -> ShaftState:
        return self._built()[1]

    @property
    def forces(self) -> tuple:
        return self._built()[2]

    def _built(self) -> tuple:
        if self._views is None:
            self._views = self.tissue.views(self.record)
        return self._views


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
    compiled_run = True
    kernels = TISSUE_KERNELS

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
        block = contact.block
        contact_arguments = (block.entry_point, block.entry_normal, float(contact.puncture_depth or 0.0),
                             float(contact.initial.track.spacing))
        unit, side = bevel if bevel is not None else (None, np.zeros(3))
        profile, speed_scale = tip_resistance if tip_resistance is not None else (None, 1.0)
        self.bevel_edge = unit.edge_a if unit else 1.0  # a [m]: the bevel's embedded fraction is depth / a
        tip_arguments = (unit is not None, float(unit.axial_force) if unit else 0.0,
                         float(unit.transverse_force) if unit else 0.0, np.asarray(side, dtype=float),
                         float(self.bevel_edge), profile is not None,
                         *((float(profile.a1), float(profile.a2), float(profile.cutting_force)) if profile
                           else (0.0, 0.0, 0.0)), float(speed_scale))
        self.constants = pack_parameters(contact_arguments, shaft.kernel_arguments, tip_arguments)

    def initial_state(self, model) -> TissueState:
        """Fresh tissue: not punctured, no track, no shaft point inside."""
        contact, shaft = self.contact.initial, self.shaft.initial
        lateral, axial = (part.fields for part in NO_SHAFT_FORCES.parts)
        fresh = Contact(bool(contact.punctured), float(contact.tip_depth), float(contact.tip_axial_speed),
                        float(contact.step_duration), bool(contact.at_front), *contact.track.kernel_arrays)
        return TissueState(self, pack_record(TissueRecord(fresh, np.nan, float(shaft.law), shaft.anchor,
                                                          shaft.active, lateral, axial)))

    def advance(self, model, state, base, tissue: TissueState) -> TissueState:
        """The tissue after the accepted step to ``state`` (see the module docstring; ``advance``)."""
        return TissueState(self, advance_packed(tissue.record, self.constants, state.q, state.qd, float(state.t)))

    @staticmethod
    def packed_state(tissue: TissueState) -> np.ndarray:
        """The state a compiled run takes (``contribution.ContributionRun``)."""
        return tissue.record

    def unpacked_state(self, record: np.ndarray) -> TissueState:
        """The state of the record a compiled run returns."""
        return TissueState(self, record)

    def views(self, packed: np.ndarray) -> tuple[ContactState, ShaftState, tuple]:
        """The contact, the shaft state and the next step's contributions of a :class:`TissueState`'s record."""
        record = unpack_record(packed)
        c = record.contact
        track = Track(self.contact.initial.track.spacing, c.vertices, c.arc, c.direction, c.previous_tip,
                      c.end_tangent)
        contact = ContactState(bool(c.punctured), float(c.tip_depth), float(c.tip_speed), float(c.step_duration),
                               bool(c.at_front), None if math.isnan(record.time) else float(record.time), track)
        shaft_forces = ShaftForces(_Frozen.from_fields(record.lateral), _Frozen.from_fields(record.axial))
        return contact, ShaftState(record.anchor, record.active, record.law_state), self._forces(contact, shaft_forces)

    def _forces(self, contact: ContactState, shaft_forces: ShaftForces) -> tuple:
        """The contributions of the next step: the shaft's, the bevel tip's and the seed 002 tip's
        (``advance.tip_parameters``)."""
        forces: list = [shaft_forces]
        block = self.contact.block
        scale, cutting = tip_parameters(contact.punctured, contact.at_front, contact.tip_depth, self.bevel_edge,
                                        *block.kernel_tables)
        if self.bevel is not None:
            forces.append(BevelTipForce(*self.bevel, float(scale)))
        if self.tip_resistance is not None:
            forces.append(TipResistance(block, *self.tip_resistance, contact.punctured, bool(cutting)))
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
