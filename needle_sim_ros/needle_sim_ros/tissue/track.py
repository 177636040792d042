"""The track cut by the advancing needle tip: a polyline in the world frame, parameterised by its arc length.

Path memory (Glozman & Shoham's virtual springs, seed 001 Sec. II: forces act "at the nodes in contact with the
tissue nodes that are previously cut by the needle"): the track starts where the tip crossed the entry surface
and, whenever the tip has advanced ``spacing`` beyond its end, grows a vertex ON THE TIP'S PATH: each tissue point's
rest position is where the tip passed when it cut that point.  The vertex is interpolated between the tip's
positions before and after the step at the exact crossing (``spacing`` ahead of the end), not put at the step's
end: the track then depends continuously on the motion, not on which step the crossing fell in (a 1 ms step at
20 mm/s would otherwise shift it by up to 20 um and make the response jump with any parameter).  Tissue beyond
the end is uncut and holds nothing laterally (the cut front carries no spring).  Retracting leaves the track in
place, so a re-insertion follows it until the tip passes its end, then cuts new tissue.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit


END_CHORD_SEGMENTS = 10  # segments over which the end tangent is taken (1 mm at the default 0.1 mm spacing)


class TrackSnapshot(NamedTuple):
    """A track's state (:meth:`Track.snapshot`): its vertex count and capacity, initial direction, the tip
    position of the previous cut and the cached end tangent (arrays that the track replaces, never changes in
    place)."""

    count: int
    capacity: int
    direction: np.ndarray
    previous_tip: np.ndarray
    end_tangent: np.ndarray | None


class Track:
    """Mutable polyline from the entry point; ``length`` is its arc length [m] (0 right after the entry).

    Coordinates beyond its end are measured along its end tangent (the initial direction while it has one
    vertex); they lie in uncut tissue. The vertex buffers only grow at their end and are zero beyond it, so a
    snapshot is a count (O(1)) and a restore zeroes what was added since.
    """

    def __init__(self, spacing: float, capacity: int = 256) -> None:
        if not spacing > 0.0:
            raise ValueError(f"tissue.track.spacing must be > 0, got {spacing!r}")
        self.spacing = spacing
        self._vertices = np.zeros((capacity, 3))
        self._arc = np.zeros(capacity)
        self._count = 0
        self._direction = np.array([1.0, 0.0, 0.0])
        self._previous_tip = np.zeros(3)  # the tip position of the previous cut() (the entry point at the start)
        self._end_tangent: np.ndarray | None = None  # end_tangent() of the current vertices (None: not computed)

    @property
    def started(self) -> bool:
        return self._count >= 1

    @property
    def vertices(self) -> np.ndarray:
        return self._vertices[: self._count]

    @property
    def arc_lengths(self) -> np.ndarray:
        """Cumulative arc length [m] at each vertex."""
        return self._arc[: self._count]

    @property
    def length(self) -> float:
        return float(self._arc[self._count - 1]) if self._count else 0.0

    def start(self, entry_point: np.ndarray, direction: np.ndarray) -> None:
        """Begin the track at ``entry_point`` heading along ``direction``."""
        norm = np.linalg.norm(direction)
        if not norm > 0.0:
            raise ValueError("track start: direction must be non-zero")
        self._count = 0
        self._vertices[:] = 0.0
        self._arc[:] = 0.0
        self._direction = np.asarray(direction, dtype=float) / norm
        self._append(np.asarray(entry_point, dtype=float))
        self._previous_tip = np.array(entry_point, dtype=float)

    def _append(self, point: np.ndarray) -> None:
        if self._count == self._vertices.shape[0]:
            self._vertices = np.vstack([self._vertices, np.zeros_like(self._vertices)])
            self._arc = np.concatenate([self._arc, np.zeros_like(self._arc)])
        self._end_tangent = None
        if self._count:
            step = point - self._vertices[self._count - 1]
            self._arc[self._count] = self._arc[self._count - 1] + np.sqrt(step @ step)
        self._vertices[self._count] = point
        self._count += 1

    def snapshot(self) -> TrackSnapshot:
        """The track's state, for :meth:`restore`."""
        return TrackSnapshot(self._count, self._arc.size, self._direction, self._previous_tip, self._end_tangent)

    def restore(self, snapshot: TrackSnapshot) -> None:
        if self._arc.size != snapshot.capacity:
            self._vertices = self._vertices[:snapshot.capacity].copy()
            self._arc = self._arc[:snapshot.capacity].copy()
        self._vertices[snapshot.count:] = 0.0
        self._arc[snapshot.count:] = 0.0
        self._count, self._direction, self._previous_tip = snapshot.count, snapshot.direction, snapshot.previous_tip
        self._end_tangent = snapshot.end_tangent

    def end_tangent(self) -> np.ndarray:
        """Direction of the cut at the end: the chord over the last ``END_CHORD_SEGMENTS`` segments (the first
        direction while there is none). One 0.1 mm segment would carry the tip's lateral jitter: tilted by it, the
        cut front seemed to recede from an advancing tip, the track stopped growing and the tip forces switched off."""
        if self._count < 2:
            return self._direction
        if self._end_tangent is None:
            d = self._vertices[self._count - 1] - self._vertices[max(self._count - 1 - END_CHORD_SEGMENTS, 0)]
            self._end_tangent = d / np.sqrt(d @ d)
        return self._end_tangent

    def coordinate_ahead(self, point: np.ndarray) -> float:
        """Track coordinate of a point near the end, measured along the end tangent (may exceed ``length``)."""
        return self.length + float((point - self._vertices[self._count - 1]) @ self.end_tangent())

    def cut(self, tip_position: np.ndarray) -> bool:
        """Extend the track while the tip is ``spacing`` or more beyond its end, each vertex where the straight path
        from the previous tip position crosses ``spacing`` ahead of the end; True if it grew."""
        tip = np.asarray(tip_position, dtype=float)
        previous, grew = self._previous_tip, False
        while (ahead := self.coordinate_ahead(tip) - self.length) >= self.spacing:
            behind = self.coordinate_ahead(previous) - self.length
            fraction = (self.spacing - behind) / (ahead - behind) if behind < self.spacing else 0.0
            previous = previous + fraction * (tip - previous)
            self._append(previous)
            grew = True
        self._previous_tip = tip.copy()
        return grew

    def locate(self, coordinate) -> tuple[np.ndarray, np.ndarray]:
        """Points (k, 3) and unit tangents (k, 3) at track coordinates (k,) (>= 0; beyond ``length`` on the
        straight continuation)."""
        s = np.ascontiguousarray(np.maximum(np.asarray(coordinate, dtype=float), 0.0))
        return locate_on_polyline(self._vertices[: self._count], self._arc[: self._count], self.end_tangent(), s)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest track coordinate (k,) and distance (k,) of points (k, 3), over the segments and the straight
        continuation beyond the end (compiled)."""
        points = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
        return project_on_polyline(self._vertices[: self._count], self._arc[: self._count], self.end_tangent(),
                                   points)


@njit(cache=True)
def project_on_polyline(vertices, arc, end_tangent, points):
    """Closest coordinate (k,) and distance (k,) of points on the polyline (vertices, cumulative arc) and on its
    straight continuation beyond the end along end_tangent."""
    count = arc.size
    n = points.shape[0]
    coordinate = np.empty(n)
    distance = np.empty(n)
    end = vertices[count - 1]
    for k in range(n):
        p = points[k]
        beyond = max((p[0] - end[0]) * end_tangent[0] + (p[1] - end[1]) * end_tangent[1]
                     + (p[2] - end[2]) * end_tangent[2], 0.0)
        best, best_coordinate = 0.0, arc[count - 1] + beyond
        for i in range(3):
            d = p[i] - end[i] - beyond * end_tangent[i]
            best += d * d
        for j in range(count - 1):
            a, b = vertices[j], vertices[j + 1]
            length2 = 0.0
            along = 0.0
            for i in range(3):
                length2 += (b[i] - a[i]) ** 2
                along += (p[i] - a[i]) * (b[i] - a[i])
            fraction = min(max(along / length2, 0.0), 1.0) if length2 > 0.0 else 0.0
            d2 = 0.0
            for i in range(3):
                d = p[i] - a[i] - fraction * (b[i] - a[i])
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
            j = min(max(np.searchsorted(arc, s[k], side="right") - 1, 0), count - 2)
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
