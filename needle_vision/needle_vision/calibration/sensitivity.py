"""How calibration error propagates into the measurement: a simulated checkerboard stereo calibration.

A planar checkerboard is shown to the rig in random poses around the needle's volume; its corners are
projected with the true calibration, disturbed by Gaussian detection noise (sized for the requested RMS
reprojection error: per-coordinate sigma = rms / sqrt(2)), and calibrated the way ROS
``camera_calibration`` does (each camera with OpenCV's 5-coefficient model, then ``stereoCalibrate`` with
the intrinsics fixed). Measuring renders of a known needle with the estimated rig shows the share of the
error that comes from the calibration.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from needle_vision.calibration.rig import CameraCalibration, StereoRig
from needle_vision.render import project_points, world_from_camera
from needle_common.transforms import RigidTransform


@dataclass(frozen=True)
class SimulatedCalibration:
    """Estimated rig (same world pose as the true one) and the RMS reprojection errors [px] of the fits."""

    rig: StereoRig
    rms_left: float
    rms_right: float
    rms_stereo: float


def board_corners(corners: tuple[int, int], square: float) -> np.ndarray:
    """Inner corners ``(cols * rows, 3)`` of a checkerboard in its own frame [m], centred, row by row (OpenCV's
    order for ``patternSize = corners``), z = 0."""
    grid = np.zeros((corners[0] * corners[1], 3), np.float32)
    grid[:, :2] = np.mgrid[0:corners[0], 0:corners[1]].T.reshape(-1, 2) * square
    grid[:, :2] -= grid[:, :2].mean(axis=0)
    return grid


def random_board_pose(rig: StereoRig, rng: np.random.Generator, centre: np.ndarray, tilt: float = 0.6,
                      spread: tuple[float, float, float] = (0.12, 0.1, 0.1)) -> RigidTransform:
    """Pose of a board in the world frame: facing the left camera, tilted by up to ``tilt`` [rad] about its
    in-plane axes, turned at random about its normal, and shifted by up to ``spread`` [m] from ``centre``."""
    towards_cameras = world_from_camera(rig, "left").translation - centre
    facing = Rotation.align_vectors([towards_cameras], [[0.0, 0.0, 1.0]])[0]
    turn = Rotation.from_rotvec(np.append(rng.uniform(-tilt, tilt, 2), rng.uniform(-np.pi, np.pi)))
    return RigidTransform((facing * turn).as_matrix(), centre + rng.uniform(-np.asarray(spread), spread))


def simulate_checkerboard_calibration(rig: StereoRig, rng: np.random.Generator, *, reprojection_rms_px: float = 0.14,
                                      views: int = 25, corners: tuple[int, int] = (9, 6), square: float = 0.03,
                                      centre: np.ndarray = np.array([0.135, 0.0, -0.04])) -> SimulatedCalibration:
    """Calibrate ``rig`` from ``views`` noisy checkerboard views (board of ``corners`` inner corners, ``square``
    [m]) held around ``centre`` (world frame [m], default: the middle of the needle's volume)."""
    grid = board_corners(corners, square)
    object_points, left_points, right_points = [], [], []
    while len(object_points) < views:
        board = random_board_pose(rig, rng, centre).apply(grid)
        seen = []
        for side, camera in (("left", rig.left), ("right", rig.right)):
            pixels = project_points(rig, board, side)
            if np.any(pixels < 10) or np.any(pixels > [camera.width - 10, camera.height - 10]):
                break
            noise = rng.normal(0.0, reprojection_rms_px / np.sqrt(2), pixels.shape)
            seen.append((pixels + noise).astype(np.float32))
        if len(seen) == 2:
            object_points.append(grid)
            left_points.append(seen[0])
            right_points.append(seen[1])
    size = rig.left.image_size
    rms_left, k_left, d_left, *_ = cv2.calibrateCamera(object_points, left_points, size, None, None)
    rms_right, k_right, d_right, *_ = cv2.calibrateCamera(object_points, right_points, size, None, None)
    rms_stereo, k_left, d_left, k_right, d_right, rotation, translation, *_ = cv2.stereoCalibrate(
        object_points, left_points, right_points, k_left, d_left, k_right, d_right, size,
        flags=cv2.CALIB_FIX_INTRINSIC)
    estimated = StereoRig(CameraCalibration(*size, k_left, d_left.ravel(), camera_name="left"),
                          CameraCalibration(*size, k_right, d_right.ravel(), camera_name="right"),
                          rotation, translation.ravel(), rig.world_from_left)
    return SimulatedCalibration(estimated, float(rms_left), float(rms_right), float(rms_stereo))
