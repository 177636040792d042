"""The tissue's state advanced after an accepted step, in compiled calls on arrays: one implementation for the
general step and the compiled run of steps (both through ``sequence.advance_tissue``).

* ``advance_contact``: tip depth and axial speed, puncture, the track started and cut, whether the tip is at the
  cut front (``coupling.ContactState``, ``track.Track``).
* ``advance_shaft``: the axial law's state, the shaft points inside the tissue (entering ones anchored), the
  anchors slipped, and the next step's frozen lateral and axial point data (``coupling.ShaftForces``), each as a
  ``FROZEN_FIELDS`` tuple.
* ``tip_parameters``: the bevel force's scale and whether the tip cuts (``TissueModel`` tip contributions).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.model.kinematics import dot3, offset_dot

from .coupling import lateral_quadrature, shaft_contact_points, slip_anchors, tip_contact
from .geometry import LATERAL_ROWS, TIP_STIFFNESS_ROW, layer_row, layer_rows
from .shaft_laws import NO_LAW, law_advance, law_coefficients
from .track import cut_polyline

# the fields of a frozen part, in the order of ``coupling._Frozen`` with its AxialCoefficients spread out
FROZEN_FIELDS = ("index", "weights", "slots", "S", "S_x", "anchor_points", "tangents", "anchor_depth",
                 "lateral_stiffness", "lateral_damping", "coulomb", "viscous", "offset", "sign_gain", "velocity_scale",
                 "stick_stiffness")


@njit(cache=True)
def inactive_part():
    """A frozen part without points (``FROZEN_FIELDS``)."""
    empty = np.zeros(0)
    return (np.zeros(0, dtype=np.int64), empty, np.zeros((0, 4), dtype=np.int64), np.zeros((0, 4)), np.zeros((0, 4)),
            np.zeros((0, 3)), np.zeros((0, 3)), empty, empty, empty, empty, empty, 0.0, 0.0, 0.0, 1.0)


@njit(cache=True)
def advance_contact(punctured, time, vertices, arc, direction, previous_tip, end_tangent, q, qd, t, entry_point,
                    entry_normal, puncture_depth, spacing):
    """The contact after a step to (q, qd) at time t from (punctured, the time of the last update (NaN: never),
    the track's vertices, arc lengths, entry direction, previous tip and end tangent): (punctured, tip depth [m],
    tip axial speed [m/s], step duration [s], at the cut front, and the track's five arrays). The track starts
    where the tip crossed the entry surface once the capsule is punctured, then grows by ``cut_polyline``."""
    r_tip = q[-6:-3].copy()
    tangent, tip_depth, tip_speed = tip_contact(q, qd, entry_point, entry_normal)
    punctured = punctured or tip_depth > puncture_depth
    if punctured and arc.size == 0 and tip_depth > 0.0:
        along = dot3(tangent, entry_normal)
        if along > 1e-3:
            entry = r_tip - tangent * tip_depth / along
        else:
            entry = r_tip - entry_normal * tip_depth
        vertices, arc = entry.reshape(1, 3).copy(), np.zeros(1)
        direction = tangent / np.sqrt(dot3(tangent, tangent))
        previous_tip, end_tangent = entry, direction
    at_front = False
    if arc.size >= 1:
        vertices, arc, end_tangent = cut_polyline(vertices, arc, end_tangent, previous_tip, r_tip, spacing)
        previous_tip = r_tip
        length = arc[-1]
        at_front = tip_depth > 0.0 and length + offset_dot(r_tip, vertices[-1], end_tangent) >= length - spacing
    step_duration = 0.0 if np.isnan(time) else max(t - time, 0.0)
    return (punctured, tip_depth, tip_speed, step_duration, at_front, vertices, arc, direction, previous_tip,
            end_tangent)


@njit(cache=True)
def lateral_part(q, node_arc, element_lengths, s_tip, xi, w, vertices, arc, end_tangent, entry_point, entry_normal,
                 bottoms, table):
    """Frozen lateral Winkler support of the needle's arc interval in cut tissue (``lateral_quadrature``; layer
    stiffness and damping at the rest points' depths)."""
    weights, slots, S, S_x, points, tangents, depth = lateral_quadrature(
        q, node_arc, element_lengths, s_tip, xi, w, vertices, arc, end_tangent, entry_point, entry_normal)
    if weights.size == 0:
        return inactive_part()
    values = layer_rows(bottoms, table, depth, LATERAL_ROWS)
    zero = np.zeros(weights.size)
    return (np.zeros(0, dtype=np.int64), weights, slots, S, S_x, points, tangents, depth, values[0].copy(),
            values[1].copy(), zero, zero, 0.0, 0.0, 0.0, 1.0)


@njit(cache=True)
def advance_shaft(q, vertices, arc, end_tangent, tip_depth, tip_speed, step_duration, anchor, was_active, law_state,
                  arc_lengths, point_weights, margin, S, S_x, slots, lateral, law_kind, law_parameters,
                  stick_stiffness, entry_point, entry_normal, bottoms, table, node_arc, element_lengths, xi, w):
    """The shaft after a step to q (contact advanced): (law state, anchors, active points, frozen lateral part,
    frozen axial part). The law's state advances first; with a started track the lateral part covers the cut
    interval and, with an axial law, the points inside the tissue are active (entering ones anchored where they
    are) and their anchors slip beyond the stick band. A point an arc length a behind the tip is at most a
    shallower than the tip, so only points closer to the tip than its depth (plus ``margin``, the outer
    neighbours for the entry coverage) are candidates."""
    law_state = law_advance(law_kind, law_parameters, law_state, tip_depth, tip_speed, step_duration)
    active = np.zeros(arc_lengths.size, dtype=np.bool_)
    if arc.size == 0:
        return law_state, anchor, active, inactive_part(), inactive_part()
    if lateral:
        lateral_frozen = lateral_part(q, node_arc, element_lengths, arc_lengths[-1], xi, w, vertices, arc,
                                      end_tangent, entry_point, entry_normal, bottoms, table)
    else:
        lateral_frozen = inactive_part()
    if law_kind == NO_LAW:
        return law_state, anchor, active, lateral_frozen, inactive_part()
    anchor = anchor.copy()
    index, coverage, tangents, points, depth, u = shaft_contact_points(
        q, arc_lengths, arc_lengths[-1] - tip_depth - margin, S, S_x, slots, entry_point, entry_normal, bottoms[-1],
        was_active, active, anchor, vertices, arc, end_tangent)
    if index.size == 0:
        return law_state, anchor, active, lateral_frozen, inactive_part()
    coulomb, viscous, offset, sign_gain, velocity_scale = law_coefficients(law_kind, law_parameters, law_state,
                                                                           depth, tip_depth, bottoms, table)
    weights, slots_in, S_in, S_x_in = slip_anchors(anchor, index, u, coulomb, stick_stiffness, points, tangents,
                                                   point_weights, coverage, slots, S, S_x)
    zero = np.zeros(index.size)
    return law_state, anchor, active, lateral_frozen, (index, weights, slots_in, S_in, S_x_in, points, tangents,
                                                       depth, zero, zero, coulomb, viscous, offset, sign_gain,
                                                       velocity_scale, stick_stiffness)


@njit(cache=True)
def tip_parameters(punctured, at_front, tip_depth, edge_a, bottoms, table):
    """(bevel force scale, cutting) of the next step: the bevel is engaged at the cut front below the punctured
    surface, K_T of the tip's layer times the square of its embedded fraction (eqs. 4-5 scale with the squared
    edge lengths, so the forces grow so while the bevel enters); the tip cuts at the front inside the block."""
    scale = 0.0
    if punctured and at_front:
        embedded = min(tip_depth / max(edge_a, 1e-12), 1.0)
        scale = layer_row(bottoms, table, tip_depth, TIP_STIFFNESS_ROW) * embedded**2
    return scale, punctured and at_front and tip_depth < bottoms[-1]
