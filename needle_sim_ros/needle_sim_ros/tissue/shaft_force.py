"""The shaft support (``coupling.ShaftSupport``) as a contribution, its points' data frozen over each step.

``ShaftRecord``: the axial law's state, the points' anchors (track coordinates) and active flags, and the next
step's frozen points (lateral, then axial): their q slots and one table (``coupling.POINT_COLUMNS``), two arrays
because numba counts the references of each array passed. ``advance_shaft`` reads the contact after each step.
Kernels: ``SHAFT_KERNELS``.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from needle_sim_ros.model.records import (pack_record, take_float, take_flag, take_flags, take_index_matrix, take_int,
                                          take_matrix, take_vector, view_matrix, view_vector)
from needle_sim_ros.model.step import Kernels

from .coupling import (POINT_COLUMNS, first_slot_in, lateral_quadrature, point_table, shaft_contact_points,
                       shaft_generalized_force, slip_anchors)
from .geometry import LATERAL_ROWS, layer_rows
from .shaft_laws import NO_LAW, law_advance, law_coefficients


class ShaftRecord(NamedTuple):
    """The shaft's state (module docstring)."""

    law_state: float
    anchor: np.ndarray    # shaft points' anchors (track coordinates)
    active: np.ndarray    # shaft points inside the tissue
    lateral_count: int    # frozen points of the next step: the first lateral_count are the lateral ones
    slots: np.ndarray     # their q slots (m, 4)
    points: np.ndarray    # their table (m, POINT_COLUMNS)


class ShaftStep(NamedTuple):
    """What the step loop carries: the record and ``ShaftSupport.kernel_arguments``."""

    record: ShaftRecord
    constants: tuple


@njit(cache=True)
def no_points():
    """The slots and table of no frozen points."""
    return np.zeros((0, 4), dtype=np.int64), np.zeros((0, POINT_COLUMNS))


@njit(cache=True)
def lateral_part(q, node_arc, element_lengths, s_tip, xi, w, vertices, arc, end_tangent, centres, radii, entry_point,
                 entry_normal, bottoms, table):
    """Frozen lateral Winkler support of the needle's arc interval in cut tissue (``lateral_quadrature``; layer
    stiffness and damping at the rest points' depths): slots and table."""
    weights, slots, S, S_x, points, tangents, depth = lateral_quadrature(
        q, node_arc, element_lengths, s_tip, xi, w, vertices, arc, end_tangent, centres, radii, entry_point,
        entry_normal)
    values = layer_rows(bottoms, table, depth, LATERAL_ROWS)
    zero = np.zeros(weights.size)
    return slots, point_table(weights, S, S_x, points, tangents, values[0], values[1], zero, zero, 0.0, 0.0, 0.0, 1.0)


@njit(cache=True)
def advance_shaft(q, vertices, arc, end_tangent, centres, radii, tip_depth, tip_speed, step_duration, anchor,
                  was_active, law_state, arc_lengths, point_weights, margin, S, S_x, slots, lateral, law_kind,
                  law_parameters, stick_stiffness, entry_point, entry_normal, bottoms, table, node_arc, element_lengths,
                  xi, w):
    """The shaft after a step to q (contact advanced): the law's state first; with a started track the lateral points
    cover the cut interval and, with an axial law, the points inside are active (entering ones anchored where they
    are), their anchors slipping beyond the stick band. A point an arc length a behind the tip is at most a shallower,
    so only points closer to the tip than its depth (plus ``margin``, for the entry coverage) are candidates."""
    law_state = law_advance(law_kind, law_parameters, law_state, tip_depth, tip_speed, step_duration)
    active = np.zeros(arc_lengths.size, dtype=np.bool_)
    lateral_slots, lateral_points = no_points()
    if arc.size == 0:
        return ShaftRecord(law_state, anchor, active, 0, lateral_slots, lateral_points)
    if lateral:
        lateral_slots, lateral_points = lateral_part(q, node_arc, element_lengths, arc_lengths[-1], xi, w, vertices,
                                                     arc, end_tangent, centres, radii, entry_point, entry_normal,
                                                     bottoms, table)
    count = lateral_slots.shape[0]
    if law_kind == NO_LAW:
        return ShaftRecord(law_state, anchor, active, count, lateral_slots, lateral_points)
    anchor = anchor.copy()
    index, coverage, tangents, points, depth, u = shaft_contact_points(
        q, arc_lengths, arc_lengths[-1] - tip_depth - margin, S, S_x, slots, entry_point, entry_normal, bottoms[-1],
        was_active, active, anchor, vertices, arc, end_tangent, centres, radii)
    if index.size == 0:
        return ShaftRecord(law_state, anchor, active, count, lateral_slots, lateral_points)
    coulomb, viscous, offset, sign_gain, velocity_scale = law_coefficients(law_kind, law_parameters, law_state,
                                                                           depth, tip_depth, bottoms, table)
    weights, slots_in, S_in, S_x_in = slip_anchors(anchor, index, u, coulomb, stick_stiffness, points, tangents,
                                                   point_weights, coverage, slots, S, S_x)
    zero = np.zeros(index.size)
    axial = point_table(weights, S_in, S_x_in, points, tangents, zero, zero, coulomb, viscous, offset, sign_gain,
                        velocity_scale, stick_stiffness)
    return ShaftRecord(law_state, anchor, active, count, np.concatenate((lateral_slots, slots_in)),
                       np.concatenate((lateral_points, axial)))


@njit(cache=True)
def unpack_shaft(buffer):
    """The ``ShaftRecord`` of ``records.pack_record``'s array."""
    c = np.zeros(1, dtype=np.int64)
    return ShaftRecord(take_float(buffer, c), take_vector(buffer, c), take_flags(buffer, c), take_int(buffer, c),
                       take_index_matrix(buffer, c), take_matrix(buffer, c))


@njit(cache=True)
def shaft_load(state, constants):
    """The record and ``ShaftSupport.kernel_arguments`` (packed by ``records.packed``)."""
    c = np.zeros(1, dtype=np.int64)  # constants: views into the buffer
    b = constants
    arguments = (view_vector(b, c), view_vector(b, c), take_float(b, c), view_matrix(b, c), view_matrix(b, c),
                 take_index_matrix(b, c), take_flag(b, c), take_int(b, c), view_vector(b, c), take_float(b, c),
                 view_vector(b, c), view_vector(b, c), view_vector(b, c), view_matrix(b, c), view_vector(b, c),
                 view_vector(b, c), view_vector(b, c), view_vector(b, c))
    return ShaftStep(unpack_shaft(state), arguments)


@njit(cache=True)
def shaft_store(carried):
    return pack_record(carried.record)


@njit(cache=True)
def shaft_acting(carried):
    """The frozen points' slots and table, and whether a point lies on the base element."""
    r = carried.record
    return r.slots, r.points, first_slot_in(r.slots, 0)


@njit(cache=True)
def shaft_assemble(forces, q, qd, rotation, Q, band, kl, c_q, c_qd):
    shaft_generalized_force(q, qd, forces[0], forces[1], Q, band, kl, c_q, c_qd)
    return True


@njit(cache=True)
def shaft_advance(carried, q, qd, t, contact):
    r, c = carried.record, contact.record
    record = advance_shaft(q, c.vertices, c.arc, c.end_tangent, c.centres, c.radii, c.tip_depth, c.tip_speed,
                           c.step_duration, r.anchor, r.active, r.law_state, *carried.constants)
    return ShaftStep(record, carried.constants)


@njit(cache=True)
def shaft_touches_base(forces):
    return forces[2]


SHAFT_KERNELS = Kernels(shaft_load, shaft_store, shaft_acting, shaft_assemble, shaft_advance, shaft_touches_base)
