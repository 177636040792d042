"""Geometry of the shape outputs, ROS-free: tangents of a sampled curve and the triangles of a tube around it (for
nav_msgs/Path, PoseArray and the Marker tube; the poses' orientations come from
:func:`needle_common.transforms.quaternions_from_x_axes`)."""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.model.kinematics import cross
from needle_sim_ros.model.outputs import transported_normals


def polyline_tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents of a sampled curve (central differences; one-sided at the ends)."""
    tangents = np.gradient(points, axis=0)
    norms = np.linalg.norm(tangents, axis=1, keepdims=True)
    return tangents / np.where(norms > 0.0, norms, 1.0)


def tube_triangles(points: np.ndarray, tangents: np.ndarray, radius: float, sides: int = 8) -> np.ndarray:
    """Triangle-list vertices (m, 3) of a tube of the given radius around a centerline, its cross-section frames carried
    by parallel transport (:func:`~needle_sim_ros.model.outputs.transported_normals`): no spin with the Frenet frame,
    well defined where the curvature vanishes."""
    t = np.ascontiguousarray(tangents / np.linalg.norm(tangents, axis=1, keepdims=True))
    helper = np.array([0.0, 0.0, 1.0]) if abs(t[0, 2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = np.array(cross(helper, t[0]))
    angles = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    return _tube_vertices(np.ascontiguousarray(points, dtype=float), t,
                          transported_normals(t, first / np.linalg.norm(first)), float(radius), np.cos(angles),
                          np.sin(angles))


@njit(cache=True)
def _tube_vertices(points, tangents, normals, radius, cosines, sines):
    """Rings of points + radius (cos n + sin (t x n)) at each centerline point, and two triangles per quad between
    neighbouring rings: (a_j, b_j, b_j+1), (a_j, b_j+1, a_j+1), (6 (k - 1) sides, 3)."""
    k, sides = points.shape[0], cosines.size
    rings = np.empty((k, sides, 3))
    for i in range(k):
        binormal = cross(tangents[i], normals[i])
        for j in range(sides):
            for d in range(3):
                rings[i, j, d] = points[i, d] + radius * (cosines[j] * normals[i, d] + sines[j] * binormal[d])
    vertices = np.empty((max(k - 1, 0), sides, 6, 3))
    for i in range(k - 1):
        for j in range(sides):
            following = (j + 1) % sides
            for d in range(3):
                a, b, b_next, a_next = rings[i, j, d], rings[i + 1, j, d], rings[i + 1, following, d], rings[
                    i, following, d]
                vertices[i, j, 0, d], vertices[i, j, 1, d], vertices[i, j, 2, d] = a, b, b_next
                vertices[i, j, 3, d], vertices[i, j, 4, d], vertices[i, j, 5, d] = a, b_next, a_next
    return vertices.reshape(-1, 3)


def compile_geometry_kernels() -> None:
    """Compile the tube's kernels now (or load them from the cache), not at a node's first visualization output
    (compiling holds the GIL for about a second)."""
    straight = np.zeros((3, 3))
    straight[:, 0] = [0.0, 0.1, 0.2]
    tube_triangles(straight, np.tile([1.0, 0.0, 0.0], (3, 1)), 1e-3)
