"""The tissue's forces at the tip as contributions, each reading the contact (``contact.ContactRecord``) after a step,
applied by the shared point-force kernel at the last element's end (eq. 15):

* the bevel tip (``BEVEL_KERNELS``): seed 001 eqs. 4-5, F = K_T (-P1 t + Q1 n) (unit bevel's P1, Q1; n the bevel
  side rolled with the base) while the tip is at the cut front below the punctured surface, ramped in over the
  bevel length a; record: the force's scale (K_T of the tip's layer times the embedded fraction squared);
* the seed 002 tip resistance (``RESISTANCE_KERNELS``): capsule stiffness -(a1 x + a2 x^2) n along the entry normal
  before puncture, then the cutting force -F_c clip(v_t / v_c, 0, 1) t while the tip advances into uncut tissue
  (never adding energy); record: (punctured, cutting).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.model.forces import assemble_point_forces
from needle_sim_ros.model.kinematics import dot3, offset_dot, rotate
from needle_sim_ros.model.records import take_float, view_matrix, view_vector
from needle_sim_ros.model.step import Kernels, itself, off_base

from .bevel_tip import tip_force_kernel
from .geometry import TIP_STIFFNESS_ROW, layer_row

_TIP_S = np.array([[0.0, 0.0, 1.0, 0.0]])    # at the last element's end r = e_3 and r_x = e_4 (eq. 4)
_TIP_S_X = np.array([[0.0, 0.0, 0.0, 1.0]])
_UNIT_WEIGHT = np.ones(1)
_NO_DERIVATIVE = np.zeros((3, 3))


@njit(cache=True)
def tip_point_force(force, d_dr, d_drx, d_dv, Q, band, kl, c_q, c_qd):
    """Add a force (3,) at the tip (the last element's end point, eq. 15) to Q and its Jacobian blocks from dF/dr,
    dF/dr_x, dF/dv (3, 3) to the band matrix by the shared point-force kernel."""
    last = Q.size // 3 - 4
    slots = np.arange(last, last + 4).reshape(1, 4)
    assemble_point_forces(slots, _TIP_S, _TIP_S_X, _UNIT_WEIGHT, force.reshape(1, 3), d_dr.reshape(1, 3, 3),
                          d_drx.reshape(1, 3, 3), d_dv.reshape(1, 3, 3), Q, band, kl, c_q, c_qd)


@njit(cache=True)
def bevel_load(state, constants):
    """(scale, unit axial force, unit transverse force, side (base frame), edge a, layer bottoms, layer table)."""
    c = np.zeros(1, dtype=np.int64)
    b = constants
    return (state[0], take_float(b, c), take_float(b, c), view_vector(b, c), take_float(b, c), view_vector(b, c),
            view_matrix(b, c))


@njit(cache=True)
def bevel_store(carried):
    return np.array([carried[0]])


@njit(cache=True)
def bevel_assemble(forces, q, qd, rotation, Q, band, kl, c_q, c_qd):
    """False if the bevel side lies along the tip tangent."""
    scale, axial, transverse, side_base = forces[0], forces[1], forces[2], forces[3]
    if scale == 0.0:
        return True
    force, jacobian, ok = tip_force_kernel(q[-3:], np.array(rotate(rotation, side_base)), axial, transverse)
    if ok:
        force *= scale
        jacobian *= scale
        tip_point_force(force, _NO_DERIVATIVE, jacobian, _NO_DERIVATIVE, Q, band, kl, c_q, c_qd)
    return ok


@njit(cache=True)
def bevel_advance(carried, q, qd, t, contact):
    """The scale of the next step from the contact (module docstring)."""
    c = contact.record
    scale = 0.0
    if c.punctured and c.at_front:
        embedded = min(c.tip_depth / max(carried[4], 1e-12), 1.0)
        scale = layer_row(carried[5], carried[6], c.tip_depth, TIP_STIFFNESS_ROW) * embedded**2
    return (scale, carried[1], carried[2], carried[3], carried[4], carried[5], carried[6])


BEVEL_KERNELS = Kernels(bevel_load, bevel_store, itself, bevel_assemble, bevel_advance, off_base)


@njit(cache=True)
def cutting_force(rx, v, cutting_force, speed_scale):
    """-F_c clip(v.t / v_c, 0, 1) t (t = r_x/|r_x|) and its derivatives with respect to r_x and v (compiled, in
    scalar loops): d/dr_x = -F_c (ramp I + slope t v^T)(I - t t^T)/|r_x|, d/dv = -F_c slope t t^T."""
    rx_norm = np.sqrt(dot3(rx, rx))
    t = rx / rx_norm
    v_t = dot3(v, t)
    argument = v_t / speed_scale
    ramp = min(max(argument, 0.0), 1.0)
    slope = 1.0 / speed_scale if 0.0 < argument < 1.0 else 0.0
    d_drx, d_dv = np.empty((3, 3)), np.empty((3, 3))
    for i in range(3):
        c_t = ramp * t[i] + slope * t[i] * v_t
        for j in range(3):
            c_ij = (ramp if i == j else 0.0) + slope * t[i] * v[j]
            d_drx[i, j] = -cutting_force * (c_ij - c_t * t[j]) / rx_norm
            d_dv[i, j] = -cutting_force * slope * t[i] * t[j]
    return -cutting_force * ramp * t, d_drx, d_dv


@njit(cache=True)
def capsule_force(r, entry_point, entry_normal, a1, a2):
    """Seed 002 eq. 1 before puncture: -(a1 x + a2 x^2) n at the tip depth x = n . (r - p0) > 0 (n the entry
    normal; zero above the surface) and its derivative with respect to r (conservative)."""
    x = offset_dot(r, entry_point, entry_normal)
    if x <= 0.0:
        return np.zeros(3), np.zeros((3, 3))
    return -(a1 * x + a2 * x * x) * entry_normal, -(a1 + 2.0 * a2 * x) * np.outer(entry_normal, entry_normal)


@njit(cache=True)
def resistance_load(state, constants):
    """(punctured, cutting, entry point, entry normal, a1, a2, F_c, v_c, block thickness)."""
    c = np.zeros(1, dtype=np.int64)
    b = constants
    return (state[0] != 0.0, state[1] != 0.0, view_vector(b, c), view_vector(b, c), take_float(b, c),
            take_float(b, c), take_float(b, c), take_float(b, c), take_float(b, c))


@njit(cache=True)
def resistance_store(carried):
    out = np.zeros(2)
    out[0], out[1] = carried[0], carried[1]
    return out


@njit(cache=True)
def resistance_assemble(forces, q, qd, rotation, Q, band, kl, c_q, c_qd):
    punctured, cutting, entry_point, entry_normal = forces[0], forces[1], forces[2], forces[3]
    a1, a2, magnitude, speed_scale = forces[4], forces[5], forces[6], forces[7]
    if not punctured:
        force, d_dr = capsule_force(q[-6:-3].copy(), entry_point, entry_normal, a1, a2)
        tip_point_force(force, d_dr, _NO_DERIVATIVE, _NO_DERIVATIVE, Q, band, kl, c_q, c_qd)
    elif cutting:
        force, d_drx, d_dv = cutting_force(q[-3:].copy(), qd[-6:-3].copy(), magnitude, speed_scale)
        tip_point_force(force, _NO_DERIVATIVE, d_drx, d_dv, Q, band, kl, c_q, c_qd)
    return True


@njit(cache=True)
def resistance_advance(carried, q, qd, t, contact):
    """Punctured, and cutting at the front inside the block, from the contact."""
    c = contact.record
    return (c.punctured, c.punctured and c.at_front and c.tip_depth < carried[8], carried[2], carried[3],
            carried[4], carried[5], carried[6], carried[7], carried[8])


RESISTANCE_KERNELS = Kernels(resistance_load, resistance_store, itself, resistance_assemble, resistance_advance,
                             off_base)
