"""Model and measured centerlines of a comparison for RViz and Foxglove: nav_msgs/Path and a Marker tube, in the
model frame, serialized by :mod:`needle_sim_ros.messages.cdr`.
"""
from __future__ import annotations

import numpy as np

from needle_sim_ros.comparison import ComparedPair
from needle_sim_ros.messages import cdr
from needle_common.transforms import quaternions_from_x_axes
from needle_sim_ros.messages.geometry import polyline_tangents, tube_triangles
from needle_sim_ros.messages.shape import stamp_ns

DISPLAY_TYPES = {"path": "nav_msgs/msg/Path", "marker": "visualization_msgs/msg/Marker"}
COLORS = {"model": (0.75, 0.75, 0.8, 1.0), "measured": (1.0, 0.55, 0.1, 0.8)}  # RGBA


def path_and_tube(sec: int, nanosec: int, frame_id: str, namespace: str, points: np.ndarray, tangents: np.ndarray,
                  orientations: np.ndarray, radius: float, color: tuple[float, float, float, float]
                  ) -> tuple[bytes, bytes]:
    """nav_msgs/Path (``orientations``: x along the tangents) and Marker tube (``radius`` [m], RGBA ``color``) of a
    centerline."""
    return (cdr.path(sec, nanosec, frame_id, points, orientations),
            cdr.triangle_list_marker(sec, nanosec, frame_id, namespace, 0, tube_triangles(points, tangents, radius),
                                     color))


def centerline_display(sec: int, nanosec: int, frame_id: str, kind: str, points: np.ndarray,
                       radius: float) -> dict[str, bytes]:
    """{'compare/<kind>/path': Path, 'compare/<kind>/marker': Marker} of a centerline (n >= 2, base to tip)."""
    tangents = polyline_tangents(points)
    path, marker = path_and_tube(sec, nanosec, frame_id, kind, points, tangents, quaternions_from_x_axes(tangents),
                                 radius, COLORS[kind])
    return {f"compare/{kind}/path": path, f"compare/{kind}/marker": marker}


class ComparisonDisplay:
    """The compared centerlines of ``needle_compare`` as :func:`centerline_display` outputs, at most ``rate``
    per second of measurement time (a tube costs a few milliseconds): the node publishes and records them, the
    offline pipeline writes them to its log, so the Foxglove layout shows both alike."""

    def __init__(self, rate: float, radius: float, model_from_camera) -> None:
        self.rate, self.radius, self.model_from_camera = rate, radius, model_from_camera
        self._next_ns = 0

    def outputs(self, pair: ComparedPair) -> dict[str, bytes]:
        """{topic: serialized Path or Marker} for one comparison (``pair.model_tag``: its std_msgs/Header), or {}
        when the rate leaves it out. The measurement is mapped into the model frame; a point cloud is ordered by
        the arc length of the closest model point."""
        stamp = pair.model_tag.stamp
        now_ns = stamp_ns(stamp)
        if self.rate <= 0.0 or self._next_ns - 2e9 / self.rate <= now_ns < self._next_ns:
            return {}
        self._next_ns = now_ns + int(1e9 / self.rate)
        points = self.model_from_camera.apply(pair.measured.points)[pair.result.matched]
        if not pair.measured.ordered:
            points = points[np.argsort(pair.result.arc_length)]
        frame = pair.model_tag.frame_id
        outputs = centerline_display(stamp.sec, stamp.nanosec, frame, "model", pair.model.points, self.radius)
        if len(points) >= 2:
            outputs.update(centerline_display(stamp.sec, stamp.nanosec, frame, "measured", points, self.radius))
        return outputs
