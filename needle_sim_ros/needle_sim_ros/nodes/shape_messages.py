"""Needle centerline <-> ROS message objects (NeedleShape, ShapeError) and the geometry of the shape outputs
(pose orientations along the centerline, the tube's triangles); :mod:`needle_sim_ros.cdr` encodes the simulator's
high-rate outputs directly."""
from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from needle_interfaces.msg import NeedleShape, ShapeError
from std_msgs.msg import Header


def quaternions_from_tangents(tangents: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of frames whose x axis is each tangent, with the least rotation from world x."""
    t = tangents / np.linalg.norm(tangents, axis=1, keepdims=True)
    x = np.array([1.0, 0.0, 0.0])
    axis = np.cross(x, t)
    w = 1.0 + t[:, 0]
    q = np.column_stack([axis, w])
    opposite = w < 1e-9  # tangent along -x: rotate by pi about z
    q[opposite] = [0.0, 0.0, 1.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _pose(position, quaternion) -> Pose:
    return Pose(position=Point(x=float(position[0]), y=float(position[1]), z=float(position[2])),
                orientation=Quaternion(x=float(quaternion[0]), y=float(quaternion[1]), z=float(quaternion[2]),
                                       w=float(quaternion[3])))


def needle_shape_msg(header: Header, source: str, points: np.ndarray, tangents: np.ndarray, arc_length: np.ndarray,
                     tip_position: np.ndarray, tip_orientation: np.ndarray,
                     uncertainty: np.ndarray | None = None) -> NeedleShape:
    return NeedleShape(
        header=header,
        source=source,
        points=[Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in points],
        tangents=[Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in tangents],
        arc_length=[float(s) for s in arc_length],
        uncertainty=[] if uncertainty is None else [float(u) for u in uncertainty],
        tip_pose=_pose(tip_position, tip_orientation),
        length=float(arc_length[-1]) if len(arc_length) else 0.0,
    )


def shape_arrays(msg: NeedleShape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (n,3), arc_length (n,), uncertainty (n,) or empty) of a NeedleShape."""
    points = np.array([[p.x, p.y, p.z] for p in msg.points], dtype=float).reshape(-1, 3)
    return points, np.asarray(msg.arc_length, dtype=float), np.asarray(msg.uncertainty, dtype=float)


def tube_triangles(points: np.ndarray, tangents: np.ndarray, radius: float, sides: int = 8) -> np.ndarray:
    """Triangle-list vertices (m, 3) of a tube of the given radius around a centerline.

    Cross-section frames are carried along the curve by parallel transport (no twist), so the tube does not
    spin with the curve's Frenet frame and stays well defined where the curvature vanishes.
    """
    t = tangents / np.linalg.norm(tangents, axis=1, keepdims=True)
    helper = np.array([0.0, 0.0, 1.0]) if abs(t[0, 2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    normals = np.empty_like(t)
    n = np.cross(helper, t[0])
    normals[0] = n / np.linalg.norm(n)
    for i in range(1, len(t)):
        n = normals[i - 1] - np.dot(normals[i - 1], t[i]) * t[i]
        normals[i] = n / np.linalg.norm(n)
    binormals = np.cross(t, normals)
    angles = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    rings = points[:, None, :] + radius * (np.cos(angles)[None, :, None] * normals[:, None, :]
                                           + np.sin(angles)[None, :, None] * binormals[:, None, :])
    a, b = rings[:-1], rings[1:]
    a_next, b_next = np.roll(a, -1, axis=1), np.roll(b, -1, axis=1)
    quads = np.stack([a, b, b_next, a, b_next, a_next], axis=2)  # two triangles per quad
    return quads.reshape(-1, 3)


def time_msg(seconds: float) -> Time:
    sec = int(np.floor(seconds))
    return Time(sec=sec, nanosec=min(int(round((seconds - sec) * 1e9)), 999_999_999))


def shape_error_msg(result, model_header: Header, measured_header: Header) -> ShapeError:
    """ShapeError of one comparison (needle_sim_ros.comparison.ShapeComparison), stamped with the measurement."""
    return ShapeError(header=Header(stamp=measured_header.stamp, frame_id=model_header.frame_id),
                      model_stamp=model_header.stamp, measurement_stamp=measured_header.stamp,
                      rmse=result.rmse, max_error=result.max_error, tip_error=result.tip_error,
                      matched_samples=result.matched_samples, errors=result.errors.tolist(),
                      arc_length=result.arc_length.tolist())
