"""Coupling of the tissue laws to the ANCF needle: ``TissueContact`` (the block, capsule puncture, track spacing)
and ``ShaftSupport`` (Winkler lateral support over the cut tissue, an axial stick-slip law of ``shaft_laws`` on
shaft points), with the shaft's compiled point-force and contact-point kernels (the contributions themselves:
``contact``, ``shaft_force``, ``tip_forces``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.model.forces import scatter_point
from needle_sim_ros.model.kinematics import dot3, offset_dot
from needle_sim_ros.model.mesh import hermite_shapes, interpolate, search_right
from needle_sim_ros.model.outputs import unit_tangents

from .geometry import TissueBlock
from .karnopp import axial_traction
from .shaft_laws import ShaftLaw
from .track import locate_on_polyline, project_on_blocks


class TissueContact:
    """How the needle meets the tissue (immutable): the block, the track spacing [m], and ``puncture_depth``: the
    depth [m] the tip must reach before the capsule tears and the track starts (seed 002 d1; None: the tissue is cut
    from first contact). ``contact.advance_contact`` advances its record (``contact.ContactRecord``)."""

    def __init__(self, block: TissueBlock, spacing: float, puncture_depth: float | None = None) -> None:
        if not spacing > 0.0:
            raise ValueError(f"tissue.track.spacing must be > 0, got {spacing!r}")
        self.block = block
        self.spacing = spacing
        self.puncture_depth = puncture_depth


LATERAL_GAUSS_POINTS = 3
_GAUSS_XI, _GAUSS_W = np.polynomial.legendre.leggauss(LATERAL_GAUSS_POINTS)


# the columns of a shaft point in the table the assembly reads (``shaft_force.shaft_acting``)
WEIGHT, SHAPES, GRADIENT_SHAPES, ANCHOR, TANGENT = 0, 1, 5, 9, 12  # S and S_x: 4 columns, anchor and tangent: 3
STIFFNESS, DAMPING, COULOMB, VISCOUS, OFFSET, SIGN_GAIN, VELOCITY_SCALE, STICK_STIFFNESS = range(15, 23)
POINT_COLUMNS = 23


@njit(cache=True)
def shaft_generalized_force(q, qd, slots, points, Q, band, kl, c_q, c_qd):
    """The shaft points' force per length (``points``: their table rows, columns above; ``slots``: their q slots) added
    to Q and, unless band is (0, 0), c_q dQ/dq + c_qd dQ/dq' to the band, in one pass without per-point temporaries:
    lateral springs and dampers perpendicular to the track tangent tau and ``karnopp.axial_traction`` along it, at
    each point's r and v (eq. 3), scattered by ``model.forces.scatter_point`` (dF/dr, dF/dv, no dF/dr_x)."""
    with_matrix = band.shape[0] > 0
    S, S_x = points[:, SHAPES:SHAPES + 4], points[:, GRADIENT_SHAPES:GRADIENT_SHAPES + 4]
    r, v, force = np.empty(3), np.empty(3), np.empty(3)
    position = np.empty((3, 3))  # c_q dF/dr + c_qd dF/dv of the point
    for k in range(slots.shape[0]):
        r[:] = 0.0
        v[:] = 0.0
        for a in range(4):
            first = 3 * slots[k, a]
            for i in range(3):
                r[i] += S[k, a] * q[first + i]
                v[i] += S[k, a] * qd[first + i]
        p = points[k]
        tau = p[TANGENT:TANGENT + 3]
        u = offset_dot(r, p[ANCHOR:ANCHOR + 3], tau)
        v_axial = dot3(v, tau)
        stiffness, damping = p[STIFFNESS], p[DAMPING]
        t, dt_du, dt_dv = axial_traction(u, v_axial, p[STICK_STIFFNESS], p[COULOMB], p[VISCOUS], p[OFFSET],
                                         p[SIGN_GAIN], p[VELOCITY_SCALE])
        for i in range(3):
            force[i] = (-stiffness * (r[i] - p[ANCHOR + i] - u * tau[i]) - damping * (v[i] - v_axial * tau[i])
                        + t * tau[i])
            if with_matrix:
                for j in range(3):
                    tt = tau[i] * tau[j]
                    perpendicular = (1.0 if i == j else 0.0) - tt
                    position[i, j] = (c_q * (-stiffness * perpendicular + dt_du * tt)
                                      + c_qd * (-damping * perpendicular + dt_dv * tt))
        scatter_point(slots, S, S_x, k, p[WEIGHT], force, position, position, False, Q, band, kl, c_q)


@njit(cache=True)
def point_table(weights, S, S_x, anchors, tangents, stiffness, damping, coulomb, viscous, offset, sign_gain,
                velocity_scale, stick_stiffness):
    """The frozen points' rows of the table ``shaft_generalized_force`` reads (columns above)."""
    points = np.empty((weights.size, POINT_COLUMNS))
    for k in range(weights.size):  # scalar loops: it runs every step
        points[k, WEIGHT], points[k, STIFFNESS], points[k, DAMPING] = weights[k], stiffness[k], damping[k]
        points[k, COULOMB], points[k, VISCOUS], points[k, OFFSET] = coulomb[k], viscous[k], offset
        points[k, SIGN_GAIN], points[k, VELOCITY_SCALE] = sign_gain, velocity_scale
        points[k, STICK_STIFFNESS] = stick_stiffness
        for a in range(4):
            points[k, SHAPES + a], points[k, GRADIENT_SHAPES + a] = S[k, a], S_x[k, a]
        for i in range(3):
            points[k, ANCHOR + i], points[k, TANGENT + i] = anchors[k, i], tangents[k, i]
    return points


@njit(cache=True)
def needle_points(S, S_x, slots, q):
    """Positions (k, 3) and unit tangents (k, 3) of the needle at interpolation points (model.interpolation)."""
    return interpolate(slots, S, q), unit_tangents(S_x, slots, q)


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
    """Share of each shaft point's length (trapezoid segment) below the entry surface, for consecutive points (base to
    tip) with their depths and inside flags: an inside point whose outer neighbour is outside takes the length from the
    surface crossing (interpolated) to its segment's inner end, so the weights sum to the inserted length without jumps
    as points enter (the first point counts as interior)."""
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
def lateral_quadrature(q, node_arc, element_lengths, s_tip, xi, w, vertices, arc, end_tangent, centres, radii,
                       entry_point, entry_normal):
    """Gauss points of the needle's arc interval in cut tissue (``shaft_force.lateral_part``): weights, slots, S, S_x
    (``cut_quadrature``), the rest points on the track (each needle point's projection), the needle tangents and the
    rest points' depths; none if the interval is empty. ``centres``, ``radii``: the track's ``track.segment_blocks``."""
    tip_coordinate = project_on_blocks(vertices, arc, end_tangent, q[-6:-3].reshape(1, 3), centres, radii)[0][0]
    upper = s_tip - max(tip_coordinate - arc[-1], 0.0)
    lower = max(s_tip - tip_coordinate, 0.0)
    weights, slots, S, S_x = cut_quadrature(node_arc, element_lengths, lower, upper, xi, w)
    r, tangents = needle_points(S, S_x, slots, q)
    coordinate = np.maximum(project_on_blocks(vertices, arc, end_tangent, r, centres, radii)[0], 0.0)
    points = locate_on_polyline(vertices, arc, end_tangent, coordinate)[0]
    depth = np.empty(weights.size)
    for k in range(weights.size):
        depth[k] = offset_dot(points[k], entry_point, entry_normal)
    return weights, slots, S, S_x, points, tangents, depth


@njit(cache=True)
def shaft_contact_points(q, arc_lengths, candidate_arc, S, S_x, slots, entry_point, entry_normal, thickness,
                         was_active, active, anchor, vertices, arc, end_tangent, centres, radii):
    """The shaft points beyond the arc length ``candidate_arc`` inside the tissue (``ShaftSupport.advance``), marked in
    ``active``, the entering ones (not ``was_active``) anchored at their projection on the track: their indices, entry
    coverage, needle tangents, anchor points and those points' depths, and the axial offsets u = (r - anchor) . tangent
    (scalar loops: it runs every step); ``centres``, ``radii``: the track's ``track.segment_blocks``."""
    first = search_right(arc_lengths, candidate_arc)
    r, tangents = needle_points(S[first:], S_x[first:], slots[first:], q)
    m = r.shape[0]
    depth = np.empty(m)
    inside = np.empty(m, dtype=np.bool_)
    count = 0
    for k in range(m):
        depth[k] = offset_dot(r[k], entry_point, entry_normal)
        inside[k] = depth[k] > 0.0 and depth[k] < thickness
        count += inside[k]
    covered = entry_coverage(arc_lengths[first:], depth, inside)
    index, coverage = np.empty(count, dtype=np.int64), np.empty(count)
    entering = 0
    j = 0
    for k in range(m):  # the inside points' rows moved up in place (j <= k)
        if inside[k]:
            index[j], coverage[j] = first + k, covered[k]
            for i in range(3):
                r[j, i], tangents[j, i] = r[k, i], tangents[k, i]
            active[first + k] = True
            entering += not was_active[first + k]
            j += 1
    if entering:                                         # an entering point anchors where it is
        new = np.empty((entering, 3))
        e = 0
        for j in range(count):
            if not was_active[index[j]]:
                new[e] = r[j]
                e += 1
        projected = project_on_blocks(vertices, arc, end_tangent, new, centres, radii)[0]
        e = 0
        for j in range(count):
            if not was_active[index[j]]:
                anchor[index[j]] = projected[e]
                e += 1
    held = np.empty(count)
    for j in range(count):
        held[j] = max(anchor[index[j]], 0.0)
    points = locate_on_polyline(vertices, arc, end_tangent, held)[0]
    point_depth = np.empty(count)
    u = np.empty(count)
    for k in range(count):
        point_depth[k] = offset_dot(points[k], entry_point, entry_normal)
        u[k] = offset_dot(r[k], points[k], tangents[k])
    return index, coverage, tangents[:count], points, point_depth, u


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


class ShaftSupport:
    """Winkler lateral support over the cut tissue and an axial stick-slip law on shaft points (immutable; the points'
    state is a ``shaft_force.ShaftRecord``, advanced by ``shaft_force.advance_shaft`` with ``kernel_arguments``).

    Lateral (per-layer ``lateral_stiffness``, ``lateral_damping`` per unit length): springs and dampers perpendicular
    to the track on the needle's arc interval in already cut tissue (path memory), LATERAL_GAUSS_POINTS Gauss points
    on each element's share of it, exact from the first cut millimetre whatever the point spacing.
    Axial (``axial_law``: one of ``shaft_laws``, None: slides freely): on the material points at ``arc_lengths`` (k,),
    base to tip, with length shares ``weights`` (k,) [m], each anchored to the track once inside (stick-slip).
    Both use the model's point-force kernel over the points inside the tissue only (cost grows with the depth)."""

    def __init__(self, model, block: TissueBlock, arc_lengths: np.ndarray, weights: np.ndarray, lateral: bool,
                 axial_law: ShaftLaw | None = None) -> None:
        self.block = block
        self.arc_lengths = np.asarray(arc_lengths, dtype=float)
        self.weights = np.asarray(weights, dtype=float)
        if np.any(np.diff(self.arc_lengths) <= 0) or self.weights.shape != self.arc_lengths.shape:
            raise ValueError("ShaftSupport: arc_lengths must increase and match weights")
        self.lateral = lateral
        self.axial_law = axial_law or ShaftLaw()
        margin = 2.0 * float(np.max(np.diff(self.arc_lengths), initial=0.0))
        table = model.interpolation(self.arc_lengths)
        law = self.axial_law
        self.kernel_arguments = (self.arc_lengths, self.weights, margin, table.S, table.S_x, table.slots,
                                 bool(lateral), law.kind, law.parameters, float(law.stick_stiffness),
                                 block.entry_point, block.entry_normal, *block.kernel_tables,
                                 model.mesh.node_arc_length, model.mesh.element_lengths, _GAUSS_XI, _GAUSS_W)
