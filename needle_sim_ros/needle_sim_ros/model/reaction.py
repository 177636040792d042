"""Reaction wrench at the base (seed 000 eq. 20).

The constrained rows of eq. 18 give the generalized constraint force on the base coordinates q_c = [r_A, r_xA]:
    Q_cc = M_cc q''_c + M_ca q''_a - Q_el_c - Q_d_c - Q_f_c
(the seed prints Q_el_a; the constrained part Q_el_c is meant -- the rows of the base node).  Its part on r_A is the
force of the holder on the needle; its part Q_rx on the gradient r_xA does the virtual work Q_rx . (dtheta x r_x)
under a virtual rotation dtheta of the clamp, so the moment about A is M = r_xA x Q_rx.

Sign convention: ``BaseWrench`` is the wrench the needle exerts ON its holder at A, i.e. minus the constraint
force -- what a force/torque sensor between robot flange and holder reads (after moving its reference point to A).
A gradient-deficient cable has no torsional degree of freedom, so the moment about the needle axis is zero.
"""
from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import njit

from .banded import NO_REFCOUNTS
from .elastic import ELEMENT_WORK, ElasticTables, add_elastic
from .kinematics import BaseMotion, cross, rotate_back
from .model import NeedleModel, State


class BaseWrench(NamedTuple):
    """Force [N] and moment about A [N m] of the needle on its holder, in the world and in the base frame: the
    (12,) ``values`` [force_world, torque_world, force_base, torque_base] as :func:`base_wrench_kernel` writes them
    (a step's record holds them as they come; the parts are views made when read)."""

    values: np.ndarray

    force_world = property(lambda self: self.values[0:3])
    torque_world = property(lambda self: self.values[3:6])
    force_base = property(lambda self: self.values[6:9])
    torque_base = property(lambda self: self.values[9:12])
    base = property(lambda self: self.values[6:12])  # [force_base, torque_base]: what the simulator publishes


@lru_cache(maxsize=32)
def base_rows(model: NeedleModel) -> tuple:
    """Element 0 (the only one acting on the base node): its quadrature tables and the base rows of the mass and
    damping slot matrices (slots 0-3)."""
    first = ElasticTables(*(np.ascontiguousarray(table[:1]) for table in model.elastic))
    rows = tuple(np.ascontiguousarray(m[:2, :4]) for m in (model.mass_slots, model.damping.isotropic,
                                                             model.damping.transverse))
    return (*first, np.ascontiguousarray(model.damping.strain_rate_weights[:1]), *rows)


@njit(cache=True, **NO_REFCOUNTS)
def base_constraint_kernel(q, qd, qdd, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights,
                           strain_rate_weights, mass_rows, isotropic_rows, transverse_rows, rotation, external, work,
                           out):
    """Q_cc = M_c. q'' - Q_el,c - Q_d,c - Q_f,c for the base node from element 0's coordinates (12,) into out[6:12]
    (out (12,) holds element 0's internal forces first; ``work``: the elastic kernel's, ``elastic.ELEMENT_WORK``)."""
    out[:] = 0.0
    add_elastic(q, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, out, rotation[:0], 0, 0.0,
                False, work, strain_rate_weights, 0.0, qd)
    for s in range(2):
        for c in range(3):
            total = -out[3 * s + c] - external[3 * s + c]
            for s2 in range(4):
                along = rotation[0, 0] * qd[3 * s2] + rotation[1, 0] * qd[3 * s2 + 1] + rotation[2, 0] * qd[3 * s2 + 2]
                total += (mass_rows[s, s2] * qdd[3 * s2 + c] + isotropic_rows[s, s2] * qd[3 * s2 + c]
                          + transverse_rows[s, s2] * rotation[c, 0] * along)
            out[6 + 3 * s + c] = total


def _base_external(model: NeedleModel, state: State, base: BaseMotion, forces) -> np.ndarray:
    """The external forces' share of the base node's rows (6,). Element-local forces off the first element have
    none and are not evaluated."""
    external = np.zeros(6)
    for force in forces:
        if not force.element_local or force.touches_element(model, 0):
            external += np.asarray(force.generalized_force(model, state.q, state.qd, state.t, base))[:6]
    return external


@njit(cache=True, **NO_REFCOUNTS)
def base_wrench_kernel(q, qd, qdd, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights,
                       strain_rate_weights, mass_rows, isotropic_rows, transverse_rows, rotation, external, work, out):
    """[force, torque about A] of the needle on its holder in the world frame, then in the base frame, into out (12,)
    from ``base_constraint_kernel``'s Q_cc on [r_A, r_xA] (module docstring: F = -Q_r, M = -r_xA x Q_rx) in one
    compiled call, from the whole q, q', q'' (read on the base element's 12 coordinates only), the base rotation (its
    first column is the axis) and ``work``, the elastic kernel's work area (``elastic.ELEMENT_WORK``)."""
    base_constraint_kernel(q, qd, qdd, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights,
                           strain_rate_weights, mass_rows, isotropic_rows, transverse_rows, rotation, external, work,
                           out)
    moment = cross(q[3:6], out[9:12])
    force, torque = (-out[6], -out[7], -out[8]), (-moment[0], -moment[1], -moment[2])
    force_base, torque_base = rotate_back(rotation, force), rotate_back(rotation, torque)
    for c in range(3):
        out[c], out[3 + c], out[6 + c], out[9 + c] = force[c], torque[c], force_base[c], torque_base[c]


def reaction_wrench(model: NeedleModel, state: State, base: BaseMotion | None = None, forces=()) -> BaseWrench:
    """Wrench of the needle on its holder at A (module docstring); ``forces`` as used for the step."""
    base = base or state.base
    if base is None:
        raise ValueError("reaction_wrench needs the base motion (argument base or state.base)")
    wrench = np.empty(12)
    base_wrench_kernel(state.q, state.qd, state.qdd, *base_rows(model), base.rotation,
                       _base_external(model, state, base, forces), np.empty(ELEMENT_WORK), wrench)
    return BaseWrench(wrench)
