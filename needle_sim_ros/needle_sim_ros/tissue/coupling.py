"""Coupling of the tissue laws to the ANCF needle: the contact, the shaft support and the tip forces.

Parameters are immutable objects; what changes is a value of the tissue state (``tissue_model.TissueState``)
that ``advance`` (compiled, on arrays) gives anew after each step, never changed in place.
* ``TissueContact``: the block, the capsule puncture and the track cut by the tip; the contact (``ContactState``:
  tip depth and axial speed, puncture, at the cut front, the track) after a step.
* ``ShaftSupport``: lateral Winkler springs and dampers (per unit length) perpendicular to the needle on the part
  of it that lies in tissue the tip has already cut (path memory, ``track``; the cut front holds nothing
  laterally), integrated by Gauss quadrature; along the needle, the selected axial law of ``shaft_laws`` on
  material shaft points anchored to the track (stick-slip; without a law the needle slides freely).  The points'
  state (``ShaftState``) and the next step's ``ShaftForces``: rest points, anchors, tangents and layer parameters
  frozen during a step (explicit in the hook, implicit in the forces), assembled by the shared point-force kernel
  over the inserted part only.
* ``BevelTipForce``: P and Q of seed 001 eqs. 4-5 at the tip, in the bevel frame rolled with the base, while the
  tip is at the cut front (cutting or resting on it) below the punctured surface, ramped in over the bevel length.
* ``TipResistance``: seed 002 at the tip: the capsule stiffness force a1 x + a2 x^2 along the entry normal before
  puncture (conservative), then the cutting force while the tip advances into uncut tissue.
The force contributions (``ShaftForces``, ``BevelTipForce``, ``TipResistance``) hold one step's frozen data: state
dependent, element local, without state of their own.
"""
from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numpy as np
from numba import njit

from needle_sim_ros.model.forces import ElementLocalForce, assemble_point_forces
from needle_sim_ros.model.kinematics import dot3, offset_dot
from needle_sim_ros.model.mesh import hermite_shapes, interpolate

from .bevel_tip import SIDE_ALONG_TANGENT, BevelTip, tip_force_kernel
from .geometry import TissueBlock
from .insertion_profile import InsertionForceProfile
from .karnopp import axial_traction
from .shaft_laws import AxialCoefficients, ShaftLaw
from .track import Track, locate_on_polyline, project_on_blocks, project_on_polyline, segment_blocks


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


def tip_coordinates(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tip position r and gradient r_x: the last node's coordinates [r, r_x] (model API layout)."""
    return q[-6:-3], q[-3:]


_NO_GRADIENT = np.zeros((0, 3, 3))  # the shaft's point forces do not depend on r_x
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
def bevel_tip_assembly(q, rotation, side_base, axial_force, transverse_force, scale, Q, band, kl, c_q, c_qd):
    """``BevelTipForce.assemble_banded`` in one compiled call: ``tip_force_kernel`` per unit K_T at the bevel
    side rolled with the base, scaled, assembled by ``tip_point_force``; False if that side is along the tip
    tangent."""
    side = np.zeros(3)
    for i in range(3):
        side[i] = rotation[i, 0] * side_base[0] + rotation[i, 1] * side_base[1] + rotation[i, 2] * side_base[2]
    force, jacobian, ok = tip_force_kernel(q[-3:].copy(), side, axial_force, transverse_force)
    if ok:
        tip_point_force(scale * force, _NO_DERIVATIVE, scale * jacobian, _NO_DERIVATIVE, Q, band, kl, c_q, c_qd)
    return ok


@njit(cache=True)
def capsule_force(r, entry_point, entry_normal, a1, a2):
    """Seed 002 eq. 1 before puncture: -(a1 x + a2 x^2) n at the tip depth x = n . (r - p0) > 0 (n the entry
    normal; zero above the surface) and its derivative with respect to r (conservative)."""
    x = offset_dot(r, entry_point, entry_normal)
    if x <= 0.0:
        return np.zeros(3), np.zeros((3, 3))
    return -(a1 * x + a2 * x * x) * entry_normal, -(a1 + 2.0 * a2 * x) * np.outer(entry_normal, entry_normal)


@njit(cache=True)
def tip_resistance_assembly(q, qd, punctured, cutting, entry_point, entry_normal, a1, a2, cutting_force_magnitude,
                            speed_scale, Q, band, kl, c_q, c_qd):
    """``TipResistance.assemble_banded`` in one compiled call: the capsule force before puncture, the cutting
    force while cutting, assembled by ``tip_point_force``."""
    if not punctured:
        force, d_dr = capsule_force(q[-6:-3].copy(), entry_point, entry_normal, a1, a2)
        tip_point_force(force, d_dr, _NO_DERIVATIVE, _NO_DERIVATIVE, Q, band, kl, c_q, c_qd)
    elif cutting:
        force, d_drx, d_dv = cutting_force(q[-3:].copy(), qd[-6:-3].copy(), cutting_force_magnitude, speed_scale)
        tip_point_force(force, _NO_DERIVATIVE, d_drx, d_dv, Q, band, kl, c_q, c_qd)


class ContactState(NamedTuple):
    """The needle-tissue contact after a step (part of the tissue state): capsule punctured, tip depth [m] and
    axial speed [m/s], the step's duration [s], whether the tip is at the cut front, the state time it was updated
    at (None: never) and the track cut so far."""

    punctured: bool
    tip_depth: float
    tip_axial_speed: float
    step_duration: float
    at_front: bool
    time: float | None
    track: Track


@njit(cache=True)
def tip_contact(q, qd, entry_point, entry_normal):
    """Unit tangent, depth below the entry surface [m] and axial speed [m/s] of the tip at (q, qd)."""
    rx_tip = q[-3:]
    tangent = rx_tip / np.sqrt(dot3(rx_tip, rx_tip))
    return tangent, offset_dot(q[-6:-3], entry_point, entry_normal), dot3(qd[-6:-3], tangent)


class TissueContact:
    """How the needle meets the tissue (immutable): the block, the track spacing, and ``puncture_depth``: the depth
    [m] the tip must reach before the capsule tears and the track starts (seed 002 d1; None: the tissue is cut from
    first contact). ``advance.advance_contact`` advances a ``ContactState``."""

    def __init__(self, block: TissueBlock, spacing: float, puncture_depth: float | None = None) -> None:
        self.block = block
        self.puncture_depth = puncture_depth
        self.initial = ContactState(False, 0.0, 0.0, 0.0, False, None, Track(spacing))


class TipForce(ElementLocalForce):
    """A tissue force at the tip over one step (its data frozen at the step's start): state dependent, acting on
    the last element."""

    state_dependent = True
    time_invariant = False
    stateful = False

    def touches_element(self, model, element: int) -> bool:
        return element == model.n_elements - 1

    def resultants(self, model, state, base) -> tuple[np.ndarray, np.ndarray]:
        """World force [N] on the tip and on the whole needle at ``state``: the same."""
        force = self.tip_force_at(state.q, state.qd, base)
        return force, force

    def tip_force_at(self, q, qd, base) -> np.ndarray:
        raise NotImplementedError

    def generalized_force(self, model, q, qd, t, base) -> np.ndarray:
        generalized = np.zeros(q.size)
        generalized[q.size - 6:q.size - 3] = self.tip_force_at(q, qd, base)
        return generalized


LATERAL_GAUSS_POINTS = 3
_GAUSS_XI, _GAUSS_W = np.polynomial.legendre.leggauss(LATERAL_GAUSS_POINTS)


class _Frozen(NamedTuple):
    """Per-step frozen data of the active shaft points (n_active entries each); a tuple: built twice per step."""

    index: np.ndarray              # indices of the active material points (after the lateral quadrature points)
    weights: np.ndarray            # length share [m] times the share below the surface
    slots: np.ndarray              # interpolation tables of the active points (model.interpolation)
    S: np.ndarray
    S_x: np.ndarray
    anchor_points: np.ndarray      # (n, 3) stick anchors on the track
    tangents: np.ndarray           # (n, 3) needle tangents at the points (frozen)
    anchor_depth: np.ndarray       # (n,)
    lateral_stiffness: np.ndarray  # (n,) [N/m^2]
    lateral_damping: np.ndarray    # (n,) [N s/m^2]
    axial: AxialCoefficients       # axial law coefficients (shaft_laws)
    stick_stiffness: float         # k_a [N/m^2]

    @classmethod
    def inactive(cls) -> "_Frozen":
        """No points (shared: never changed in place, like all frozen data)."""
        return _INACTIVE

    @property
    def fields(self) -> tuple:
        """The kernels' form (``advance.FROZEN_FIELDS``)."""
        return (*self[:10], *self.axial, self.stick_stiffness)

    @classmethod
    def from_fields(cls, fields: tuple) -> "_Frozen":
        """From a kernel's frozen part (``advance.FROZEN_FIELDS``); the shared inactive part if it has no points."""
        if fields[1].size == 0:
            return _INACTIVE
        return cls(*fields[:10], AxialCoefficients(*fields[10:15]), fields[15])


_EMPTY = np.zeros(0)
_INACTIVE = _Frozen(np.zeros(0, dtype=int), _EMPTY, np.zeros((0, 4), dtype=np.int64), np.zeros((0, 4)),
                    np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)), _EMPTY, _EMPTY, _EMPTY,
                    AxialCoefficients(_EMPTY, _EMPTY, 0.0, 0.0, 0.0), 1.0)


@njit(cache=True)
def shaft_point_forces(r, v, anchors, tangents, lateral_stiffness, lateral_damping, stick_stiffness, coulomb,
                       viscous, offset, sign_gain, velocity_scale):
    """Force per length on each shaft point and dF/dr, dF/dv: lateral springs and dampers perpendicular to the
    track tangent tau, and the axial traction of ``karnopp.axial_traction`` along it (1 kHz loop: compiled)."""
    n = r.shape[0]
    force = np.zeros((n, 3))
    d_dr = np.zeros((n, 3, 3))
    d_dv = np.zeros((n, 3, 3))
    for k in range(n):
        tau = tangents[k]
        u = offset_dot(r[k], anchors[k], tau)
        v_axial = dot3(v[k], tau)
        t, dt_du, dt_dv = axial_traction(u, v_axial, stick_stiffness, coulomb[k], viscous[k], offset, sign_gain,
                                         velocity_scale)
        for i in range(3):
            force[k, i] = (-lateral_stiffness[k] * (r[k, i] - anchors[k, i] - u * tau[i])
                           - lateral_damping[k] * (v[k, i] - v_axial * tau[i]) + t * tau[i])
            for j in range(3):
                tt = tau[i] * tau[j]
                perpendicular = (1.0 if i == j else 0.0) - tt
                d_dr[k, i, j] = -lateral_stiffness[k] * perpendicular + dt_du * tt
                d_dv[k, i, j] = -lateral_damping[k] * perpendicular + dt_dv * tt
    return force, d_dr, d_dv


@njit(cache=True)
def interpolate_pair(slots, S_a, x_a, S_b, x_b):
    """Two interpolations (k, 3) at interpolation points (model.interpolation): shape functions S_a of
    coordinates x_a (e.g. S of q: positions) and S_b of x_b (e.g. S of q': velocities, S_x of q: gradients)."""
    return interpolate(slots, S_a, x_a), interpolate(slots, S_b, x_b)


@njit(cache=True)
def point_kinematics(q, qd, slots, S):
    """Positions and velocities (k, 3) of interpolation points (model.interpolation) at (q, qd)."""
    return interpolate_pair(slots, S, q, S, qd)


@njit(cache=True)
def shaft_generalized_force(q, qd, slots, S, S_x, weights, anchors, tangents, lateral_stiffness, lateral_damping,
                            stick_stiffness, coulomb, viscous, offset, sign_gain, velocity_scale, Q, band, kl, c_q,
                            c_qd):
    """Kinematics, ``shaft_point_forces`` and assembly of one part's points (ShaftSupport) in one compiled call:
    adds to Q and, unless band is (0, 0) (Q alone), c_q dQ/dq + c_qd dQ/dq' to the band matrix."""
    r, v = point_kinematics(q, qd, slots, S)
    force, d_dr, d_dv = shaft_point_forces(r, v, anchors, tangents, lateral_stiffness, lateral_damping,
                                           stick_stiffness, coulomb, viscous, offset, sign_gain, velocity_scale)
    assemble_point_forces(slots, S, S_x, weights, force, d_dr, _NO_GRADIENT, d_dv, Q, band, kl, c_q, c_qd)


@njit(cache=True)
def shaft_arguments(part):
    """``shaft_generalized_force``'s arguments slots ... velocity_scale of a frozen part (``advance.FROZEN_FIELDS``)."""
    return (part[2], part[3], part[4], part[1], part[5], part[6], part[8], part[9], part[15], part[10], part[11],
            part[12], part[13], part[14])


@njit(cache=True)
def shaft_forces_assembly(q, qd, lateral, axial, Q, band, kl, c_q, c_qd):
    """``shaft_generalized_force`` of the lateral, then the axial part (``ShaftForces``: each part's arguments
    slots ... velocity_scale as a tuple) in one compiled call."""
    shaft_generalized_force(q, qd, *lateral, Q, band, kl, c_q, c_qd)
    shaft_generalized_force(q, qd, *axial, Q, band, kl, c_q, c_qd)


@njit(cache=True)
def needle_points(S, S_x, slots, q):
    """Positions (k, 3) and unit tangents (k, 3) of the needle at interpolation points (model.interpolation)."""
    r, tangents = interpolate_pair(slots, S, q, S_x, q)
    for p in range(slots.shape[0]):
        norm = np.sqrt(tangents[p, 0] * tangents[p, 0] + tangents[p, 1] * tangents[p, 1]
                       + tangents[p, 2] * tangents[p, 2])
        for i in range(3):
            tangents[p, i] /= norm
    return r, tangents


@njit(cache=True)
def cut_quadrature(node_arc, element_lengths, lower, upper, xi, w):
    """Gauss points (xi, w on [-1, 1]) on each element's share of the arc interval [lower, upper]: weights (m,) [m],
    q slots (m, 4), S and S_x (m, 4) of eq. 4."""
    starts = np.maximum(node_arc[:-1], lower)
    ends = np.minimum(node_arc[1:], upper)
    cut = np.flatnonzero(ends > starts)
    m = cut.size * xi.size
    weights, local, lengths = np.empty(m), np.empty(m), np.empty(m)
    slots = np.empty((m, 4), dtype=np.int64)
    k = 0
    for e in cut:
        half, middle = 0.5 * (ends[e] - starts[e]), 0.5 * (ends[e] + starts[e])
        for g in range(xi.size):
            weights[k] = half * w[g]
            lengths[k] = element_lengths[e]
            local[k] = 2.0 * (middle + half * xi[g] - node_arc[e]) / element_lengths[e] - 1.0
            for a in range(4):
                slots[k, a] = 2 * e + a
            k += 1
    S, S_x, S_xx = np.empty((m, 4)), np.empty((m, 4)), np.empty((m, 4))
    hermite_shapes(local, lengths, S, S_x, S_xx)
    return weights, slots, S, S_x


@njit(cache=True)
def entry_coverage(arc_lengths, depth, inside):
    """Share of each shaft point's length (trapezoid segment) that lies below the entry surface, for consecutive
    points (base to tip) with their depths and inside flags.

    Interior inside points count fully; an inside point whose outer neighbour is still outside takes the inserted
    length from the crossing of the surface (interpolated between the two) to its segment's inner end, so the
    weights sum to the inserted length without jumps as points enter one by one.  (The first point of the list
    is taken as interior.)"""
    n = arc_lengths.size
    coverage = np.zeros(n)
    for k in range(n):
        if not inside[k]:
            continue
        coverage[k] = 1.0
        if k > 0 and not inside[k - 1]:
            s, s_out = arc_lengths[k], arc_lengths[k - 1]
            crossing = s - (s - s_out) * depth[k] / max(depth[k] - depth[k - 1], 1e-300)
            upper = 0.5 * (s + arc_lengths[k + 1]) if k + 1 < n else s
            coverage[k] = (upper - crossing) / (upper - 0.5 * (s + s_out))
    return coverage


@njit(cache=True)
def lateral_quadrature(q, node_arc, element_lengths, s_tip, xi, w, vertices, arc, end_tangent, entry_point,
                       entry_normal):
    """Gauss points of the needle's arc interval in cut tissue (``advance.lateral_part``): weights,
    slots, S, S_x (``cut_quadrature``), the rest points on the track (each needle point's projection), the needle
    tangents and the rest points' depths; none if the interval is empty."""
    centres, radii = segment_blocks(vertices, arc)
    tip_coordinate = project_on_blocks(vertices, arc, end_tangent, q[-6:-3].reshape(1, 3), centres, radii)[0][0]
    upper = s_tip - max(tip_coordinate - arc[-1], 0.0)
    lower = max(s_tip - tip_coordinate, 0.0)
    weights, slots, S, S_x = cut_quadrature(node_arc, element_lengths, lower, upper, xi, w)
    r, tangents = needle_points(S, S_x, slots, q)
    coordinate = np.maximum(project_on_blocks(vertices, arc, end_tangent, r, centres, radii)[0], 0.0)
    points = locate_on_polyline(vertices, arc, end_tangent, coordinate)[0]
    depth = np.empty(weights.size)
    for k in range(weights.size):
        depth[k] = ((points[k, 0] - entry_point[0]) * entry_normal[0] + (points[k, 1] - entry_point[1])
                    * entry_normal[1] + (points[k, 2] - entry_point[2]) * entry_normal[2])
    return weights, slots, S, S_x, points, tangents, depth


@njit(cache=True)
def shaft_contact_points(q, arc_lengths, candidate_arc, S, S_x, slots, entry_point, entry_normal, thickness,
                         was_active, active, anchor, vertices, arc, end_tangent):
    """The shaft points beyond the arc length ``candidate_arc`` inside the tissue (``ShaftSupport.advance``):
    marks them in ``active``, anchors the entering ones (not in ``was_active``) at their projection on the track,
    and returns their indices, entry coverage, needle tangents, anchor points on the track and those points'
    depths, and the axial offsets u = (r - anchor point) . tangent."""
    candidates = np.flatnonzero(arc_lengths > candidate_arc)
    r, tangents = needle_points(S[candidates], S_x[candidates], slots[candidates], q)
    depth = np.empty(candidates.size)
    for k in range(candidates.size):
        depth[k] = ((r[k, 0] - entry_point[0]) * entry_normal[0] + (r[k, 1] - entry_point[1]) * entry_normal[1]
                    + (r[k, 2] - entry_point[2]) * entry_normal[2])
    inside = (depth > 0.0) & (depth < thickness)
    coverage = entry_coverage(arc_lengths[candidates], depth, inside)[inside]
    index, r, tangents = candidates[inside], r[inside], tangents[inside]
    active[index] = True
    entering = ~was_active[index]
    if np.any(entering):                                 # an entering point anchors where it is
        anchor[index[entering]] = project_on_polyline(vertices, arc, end_tangent, r[entering])[0]
    points = locate_on_polyline(vertices, arc, end_tangent, np.maximum(anchor[index], 0.0))[0]
    point_depth = np.empty(index.size)
    u = np.empty(index.size)
    for k in range(index.size):
        point_depth[k] = ((points[k, 0] - entry_point[0]) * entry_normal[0] + (points[k, 1] - entry_point[1])
                          * entry_normal[1] + (points[k, 2] - entry_point[2]) * entry_normal[2])
        u[k] = ((r[k, 0] - points[k, 0]) * tangents[k, 0] + (r[k, 1] - points[k, 1]) * tangents[k, 1]
                + (r[k, 2] - points[k, 2]) * tangents[k, 2])
    return index, coverage, tangents, points, point_depth, u


@njit(cache=True)
def slip_anchors(anchor, index, u, coulomb, stick_stiffness, points, tangents, weights, coverage, slots, S, S_x):
    """Plastic slip of the active points' anchors along the track (``ShaftSupport.advance``): each anchor (track
    coordinate) and anchor point slides by the part of the axial offset u beyond the stick band C / k_a (the point
    stays on the same segment to first order; relocated next step). Returns the points' weights (length share times
    coverage) and interpolation tables."""
    for k in range(index.size):
        band = coulomb[k] / stick_stiffness
        held = u[k] if u[k] > -band else -band
        held = held if held < band else band
        slip = u[k] - held
        anchor[index[k]] += slip
        for i in range(3):
            points[k, i] += slip * tangents[k, i]
    return weights[index] * coverage, slots[index], S[index], S_x[index]


@njit(cache=True)
def first_slot_in(slots, slot):
    """Whether a point's first slot (its element's first node slot) is ``slot``."""
    for k in range(slots.shape[0]):
        if slots[k, 0] == slot:
            return True
    return False


class ShaftState(NamedTuple):
    """The shaft points' state (part of the tissue state): the track coordinate of each point's stick anchor (k,),
    which points are inside the tissue (k,) and the axial law's own state (LuGre z [m]; None)."""

    anchor: np.ndarray
    active: np.ndarray
    law: object


class ShaftForces(ElementLocalForce):
    """The shaft's lateral and axial point forces over one step (``ShaftSupport.advance``): the lateral
    quadrature points and the active material points with their rest points, anchors, tangents and law
    coefficients frozen at the step's start (explicit in the hook, implicit in the forces)."""

    state_dependent = True
    time_invariant = False
    stateful = False

    def __init__(self, lateral: _Frozen, axial: _Frozen) -> None:
        self.parts = (lateral, axial)

    @cached_property
    def _arguments(self) -> tuple:
        """The point-force kernel's arguments of both parts (made at the first evaluation: a compiled run of
        steps never evaluates these objects, it takes the parts' fields)."""
        return tuple(shaft_arguments.py_func(fz.fields) for fz in self.parts)

    def __getstate__(self) -> dict:
        return {"parts": self.parts}  # the arguments are a cache, not state

    @staticmethod
    def _kinematics(fz: _Frozen, q, qd):
        """Positions and velocities (k, 3) of a part's points."""
        return point_kinematics(q, qd, fz.slots, fz.S)

    @staticmethod
    def _law(fz: _Frozen, r, v):
        """Force per unit length (k, 3) on a part's points and dF/dr, dF/dv (k, 3, 3) (anchors frozen)."""
        return shaft_point_forces(r, v, fz.anchor_points, fz.tangents, fz.lateral_stiffness, fz.lateral_damping,
                                  fz.stick_stiffness, *fz.axial)

    def assemble_banded(self, model, q, qd, t, base, band, kl, c_q, c_qd) -> np.ndarray:
        """Both parts' generalized forces and Jacobian blocks (one compiled kernel call)."""
        Q = np.zeros(q.size)
        shaft_forces_assembly(q, qd, *self._arguments, Q, band, kl, c_q, c_qd)
        return Q

    def touches_element(self, model, element: int) -> bool:
        """Whether a lateral or axial point of this step lies in ``element`` (slots 2 e ... 2 e + 3)."""
        return any(first_slot_in(fz.slots, 2 * element) for fz in self.parts)

    def total_force(self, model, q, qd, t, base) -> np.ndarray:
        """World resultant [N] of the shaft forces at (q, qd)."""
        return sum((fz.weights @ self._law(fz, *self._kinematics(fz, q, qd))[0] for fz in self.parts
                    if fz.weights.size), np.zeros(3))

    def resultants(self, model, state, base) -> tuple[np.ndarray, np.ndarray]:
        """No force on the tip; the shaft forces' resultant on the needle."""
        return np.zeros(3), self.total_force(model, state.q, state.qd, state.t, base)

    def elastic_energy(self, model, q) -> float:
        """Energy [J] stored in the lateral springs and the sticking axial anchors (stick band |u| <= C/k_a)."""
        energy = 0.0
        for fz in self.parts:
            if fz.weights.size:
                offset = self._kinematics(fz, q, np.zeros_like(q))[0] - fz.anchor_points
                u = np.einsum("ki,ki->k", offset, fz.tangents)
                density = 0.5 * fz.lateral_stiffness * np.sum((offset - u[:, None] * fz.tangents) ** 2, axis=1)
                band = fz.axial.coulomb / fz.stick_stiffness
                density = density + 0.5 * fz.stick_stiffness * np.clip(u, -band, band) ** 2
                energy += float(fz.weights @ density)
        return energy


NO_SHAFT_FORCES = ShaftForces(_Frozen.inactive(), _Frozen.inactive())  # shared: never changed


class ShaftSupport:
    """Winkler lateral support over the cut tissue and an axial stick-slip law on shaft points along the needle
    (immutable; the points' state is a :class:`ShaftState`).

    Lateral (``lateral``: per-layer ``lateral_stiffness``, ``lateral_damping`` per unit length): springs and
    dampers perpendicular to the track on the needle's arc interval lying in tissue the tip has already cut (path
    memory), integrated with LATERAL_GAUSS_POINTS Gauss points on each element's share of that interval, so the
    support is exact from the first cut millimetre on, whatever the shaft point spacing.
    Axial (``axial_law``: one of ``shaft_laws``, or None for none): on the material shaft points at
    ``arc_lengths`` (k,), base to tip, with length shares ``weights`` (k,) [m], each anchored to the track once
    inside the tissue (stick-slip); without a law the needle slides freely.  Both are assembled with the model's
    point-force kernel over the points inside the tissue only, so the cost grows with the inserted length.
    ``advance.advance_shaft`` advances a ``ShaftState`` with ``kernel_arguments``.
    """

    def __init__(self, model, block: TissueBlock, arc_lengths: np.ndarray, weights: np.ndarray, lateral: bool,
                 axial_law: ShaftLaw | None = None) -> None:
        self.block = block
        self.arc_lengths = np.asarray(arc_lengths, dtype=float)
        self.weights = np.asarray(weights, dtype=float)
        if np.any(np.diff(self.arc_lengths) <= 0) or self.weights.shape != self.arc_lengths.shape:
            raise ValueError("ShaftSupport: arc_lengths must increase and match weights")
        self.lateral = lateral
        self.axial_law = axial_law or ShaftLaw()
        k = self.arc_lengths.size
        self.initial = ShaftState(np.zeros(k), np.zeros(k, dtype=bool), self.axial_law.initial_state)
        margin = 2.0 * float(np.max(np.diff(self.arc_lengths), initial=0.0))
        table = model.interpolation(self.arc_lengths)
        law = self.axial_law
        self.kernel_arguments = (self.arc_lengths, self.weights, margin, table.S, table.S_x, table.slots,
                                 bool(lateral), law.kind, law.parameters, float(law.stick_stiffness),
                                 block.entry_point, block.entry_normal, *block.kernel_tables,
                                 model.mesh.node_arc_length, model.mesh.element_lengths, _GAUSS_XI, _GAUSS_W)


class BevelTipForce(TipForce):
    """Seed 001 eqs. 4-5 at the tip over one step: F = K_T (-P1 t + Q1 n) with P1, Q1 the forces of ``unit_bevel``
    per unit K_T, ``scale`` K_T of the tip's layer times the bevel's embedded share (0: not engaged), n the bevel side
    ``side_base`` (base frame, unit) rolled with the base orientation."""

    def __init__(self, unit_bevel: BevelTip, side_base: np.ndarray, scale: float) -> None:
        self.unit_bevel = unit_bevel
        self.side_base = side_base
        self.scale = scale

    def tip_force(self, q, base) -> tuple[np.ndarray, np.ndarray]:
        """World tip force [N] and dF/dr_x (3, 3) at coordinates q."""
        if self.scale == 0.0:
            return np.zeros(3), np.zeros((3, 3))
        force, jacobian = self.unit_bevel.tip_force(tip_coordinates(q)[1], base.rotation @ self.side_base)
        return self.scale * force, self.scale * jacobian

    def tip_force_at(self, q, qd, base) -> np.ndarray:
        return self.tip_force(q, base)[0]

    def assemble_banded(self, model, q, qd, t, base, band, kl, c_q, c_qd) -> np.ndarray:
        Q = np.zeros(q.size)
        unit = self.unit_bevel
        if self.scale != 0.0 and not bevel_tip_assembly(q, base.rotation, self.side_base, unit.axial_force,
                                                        unit.transverse_force, self.scale, Q, band, kl, c_q, c_qd):
            raise ValueError(SIDE_ALONG_TANGENT)
        return Q


class TipResistance(TipForce):
    """Seed 002 at the tip over one step: capsule stiffness before puncture, cutting force F_c while cutting.

    The capsule force -(a1 x + a2 x^2) n (x = tip depth, n = entry normal) is elastic.  The cutting force
    -F_c clip(v_t / v_c, 0, 1) t resists only forward motion of the tip at the cut front (t tip tangent,
    v_t its axial speed, ``cutting_speed_scale`` v_c regularises the onset), so it never adds energy.
    """

    def __init__(self, block: TissueBlock, profile: InsertionForceProfile, cutting_speed_scale: float,
                 punctured: bool, cutting: bool) -> None:
        self.block = block
        self.profile = profile
        self.cutting_speed_scale = cutting_speed_scale
        self.punctured = punctured
        self.cutting = cutting

    def tip_force(self, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """World tip force and its derivatives with respect to the tip r, r_x and velocity."""
        zero = np.zeros((3, 3))
        if not self.punctured:
            profile, block = self.profile, self.block
            force, d_dr = capsule_force(np.ascontiguousarray(q[-6:-3]), block.entry_point, block.entry_normal,
                                        profile.a1, profile.a2)
            return force, d_dr, zero, zero
        if not self.cutting:
            return np.zeros(3), zero, zero, zero
        force, d_drx, d_dv = cutting_force(np.ascontiguousarray(q[-3:]), np.ascontiguousarray(qd[-6:-3]),
                                           self.profile.cutting_force, self.cutting_speed_scale)
        return force, zero, d_drx, d_dv

    def tip_force_at(self, q, qd, base) -> np.ndarray:
        return self.tip_force(q, qd)[0]

    def assemble_banded(self, model, q, qd, t, base, band, kl, c_q, c_qd) -> np.ndarray:
        Q = np.zeros(q.size)
        profile, block = self.profile, self.block
        tip_resistance_assembly(q, qd, self.punctured, self.cutting, block.entry_point, block.entry_normal,
                                profile.a1, profile.a2, profile.cutting_force, self.cutting_speed_scale, Q, band, kl,
                                c_q, c_qd)
        return Q
