"""The tissue as one stateful force contribution composed of its parts, each with a typed record and compiled
kernels that every path runs: the contact (the shared record), the shaft support, the bevel tip and the seed 002 tip
resistance (``contact``, ``shaft_force``, ``tip_forces``). A :class:`TissueModel` is immutable; its
:class:`TissueState` in ``NeedleData.force_states`` (the parts' records in one array) is replaced once per accepted
step by :meth:`TissueModel.advance`, so a failed step leaves it as it was.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from needle_sim_ros.model import centerline
from needle_sim_ros.model.contribution import ComposedForces
from needle_sim_ros.model.forces import ForceContribution
from needle_sim_ros.model.records import packed
from needle_sim_ros.model.step import compose, pack, unpack

from .bevel_tip import BevelTip
from .contact import CONTACT_KERNELS, unpack_contact
from .coupling import ShaftSupport, TissueContact
from .geometry import inserted_interval
from .insertion_profile import InsertionForceProfile
from .shaft_force import SHAFT_KERNELS, no_points, unpack_shaft
from .tip_forces import BEVEL_KERNELS, RESISTANCE_KERNELS


class TissueState:
    """The tissue's state after a step: its parts' records packed into one array (``record``, ``step.pack``), as
    the compiled advance returns it and the next compiled run takes it. A value: never changed in place."""

    __slots__ = ("tissue", "record")

    def __init__(self, tissue: TissueModel, record: np.ndarray) -> None:
        self.tissue = tissue
        self.record = record

    def __reduce__(self):
        return TissueState, (self.tissue, self.record)

    @property
    def records(self) -> tuple:
        """The parts' records: the contact's and the shaft's (``ContactRecord``, ``ShaftRecord``), then the tip
        forces' packed arrays."""
        states = unpack(self.record, len(self.tissue.at_tip))
        return (unpack_contact(states[0]), unpack_shaft(states[1]), *(state.copy() for state in states[2:]))


@dataclass(frozen=True)
class TissueReadout:
    """What the simulator publishes: insertion_depth [m] (tip below the entry surface, >= 0), inserted_length [m]
    (arc length below it), tip_force [N] (world; bevel + cutting/capsule), axial_force [N] (total tissue force along
    the base x axis, positive resisting insertion: what the holder's force sensor sees of the tissue)."""

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
        block, along_x, k = contact.block, np.array([1.0, 0.0, 0.0]), shaft.arc_lengths.size
        # each part: kernels, constants, initial state, whether it acts at the tip (the readout's tip force)
        parts = [(CONTACT_KERNELS, packed(block.entry_point, block.entry_normal, float(contact.puncture_depth or 0.0),
                                          contact.spacing),
                  packed(False, 0.0, 0.0, 0.0, False, np.nan, np.zeros((0, 3)), np.zeros(0), along_x, np.zeros(3),
                         along_x, np.zeros((0, 3)), np.zeros(0)),
                  False),  # the fresh track (vertices, arc, direction, previous tip, end tangent): empty, so are its
                 # segment blocks; the shaft: its law's state 0, no point anchored or inside the tissue
                 (SHAFT_KERNELS, packed(*shaft.kernel_arguments),
                  packed(0.0, np.zeros(k), np.zeros(k), 0, *no_points()), False)]
        if bevel is not None:
            unit, side = bevel
            parts.append((BEVEL_KERNELS, packed(unit.axial_force, unit.transverse_force, side, unit.edge_a,
                                                *block.kernel_tables), np.zeros(1), True))
        if tip_resistance is not None:
            profile, speed_scale = tip_resistance
            parts.append((RESISTANCE_KERNELS, packed(block.entry_point, block.entry_normal, profile.a1, profile.a2,
                                                     profile.cutting_force, speed_scale, block.thickness),
                          np.zeros(2), True))
        kernels, constants, initial, self.at_tip = zip(*parts)
        self.kernels = kernels  # the engine composes the parts directly (``model.step.compiled_run``)
        self.composition = compose(kernels, shared=True)  # the same parts for the general path and the readout
        self.constants = pack(constants)
        self._initial = pack(initial)

    def __reduce__(self):
        return TissueModel, (self.contact, self.shaft, self.bevel, self.tip_resistance)

    def initial_state(self, model) -> TissueState:
        """Fresh tissue: not punctured, no track, no shaft point inside."""
        return TissueState(self, self._initial)

    def advance(self, model, state, base, tissue: TissueState) -> TissueState:
        """The tissue after the accepted step to ``state`` (the contact, then each force from it)."""
        return TissueState(self, self.composition.packed_advance(tissue.record, self.constants, state.q, state.qd,
                                                                 float(state.t)))

    @staticmethod
    def packed_state(tissue: TissueState) -> np.ndarray:
        """The state a compiled run takes (``contribution.ContributionRun``)."""
        return tissue.record

    def unpacked_state(self, record: np.ndarray) -> TissueState:
        """The state of the record a compiled run returns."""
        return TissueState(self, record)

    def at(self, tissue: TissueState) -> tuple:
        """The forces acting over the step that starts from ``tissue``: the composition's, at its state."""
        return (ComposedForces(self.composition, tissue.record, self.constants),)

    def readout(self, model, tissue: TissueState, state, base) -> TissueReadout:
        """What the simulator publishes at ``state`` with the tissue in ``tissue``: the tip force is the sum of the
        tip forces' generalized forces on the tip's position rows, the total that of every part's on all nodes'
        position rows (the Hermite position shape functions sum to one)."""
        block = self.contact.block
        depth = max(float(block.depth(state.q[-6:-3])), 0.0)
        line = centerline(model, state.q, max(4 * model.n_nodes, 16))
        s_entry, s_tip = inserted_interval(block, line.points, line.arc_length)
        parts = self.at(tissue)[0].parts(state.q, state.qd, base.rotation)
        tip_force = parts[np.array(self.at_tip), -6:-3].sum(axis=0)
        total = parts.reshape(len(self.at_tip), -1, 3)[:, 0::2].sum(axis=(0, 1))
        return TissueReadout(depth, s_tip - s_entry, tip_force, float(-total @ base.rotation[:, 0]))
