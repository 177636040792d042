"""Epipolar rectification of points and triangulation for a verged, distorted stereo rig (seed 000, Sec. III-A).

Only the detected centerline points are rectified (``cv2.undistortPoints`` with ``R_i``, ``P_i``), never whole
images. The rectification is recomputed from the rig's extrinsics *without* ``CALIB_ZERO_DISPARITY``: on a
toed-in rig that flag shifts the principal points until the needle can leave the rectified image. Without it
the two rectified principal points differ, so raw disparities may be negative; depth uses the disparity
relative to ``c'_left - c'_right``. Triangulation applies the rectified projection in closed form (what the
reprojection matrix ``Q`` does; ``cv2.triangulatePoints`` gives the same result ~1000x slower) and rotates the
result back from the rectified to the raw left optical frame (``R_leftᵀ``), which is the frame we report in.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from needle_vision.calibration.rig import StereoRig


@dataclass(frozen=True)
class Rectification:
    """Rectifying rotations ``R_i`` (raw -> rectified), projections ``P_i`` and the disparity axis.

    ``disparity_axis`` is 0 when the baseline is mostly horizontal in the images (epipolar lines are rows, the
    epipolar coordinate is y) and 1 for a vertical rig (epipolar lines are columns).
    """

    rig: StereoRig
    rotation_left: np.ndarray
    rotation_right: np.ndarray
    projection_left: np.ndarray
    projection_right: np.ndarray
    disparity_axis: int

    @classmethod
    def from_rig(cls, rig: StereoRig) -> "Rectification":
        r1, r2, p1, p2, *_ = cv2.stereoRectify(
            rig.left.camera_matrix, rig.left.distortion, rig.right.camera_matrix, rig.right.distortion,
            rig.left.image_size, rig.rotation, rig.translation.reshape(3, 1),  # OpenCV 5 rejects a flat T
            flags=0, alpha=-1.0)
        axis = 0 if abs(p2[0, 3]) >= abs(p2[1, 3]) else 1
        return cls(rig, r1, r2, p1, p2, axis)

    @property
    def epipolar_axis(self) -> int:
        """Index of the rectified coordinate that is equal for corresponding points."""
        return 1 - self.disparity_axis

    @property
    def focal_length(self) -> float:
        """Rectified focal length [px] along the disparity axis."""
        return float(self.projection_left[self.disparity_axis, self.disparity_axis])

    def rectify(self, points: np.ndarray, side: str) -> np.ndarray:
        """Raw (distorted) pixel coordinates ``(n, 2)`` of camera ``side`` ('left'/'right') -> rectified pixels."""
        camera, rotation, projection = (
            (self.rig.left, self.rotation_left, self.projection_left) if side == "left"
            else (self.rig.right, self.rotation_right, self.projection_right))
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 1, 2)
        if points.shape[0] == 0:
            return np.zeros((0, 2))
        return cv2.undistortPoints(points, camera.camera_matrix, camera.distortion,
                                   R=rotation, P=projection).reshape(-1, 2)

    def triangulate(self, left: np.ndarray, right_disparity_coordinate: np.ndarray) -> np.ndarray:
        """3D points [m] in the raw left optical frame from rectified left points ``(n, 2)`` and the matching right
        coordinate along the disparity axis ``(n,)``; points at or behind infinity become NaN (callers reject them)."""
        a = self.disparity_axis
        p1, p2 = self.projection_left, self.projection_right
        disparity = (left[:, a] - p1[a, 2]) - (right_disparity_coordinate - p2[a, 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = -p2[a, 3] / disparity
            depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
            rectified = np.column_stack([(left[:, 0] - p1[0, 2]) / p1[0, 0] * depth,
                                         (left[:, 1] - p1[1, 2]) / p1[1, 1] * depth, depth])
            return rectified @ self.rotation_left  # = (R_leftᵀ x_rect)ᵀ

    def project_rectified(self, points_left: np.ndarray, side: str) -> np.ndarray:
        """Rectified pixel coordinates of 3D points given in the raw left optical frame (for uncertainty and tests)."""
        rectified = points_left @ self.rotation_left.T
        projection = self.projection_left if side == "left" else self.projection_right
        homogeneous = np.hstack([rectified, np.ones((len(rectified), 1))]) @ projection.T
        return homogeneous[:, :2] / homogeneous[:, 2:3]

    def depth_per_disparity(self, points_left: np.ndarray) -> np.ndarray:
        """|dZ/dd| [m/px] at the given points: depth change per pixel of disparity (``Z² / (f' b)``)."""
        depth = (points_left @ self.rotation_left.T)[:, 2]
        return depth ** 2 / abs(self.projection_right[self.disparity_axis, 3])
