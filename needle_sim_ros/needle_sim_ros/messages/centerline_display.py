"""Model and measured centerlines of a comparison for RViz and Foxglove: nav_msgs/Path and a Marker tube.

Both are in the model frame (the measurement mapped by the camera -> model extrinsic), serialized with the
encoders of :mod:`needle_sim_ros.messages.cdr` (checked byte for byte against rclpy in test_cdr).
"""
from __future__ import annotations

import numpy as np

from needle_sim_ros.messages import cdr
from needle_sim_ros.messages.geometry import polyline_tangents, quaternions_from_tangents, tube_triangles

COLORS = {"model": (0.75, 0.75, 0.8, 1.0), "measured": (1.0, 0.55, 0.1, 0.8)}  # RGBA


def centerline_display(sec: int, nanosec: int, frame_id: str, kind: str, points: np.ndarray,
                       radius: float) -> dict[str, bytes]:
    """{'compare/<kind>/path': Path, 'compare/<kind>/marker': Marker} of a centerline (n >= 2, base to tip)."""
    tangents = polyline_tangents(points)
    return {f"compare/{kind}/path": cdr.path(sec, nanosec, frame_id, points, quaternions_from_tangents(tangents)),
            f"compare/{kind}/marker": cdr.triangle_list_marker(sec, nanosec, frame_id, kind, 0,
                                                               tube_triangles(points, tangents, radius),
                                                               COLORS[kind])}
