"""The tissue as a contribution of the compiled step loop (:mod:`needle_sim_ros.model.step`): its typed state
record, its assemble / advance / touches_base kernels, and the compiled run of steps through the tissue.

* ``TissueRecord``: the contact (``Contact``: puncture, tip depth and speed, step duration, at the cut front, the
  track's arrays), its state time (NaN: never updated), the axial law's state, the shaft points' anchors and
  active flags, and the frozen lateral and axial parts of the next step (``advance.FROZEN_FIELDS`` tuples);
  ``TissueParameters``: the tissue's constants. Both cross the Python boundary packed into one float64 array
  (:mod:`needle_sim_ros.model.records`): ``pack_record`` / ``unpack_record``, ``pack_parameters``.
* ``tissue_acting``: the forces of a step from the record; ``tissue_assemble``: the shaft's lateral and axial
  point forces, the bevel tip and the seed 002 tip, each on its own Q then added (the general path's order,
  ``TissueModel.at``); ``advance_tissue``: the contact and the
  shaft advanced after an accepted step (the general path's ``TissueModel.advance`` calls it too).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import literal_unroll, njit

from needle_sim_ros.model.records import (put, take_flag, take_flags, take_float, take_index_matrix, take_indices,
                                          take_int, take_matrix, take_vector, view_matrix, view_vector)
from needle_sim_ros.model.step import Kernels

from .advance import advance_contact, advance_shaft, tip_parameters
from .coupling import (bevel_tip_assembly, first_slot_in, shaft_arguments, shaft_forces_assembly,
                       tip_resistance_assembly)


class Contact(NamedTuple):
    """The tissue contact after a step (``advance.advance_contact``)."""

    punctured: bool
    tip_depth: float      # [m] below the entry surface
    tip_speed: float      # [m/s] along the entry normal
    step_duration: float  # [s] since the previous update
    at_front: bool        # the tip at the cut front
    vertices: np.ndarray  # the track (``track.Track``)
    arc: np.ndarray
    direction: np.ndarray
    previous_tip: np.ndarray
    end_tangent: np.ndarray


class TissueRecord(NamedTuple):
    """The tissue's state (module docstring)."""

    contact: Contact
    time: float           # of the contact's last update (NaN: never)
    law_state: float
    anchor: np.ndarray    # shaft points' anchors (track coordinates)
    active: np.ndarray    # shaft points inside the tissue
    lateral: tuple        # frozen lateral part of the next step (``advance.FROZEN_FIELDS``)
    axial: tuple          # frozen axial part


class TissueParameters(NamedTuple):
    """The tissue's constants: block entry, capsule puncture depth, track spacing, ``ShaftSupport.kernel_arguments``
    (``shaft``) and the tip forces' constants."""

    entry_point: np.ndarray
    entry_normal: np.ndarray
    puncture_depth: float
    spacing: float
    shaft: tuple
    bevel_on: bool
    bevel_axial: float
    bevel_transverse: float
    bevel_side: np.ndarray
    bevel_edge: float
    resistance_on: bool
    a1: float
    a2: float
    cutting_force: float
    speed_scale: float


class TissueStep(NamedTuple):
    """The state the step loop carries: the record and the constants."""

    record: TissueRecord
    parameters: TissueParameters


class TissueForces(NamedTuple):
    """What acts over a step (``tissue_acting``): the shaft parts' point-force arguments, the bevel's and the seed
    002 tip's constants and step values, and whether a shaft point lies on the base element."""

    lateral: tuple
    axial: tuple
    bevel_on: bool
    bevel_axial: float
    bevel_transverse: float
    bevel_side: np.ndarray
    bevel_scale: float
    resistance_on: bool
    punctured: bool
    cutting: bool
    entry_point: np.ndarray
    entry_normal: np.ndarray
    a1: float
    a2: float
    cutting_force: float
    speed_scale: float
    on_base: bool


@njit(cache=True)
def _write_fields(buffer, cursor, fields):
    for field in literal_unroll(fields):
        put(buffer, cursor, field)


@njit(cache=True)
def _write_record(buffer, record):
    cursor = np.zeros(1, dtype=np.int64)
    _write_fields(buffer, cursor, record.contact)
    _write_fields(buffer, cursor, (record.time, record.law_state, record.anchor, record.active))
    _write_fields(buffer, cursor, record.lateral)
    _write_fields(buffer, cursor, record.axial)
    return cursor[0]


@njit(cache=True)
def pack_record(record):
    """A ``TissueRecord`` as one float64 array."""
    buffer = np.empty(_write_record(np.empty(0), record))
    _write_record(buffer, record)
    return buffer


@njit(cache=True)
def _take_part(buffer, cursor):
    return (take_indices(buffer, cursor), take_vector(buffer, cursor), take_index_matrix(buffer, cursor),
            take_matrix(buffer, cursor), take_matrix(buffer, cursor), take_matrix(buffer, cursor),
            take_matrix(buffer, cursor), take_vector(buffer, cursor), take_vector(buffer, cursor),
            take_vector(buffer, cursor), take_vector(buffer, cursor), take_vector(buffer, cursor),
            take_float(buffer, cursor), take_float(buffer, cursor), take_float(buffer, cursor),
            take_float(buffer, cursor))


@njit(cache=True)
def unpack_record(buffer):
    """The ``TissueRecord`` of ``pack_record``'s array."""
    cursor = np.zeros(1, dtype=np.int64)
    contact = Contact(take_flag(buffer, cursor), take_float(buffer, cursor), take_float(buffer, cursor),
                      take_float(buffer, cursor), take_flag(buffer, cursor), take_matrix(buffer, cursor),
                      take_vector(buffer, cursor), take_vector(buffer, cursor), take_vector(buffer, cursor),
                      take_vector(buffer, cursor))
    return TissueRecord(contact, take_float(buffer, cursor), take_float(buffer, cursor), take_vector(buffer, cursor),
                        take_flags(buffer, cursor), _take_part(buffer, cursor), _take_part(buffer, cursor))


@njit(cache=True)
def _write_parameters(buffer, contact, shaft, tip):
    cursor = np.zeros(1, dtype=np.int64)
    _write_fields(buffer, cursor, contact)
    _write_fields(buffer, cursor, shaft)
    _write_fields(buffer, cursor, tip)
    return cursor[0]


@njit(cache=True)
def pack_parameters(contact, shaft, tip):
    """``TissueParameters`` as one float64 array from (entry point, entry normal, puncture depth, track spacing),
    ``ShaftSupport.kernel_arguments`` and the tip's (bevel on, its axial and transverse force per unit K_T, side,
    edge a, tip resistance on, a1, a2, cutting force, speed scale)."""
    buffer = np.empty(_write_parameters(np.empty(0), contact, shaft, tip))
    _write_parameters(buffer, contact, shaft, tip)
    return buffer


@njit(cache=True)
def unpack_parameters(buffer):
    """The ``TissueParameters`` of ``pack_parameters``' array."""
    c = np.zeros(1, dtype=np.int64)  # constants: views into the buffer
    entry_point, entry_normal, puncture_depth, spacing = (view_vector(buffer, c), view_vector(buffer, c),
                                                          take_float(buffer, c), take_float(buffer, c))
    shaft = (view_vector(buffer, c), view_vector(buffer, c), take_float(buffer, c), view_matrix(buffer, c),
             view_matrix(buffer, c), take_index_matrix(buffer, c), take_flag(buffer, c), take_int(buffer, c),
             view_vector(buffer, c), take_float(buffer, c), view_vector(buffer, c), view_vector(buffer, c),
             view_vector(buffer, c), view_matrix(buffer, c), view_vector(buffer, c), view_vector(buffer, c),
             view_vector(buffer, c), view_vector(buffer, c))
    bevel_on, bevel_axial, bevel_transverse, side, edge = (take_flag(buffer, c), take_float(buffer, c),
                                                           take_float(buffer, c), view_vector(buffer, c),
                                                           take_float(buffer, c))
    return TissueParameters(entry_point, entry_normal, puncture_depth, spacing, shaft, bevel_on, bevel_axial,
                            bevel_transverse, side, edge, take_flag(buffer, c), take_float(buffer, c),
                            take_float(buffer, c), take_float(buffer, c), take_float(buffer, c))


@njit(cache=True)
def advance_tissue(record, parameters, q, qd, t):
    """The ``TissueRecord`` after a step accepted at (q, q', t)."""
    c = record.contact
    contact = Contact(*advance_contact(c.punctured, record.time, c.vertices, c.arc, c.direction, c.previous_tip,
                                       c.end_tangent, q, qd, t, parameters.entry_point, parameters.entry_normal,
                                       parameters.puncture_depth, parameters.spacing))
    law_state, anchor, active, lateral, axial = advance_shaft(
        q, contact.vertices, contact.arc, contact.end_tangent, contact.tip_depth, contact.tip_speed,
        contact.step_duration, record.anchor, record.active, record.law_state, *parameters.shaft)
    return TissueRecord(contact, t, law_state, anchor, active, lateral, axial)


@njit(cache=True)
def advance_packed(record, parameters, q, qd, t):
    """``advance_tissue`` on packed arrays (the general path's ``TissueModel.advance``)."""
    return pack_record(advance_tissue(unpack_record(record), unpack_parameters(parameters), q, qd, t))


@njit(cache=True)
def tissue_acting(step):
    """The step loop's acting kernel: the tissue's forces over the step from ``step`` (the bevel force's scale and
    whether the tip cuts from the contact, ``advance.tip_parameters``)."""
    record, p = step.record, step.parameters
    c = record.contact
    scale, cutting = tip_parameters(c.punctured, c.at_front, c.tip_depth, p.bevel_edge, p.shaft[12], p.shaft[13])
    on_base = first_slot_in(record.lateral[2], 0) or first_slot_in(record.axial[2], 0)
    return TissueForces(shaft_arguments(record.lateral), shaft_arguments(record.axial), p.bevel_on, p.bevel_axial,
                        p.bevel_transverse, p.bevel_side, scale, p.resistance_on, c.punctured, cutting, p.entry_point,
                        p.entry_normal, p.a1, p.a2, p.cutting_force, p.speed_scale, on_base)


@njit(cache=True)
def tissue_assemble(f, q, qd, rotation, Q, band, kl, c_q, c_qd):
    """Q += the tissue's generalized forces ``f`` at (q, q'), each contribution on its own Q then added (shaft,
    bevel, tip resistance: the general path's order); c_q dQ/dq + c_qd dQ/dq' added to band unless it is (0, 0).
    False if the bevel side lies along the tip tangent."""
    own = np.zeros(q.size)
    shaft_forces_assembly(q, qd, f.lateral, f.axial, own, band, kl, c_q, c_qd)
    Q += own
    if f.bevel_on:
        own[:] = 0.0
        if f.bevel_scale != 0.0 and not bevel_tip_assembly(q, rotation, f.bevel_side, f.bevel_axial,
                                                            f.bevel_transverse, f.bevel_scale, own, band, kl, c_q,
                                                            c_qd):
            return False
        Q += own
    if f.resistance_on:
        own[:] = 0.0
        tip_resistance_assembly(q, qd, f.punctured, f.cutting, f.entry_point, f.entry_normal, f.a1, f.a2,
                                f.cutting_force, f.speed_scale, own, band, kl, c_q, c_qd)
        Q += own
    return True


@njit(cache=True)
def tissue_advance(step, q, qd, t):
    """The step loop's advance kernel: the tissue after the accepted step."""
    return TissueStep(advance_tissue(step.record, step.parameters, q, qd, t), step.parameters)


@njit(cache=True)
def tissue_touches_base(f):
    """Whether a shaft point of the step lies on the base element."""
    return f.on_base


@njit(cache=True)
def tissue_load(record, parameters):
    """The step loop's load kernel: the carried ``TissueStep`` from the packed record and parameters."""
    return TissueStep(unpack_record(record), unpack_parameters(parameters))


@njit(cache=True)
def tissue_store(step):
    """The step loop's store kernel: the record after a run, packed."""
    return pack_record(step.record)


TISSUE_KERNELS = Kernels(tissue_load, tissue_store, tissue_acting, tissue_assemble, tissue_advance, tissue_touches_base)
