"""Distance of points to a needle centerline given as a polyline, and the arc length of the closest point.

Between samples r_i = r(s_i) the centerline is the chord: the closest point on segment i to p is r_i + t d_i,
t = clip(((p - r_i) . d_i) / |d_i|^2, 0, 1), at arc length s_i + t (s_{i+1} - s_i). The chord differs from the
smooth curve by at most the sagitta kappa h^2 / 8 (curvature kappa, sample spacing h).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Point-segment pairs per block: the (points x segments) work arrays stay around 8 MB each.
_PAIRS_PER_BLOCK = 1_000_000


@dataclass(frozen=True)
class ClosestPoints:
    """Per query point: distance [m] to the polyline, closest point (m, 3) [m] and its arc length [m]."""

    distance: np.ndarray
    point: np.ndarray
    arc_length: np.ndarray


def chord_arc_length(vertices: np.ndarray) -> np.ndarray:
    """Cumulative chord length [m] along a polyline, 0 at the first vertex."""
    steps = np.linalg.norm(np.diff(vertices, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def closest_points_on_polyline(points: np.ndarray, vertices: np.ndarray,
                               vertex_arc_length: np.ndarray | None = None) -> ClosestPoints:
    """Closest points on the polyline ``vertices`` (n, 3) to each of ``points`` (m, 3), vectorized over both;
    ``vertex_arc_length`` (n,) parameterizes it (default: chord length), interpolated linearly within a segment. A
    single vertex is a degenerate polyline (a point)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=float).reshape(-1, 3)
    if len(vertices) == 0:
        raise ValueError("polyline needs at least one vertex")
    s = chord_arc_length(vertices) if vertex_arc_length is None else np.asarray(vertex_arc_length, dtype=float)
    if s.shape != (len(vertices),):
        raise ValueError(f"vertex_arc_length has {s.size} values for {len(vertices)} vertices")
    if len(vertices) == 1:
        distance = np.linalg.norm(points - vertices[0], axis=1)
        return ClosestPoints(distance, np.repeat(vertices, len(points), axis=0), np.full(len(points), s[0]))

    start, direction = vertices[:-1], np.diff(vertices, axis=0)
    length2 = np.einsum("ij,ij->i", direction, direction)
    inverse_length2 = np.divide(1.0, length2, out=np.zeros_like(length2), where=length2 > 0.0)  # repeated vertex: t = 0
    start_dot_direction = np.einsum("ij,ij->i", start, direction)
    start2 = np.einsum("ij,ij->i", start, start)
    k = np.empty(len(points), dtype=np.intp)
    block = max(1, _PAIRS_PER_BLOCK // len(start))
    for lo in range(0, len(points), block):
        p = points[lo:lo + block]
        # Segment choice from |o - t d|^2 = |o|^2 - 2 t (o.d) + t^2 |d|^2 with o = p - r_i, all terms as matrix
        # products (points x segments); its round-off only matters between near-equidistant segments.
        o_dot_d = p @ direction.T - start_dot_direction
        o2 = np.einsum("ij,ij->i", p, p)[:, None] - 2.0 * (p @ start.T) + start2
        t = np.clip(o_dot_d * inverse_length2, 0.0, 1.0)
        k[lo:lo + block] = np.argmin(o2 - t * (2.0 * o_dot_d - t * length2), axis=1)
    # Exact distance and arc length on the chosen segment.
    offset = points - start[k]
    t = np.clip(np.einsum("ij,ij->i", offset, direction[k]) * inverse_length2[k], 0.0, 1.0)
    closest = start[k] + t[:, None] * direction[k]
    distance = np.linalg.norm(points - closest, axis=1)
    return ClosestPoints(distance, closest, s[k] + t * (s[k + 1] - s[k]))
