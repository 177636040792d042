"""Geometry of the shape outputs, ROS-free: pose orientations along a centerline, tangents of a sampled curve and
the triangles of a tube around it (for nav_msgs/Path, PoseArray and the Marker tube)."""
from __future__ import annotations

import numpy as np


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


def polyline_tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents of a sampled curve (central differences; one-sided at the ends)."""
    tangents = np.gradient(points, axis=0)
    norms = np.linalg.norm(tangents, axis=1, keepdims=True)
    return tangents / np.where(norms > 0.0, norms, 1.0)


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
