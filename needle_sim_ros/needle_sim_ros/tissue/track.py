"""The track cut by the advancing needle tip: a polyline in the world frame, parameterised by its arc length.

Path memory (seed 001 Sec. II, Glozman & Shoham's virtual springs): the track starts where the tip crossed the entry
surface and, whenever the tip has advanced ``spacing`` beyond its end, grows a vertex on the tip's path, interpolated
at the exact crossing so the track depends continuously on the motion (docs/design_notes.md). Tissue beyond the end
is uncut and holds nothing laterally; retracting leaves the track, so a re-insertion follows it past its end.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.model.kinematics import dot3, offset_dot
from needle_sim_ros.model.mesh import search_right


END_CHORD_SEGMENTS = 10  # segments over which the end tangent is taken (1 mm at the default 0.1 mm spacing)


@njit(cache=True)
def chord_tangent(vertices, direction):
    """Direction of the cut at the end: the chord over the last ``END_CHORD_SEGMENTS`` segments (``direction``
    while there is none; why not one segment: docs/design_notes.md)."""
    count = vertices.shape[0]
    if count < 2:
        return direction
    d = vertices[count - 1] - vertices[max(count - 1 - END_CHORD_SEGMENTS, 0)]
    return d / np.sqrt(dot3(d, d))


@njit(cache=True)
def cut_polyline(vertices, arc, end_tangent, previous, tip, spacing):
    """The track (vertices, arc lengths, end tangent) grown from the previous tip position toward ``tip`` while the
    tip is ``spacing`` or more beyond its end, a vertex where that path crosses ``spacing`` ahead of the end; beyond
    the end a point's coordinate is length + (point - end) . end_tangent (uncut tissue)."""
    while True:
        count = arc.size
        length = arc[count - 1]
        end = vertices[count - 1]
        ahead = length + offset_dot(tip, end, end_tangent) - length
        if not ahead >= spacing:
            return vertices, arc, end_tangent
        behind = length + offset_dot(previous, end, end_tangent) - length
        fraction = (spacing - behind) / (ahead - behind) if behind < spacing else 0.0
        previous = previous + fraction * (tip - previous)
        step = previous - end
        grown, grown_arc = np.empty((count + 1, 3)), np.empty(count + 1)
        grown[:count], grown_arc[:count] = vertices, arc
        grown[count], grown_arc[count] = previous, length + np.sqrt(dot3(step, step))
        vertices, arc = grown, grown_arc
        end_tangent = chord_tangent(vertices, end_tangent)


PROJECTION_BLOCK = 16  # segments per bounding sphere of ``project_on_polyline``'s search


@njit(cache=True)
def segment_blocks(vertices, arc):
    """Bounding spheres (centres (b, 3), radii (b,)) of the polyline's segments in blocks of PROJECTION_BLOCK,
    radii widened by far more than the rounding of the distances they bound."""
    segments = arc.size - 1
    blocks = (segments + PROJECTION_BLOCK - 1) // PROJECTION_BLOCK
    centres, radii = np.empty((blocks, 3)), np.empty(blocks)
    for b in range(blocks):
        first, last = b * PROJECTION_BLOCK, min((b + 1) * PROJECTION_BLOCK, segments)
        radius = 0.0
        for i in range(3):
            centres[b, i] = 0.5 * (vertices[first, i] + vertices[last, i])
        for j in range(first, last + 1):
            d2 = 0.0
            for i in range(3):
                d2 += (vertices[j, i] - centres[b, i]) ** 2
            radius = max(radius, d2)
        radii[b] = np.sqrt(radius) * (1.0 + 1e-9) + 1e-12
    return centres, radii


@njit(cache=True)
def project_on_polyline(vertices, arc, end_tangent, points):
    """Closest coordinate (k,) and distance (k,) of points on the polyline (vertices, cumulative arc) and on its
    straight continuation beyond the end along end_tangent: the first closest in the order continuation, then
    segments base to tip (``project_on_blocks`` with the polyline's ``segment_blocks``)."""
    return project_on_blocks(vertices, arc, end_tangent, points, *segment_blocks(vertices, arc))


@njit(cache=True)
def project_on_blocks(vertices, arc, end_tangent, points, centres, radii):
    """``project_on_polyline`` with the polyline's ``segment_blocks``: blocks whose bounding sphere lies beyond an
    upper bound of the closest distance (the continuation's and the nearest block's vertices') are skipped, so the
    result is the full scan's at a cost growing with the block count only. Distances compared squared."""
    count = arc.size
    n = points.shape[0]
    coordinate = np.empty(n)
    distance = np.empty(n)
    end = vertices[count - 1]
    blocks = radii.size
    centre_distance2 = np.empty(blocks)
    for k in range(n):
        p = points[k]
        beyond = max(offset_dot(p, end, end_tangent), 0.0)
        best, best_coordinate = 0.0, arc[count - 1] + beyond
        for i in range(3):
            d = p[i] - end[i] - beyond * end_tangent[i]
            best += d * d
        nearest, nearest_distance2 = -1, np.inf
        for b in range(blocks):
            d2 = 0.0
            for i in range(3):
                d2 += (p[i] - centres[b, i]) ** 2
            centre_distance2[b] = d2
            if d2 < nearest_distance2:
                nearest, nearest_distance2 = b, d2
        bound = best
        if nearest >= 0:
            for j in range(nearest * PROJECTION_BLOCK, min((nearest + 1) * PROJECTION_BLOCK, count - 1) + 1):
                d2 = 0.0
                for i in range(3):
                    d2 += (p[i] - vertices[j, i]) ** 2
                bound = min(bound, d2)
        reach = np.sqrt(bound * (1.0 + 1e-9) + 1e-24)
        for b in range(blocks):
            if centre_distance2[b] > (radii[b] + reach) ** 2:
                continue
            for j in range(b * PROJECTION_BLOCK, min((b + 1) * PROJECTION_BLOCK, count - 1)):
                length2 = 0.0
                along = 0.0
                for i in range(3):
                    length2 += (vertices[j + 1, i] - vertices[j, i]) ** 2
                    along += (p[i] - vertices[j, i]) * (vertices[j + 1, i] - vertices[j, i])
                fraction = min(max(along / length2, 0.0), 1.0) if length2 > 0.0 else 0.0
                d2 = 0.0
                for i in range(3):
                    d = p[i] - vertices[j, i] - fraction * (vertices[j + 1, i] - vertices[j, i])
                    d2 += d * d
                if d2 < best:
                    best, best_coordinate = d2, arc[j] + fraction * (arc[j + 1] - arc[j])
        coordinate[k] = best_coordinate
        distance[k] = np.sqrt(best)
    return coordinate, distance


@njit(cache=True)
def locate_on_polyline(vertices, arc, end_tangent, s):
    """Interpolate the polyline (vertices, cumulative arc) at coordinates s; straight beyond the end."""
    n = s.size
    points = np.empty((n, 3))
    tangents = np.empty((n, 3))
    count = arc.size
    end = vertices[count - 1]
    for k in range(n):
        if count >= 2 and s[k] < arc[count - 1]:
            j = min(max(search_right(arc, s[k]) - 1, 0), count - 2)
            seg = arc[j + 1] - arc[j]
            fraction = (s[k] - arc[j]) / seg
            for i in range(3):
                d = vertices[j + 1, i] - vertices[j, i]
                points[k, i] = vertices[j, i] + fraction * d
                tangents[k, i] = d / seg
        else:
            for i in range(3):
                points[k, i] = end[i] + (s[k] - arc[count - 1]) * end_tangent[i]
                tangents[k, i] = end_tangent[i]
    return points, tangents
