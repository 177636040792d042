"""Model and measured centerlines of a comparison for RViz and Foxglove: nav_msgs/Path and a Marker tube.

Both are in the model frame (the measurement mapped by the camera -> model extrinsic), serialized with the
encoders of :mod:`needle_sim_ros.cdr` (checked byte for byte against rclpy in test_end_to_end).
"""
from __future__ import annotations

import numpy as np

from needle_sim_ros import cdr
from needle_sim_ros.nodes.shape_messages import quaternions_from_tangents, tube_triangles

DISPLAY_TOPICS = ("compare/model/path", "compare/model/marker", "compare/measured/path", "compare/measured/marker")
COLORS = {"model": (0.75, 0.75, 0.8, 1.0), "measured": (1.0, 0.55, 0.1, 0.8)}  # RGBA


def polyline_tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents of a sampled curve (central differences; one-sided at the ends)."""
    tangents = np.gradient(points, axis=0)
    norms = np.linalg.norm(tangents, axis=1, keepdims=True)
    return tangents / np.where(norms > 0.0, norms, 1.0)


def centerline_display(sec: int, nanosec: int, frame_id: str, kind: str, points: np.ndarray,
                       radius: float) -> dict[str, bytes]:
    """{'compare/<kind>/path': Path, 'compare/<kind>/marker': Marker} of a centerline (n >= 2, base to tip)."""
    tangents = polyline_tangents(points)
    return {f"compare/{kind}/path": cdr.path(sec, nanosec, frame_id, points, quaternions_from_tangents(tangents)),
            f"compare/{kind}/marker": cdr.triangle_list_marker(sec, nanosec, frame_id, kind, 0,
                                                               tube_triangles(points, tangents, radius),
                                                               COLORS[kind])}
