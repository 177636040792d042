"""Rectification of points and triangulation on the verged, distorted rig, against known 3D points."""
import time

import cv2
import numpy as np
import pytest

from needle_vision.calibration.rectification import Rectification
from needle_vision.render import project_points, world_from_camera


@pytest.fixture(scope="module")
def points_world():
    """Points spread over the measurement volume (0.4-0.6 m from the cameras, across the field of view)."""
    rng = np.random.default_rng(3)
    return np.column_stack([rng.uniform(-0.05, 0.32, 400), rng.uniform(-0.1, 0.1, 400), rng.uniform(-0.2, 0.1, 400)])


def test_corresponding_points_share_the_epipolar_coordinate(rig, points_world):
    rectification = Rectification.from_rig(rig)
    left = rectification.rectify(project_points(rig, points_world, "left"), "left")
    right = rectification.rectify(project_points(rig, points_world, "right"), "right")
    e = rectification.epipolar_axis
    # Exact projections: only the iterative undistortion's residual remains (< 1e-4 px).
    assert np.max(np.abs(left[:, e] - right[:, e])) < 1e-4


def test_triangulation_recovers_points_in_the_raw_left_frame(rig, points_world):
    rectification = Rectification.from_rig(rig)
    left = rectification.rectify(project_points(rig, points_world, "left"), "left")
    right = rectification.rectify(project_points(rig, points_world, "right"), "right")
    measured = rectification.triangulate(left, right[:, rectification.disparity_axis])
    truth = world_from_camera(rig, "left").inverse().apply(points_world)
    # 1e-4 px of undistortion residual is ~1e-7 m of depth at 0.6 m.
    np.testing.assert_allclose(measured, truth, atol=1e-6)
    # Reporting in the rectified frame instead would be wrong by the rectifying rotation (~8°, ~70 mm here).
    assert np.max(np.linalg.norm(measured @ rectification.rotation_left.T - truth, axis=1)) > 0.03


def test_verged_rig_has_negative_raw_disparities(rig, points_world):
    """Without CALIB_ZERO_DISPARITY the principal points differ, and x_left - x_right changes sign."""
    rectification = Rectification.from_rig(rig)
    a = rectification.disparity_axis
    left = rectification.rectify(project_points(rig, points_world, "left"), "left")
    right = rectification.rectify(project_points(rig, points_world, "right"), "right")
    assert np.any(left[:, a] - right[:, a] < 0)
    assert rectification.projection_left[a, 2] != pytest.approx(rectification.projection_right[a, 2], abs=10)


def test_ros_zero_disparity_rectification_zooms_the_verged_rig(rig):
    """The pitfall: camera_calibration's rectification magnifies this rig ~1.4x, ours keeps the scale."""
    ros = rig.with_ros_rectification()
    ours = Rectification.from_rig(rig)
    assert ros.left.projection[0, 0] > 1.3 * rig.left.camera_matrix[0, 0]
    assert ours.focal_length == pytest.approx(rig.left.camera_matrix[0, 0], rel=0.01)


def test_closed_form_triangulation_matches_opencv_and_is_faster(rig, points_world):
    rectification = Rectification.from_rig(rig)
    left = rectification.rectify(project_points(rig, points_world, "left"), "left")
    right = rectification.rectify(project_points(rig, points_world, "right"), "right")
    start = time.perf_counter()
    ours = rectification.triangulate(left, right[:, rectification.disparity_axis])
    ours_time = time.perf_counter() - start
    start = time.perf_counter()
    homogeneous = cv2.triangulatePoints(rectification.projection_left, rectification.projection_right,
                                        left.T.copy(), right.T.copy())
    opencv_time = time.perf_counter() - start
    opencv = (homogeneous[:3] / homogeneous[3]).T @ rectification.rotation_left
    np.testing.assert_allclose(ours, opencv, atol=1e-9)
    assert ours_time < opencv_time * 2  # never slower (timing on a shared machine: loose)


def test_points_at_infinity_become_nan(rig):
    rectification = Rectification.from_rig(rig)
    a = rectification.disparity_axis
    left = np.array([[700.0, 500.0]])
    # Zero or wrong-signed disparity relative to the principal points: behind or at infinity.
    at_infinity = left[:, a] - rectification.projection_left[a, 2] + rectification.projection_right[a, 2]
    assert np.all(np.isnan(rectification.triangulate(left, at_infinity)))
