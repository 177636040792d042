"""The tissue contact, the shared record of the tissue's contributions: puncture, tip depth and speed, the step's
duration, whether the tip is at the cut front, and the track cut so far (``track``). It adds no force; the force
contributions read it after each accepted step (``model.step.compose`` with ``shared``). Kernels:
``CONTACT_KERNELS``; state packed by ``pack_record`` / ``unpack_contact``, constants by ``contact_constants``.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from needle_sim_ros.model.kinematics import dot3, offset_dot
from needle_sim_ros.model.records import pack_record, take_flag, take_float, take_matrix, take_vector, view_vector
from needle_sim_ros.model.step import Kernels, off_base

from .track import cut_polyline, segment_blocks


class ContactRecord(NamedTuple):
    """The contact after a step (module docstring); ``time``: of its last update (NaN: never)."""

    punctured: bool
    tip_depth: float      # [m] below the entry surface
    tip_speed: float      # [m/s] along the tip tangent
    step_duration: float  # [s] since the previous update
    at_front: bool        # the tip at the cut front
    time: float
    vertices: np.ndarray  # the track (``track``) [m]: vertices (count, 3) and their arc lengths (count,)
    arc: np.ndarray
    direction: np.ndarray    # the unit direction at the entry
    previous_tip: np.ndarray  # the tip at the previous update (the entry point at the start)
    end_tangent: np.ndarray   # the direction of the cut at the end (``track.chord_tangent``)
    centres: np.ndarray   # the track's ``track.segment_blocks``, made again only when it grows
    radii: np.ndarray


class ContactConstants(NamedTuple):
    """The block's entry point and normal, the capsule's puncture depth [m] and the track spacing [m]."""

    entry_point: np.ndarray
    entry_normal: np.ndarray
    puncture_depth: float
    spacing: float


class ContactStep(NamedTuple):
    """What the step loop carries: the record and the constants."""

    record: ContactRecord
    constants: ContactConstants


@njit(cache=True)
def tip_contact(q, qd, entry_point, entry_normal):
    """Unit tangent, depth below the entry surface [m] and axial speed [m/s] of the tip at (q, qd)."""
    rx_tip = q[-3:]
    tangent = rx_tip / np.sqrt(dot3(rx_tip, rx_tip))
    return tangent, offset_dot(q[-6:-3], entry_point, entry_normal), dot3(qd[-6:-3], tangent)


@njit(cache=True)
def advance_contact(c, p, q, qd, t):
    """The contact ``c`` after a step to (q, qd) at time t (constants ``p``). The track starts where the tip crossed
    the entry surface once the capsule is punctured, then grows by ``cut_polyline``."""
    r_tip = q[-6:-3].copy()
    tangent, tip_depth, tip_speed = tip_contact(q, qd, p.entry_point, p.entry_normal)
    punctured = c.punctured or tip_depth > p.puncture_depth
    vertices, arc, direction, previous_tip, end_tangent = c.vertices, c.arc, c.direction, c.previous_tip, c.end_tangent
    if punctured and arc.size == 0 and tip_depth > 0.0:
        along = dot3(tangent, p.entry_normal)
        if along > 1e-3:
            entry = r_tip - tangent * tip_depth / along
        else:
            entry = r_tip - p.entry_normal * tip_depth
        vertices, arc = entry.reshape(1, 3).copy(), np.zeros(1)
        direction = tangent / np.sqrt(dot3(tangent, tangent))
        previous_tip, end_tangent = entry, direction
    at_front = False
    if arc.size >= 1:
        vertices, arc, end_tangent = cut_polyline(vertices, arc, end_tangent, previous_tip, r_tip, p.spacing)
        previous_tip = r_tip
        length = arc[-1]
        at_front = tip_depth > 0.0 and length + offset_dot(r_tip, vertices[-1], end_tangent) >= length - p.spacing
    centres, radii = c.centres, c.radii
    if arc.size != c.arc.size:
        centres, radii = segment_blocks(vertices, arc)
    step_duration = 0.0 if np.isnan(c.time) else max(t - c.time, 0.0)
    return ContactRecord(punctured, tip_depth, tip_speed, step_duration, at_front, t, vertices, arc, direction,
                         previous_tip, end_tangent, centres, radii)


@njit(cache=True)
def unpack_contact(buffer):
    """The ``ContactRecord`` of ``pack_record``'s array."""
    c = np.zeros(1, dtype=np.int64)
    return ContactRecord(take_flag(buffer, c), take_float(buffer, c), take_float(buffer, c), take_float(buffer, c),
                         take_flag(buffer, c), take_float(buffer, c), take_matrix(buffer, c), take_vector(buffer, c),
                         take_vector(buffer, c), take_vector(buffer, c), take_vector(buffer, c),
                         take_matrix(buffer, c), take_vector(buffer, c))


@njit(cache=True)
def contact_load(state, constants):
    c = np.zeros(1, dtype=np.int64)
    entry_point, entry_normal = view_vector(constants, c), view_vector(constants, c)
    return ContactStep(unpack_contact(state), ContactConstants(entry_point, entry_normal, take_float(constants, c),
                                                               take_float(constants, c)))


@njit(cache=True)
def contact_store(carried):
    return pack_record(carried.record)


@njit(cache=True)
def contact_acting(carried):
    """No force: nothing acts."""
    return 0


@njit(cache=True)
def contact_assemble(forces, q, qd, rotation, Q, band, kl, c_q, c_qd):
    return True


@njit(cache=True)
def contact_advance(carried, q, qd, t):
    return ContactStep(advance_contact(carried.record, carried.constants, q, qd, t), carried.constants)


CONTACT_KERNELS = Kernels(contact_load, contact_store, contact_acting, contact_assemble, contact_advance, off_base)
