"""``needle_stereo_calibrate``: stereo calibration of the two cameras from checkerboard pairs (seed 000, Sec. III-A
needs a calibrated rig).

Input read as ``needle_stereo_offline`` reads it; outputs and accuracy: README, "Calibration". Each camera is
calibrated alone (``plumb_bob``), then ``cv2.stereoCalibrate`` refines both cameras' intrinsics with the extrinsics
(unlike ROS ``camera_calibration``); R and P come from ``stereoRectify`` with ``CALIB_ZERO_DISPARITY``.
Exit status 0 on success, 1 when too few pairs show the board, 2 on bad input.

    needle_stereo_calibrate board_images/ --board 9x6 --square 0.015 --output-dir calibration/
"""
from __future__ import annotations

import argparse
import os
import re
import sys
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from needle_common.bag_reader import BagReadError
from needle_common.cli_types import command_status, non_negative, positive, positive_int
from needle_common.output_files import write_atomically
from needle_vision.calibration.rig import CalibrationError, CameraCalibration, StereoRig, camera_calibration_yaml
from needle_vision.offline import InputError, SkippedPair, decoded, open_source
from needle_vision.calibration.rectification import Rectification

MIN_VIEWS = 6  # pairs showing the whole board in both images


class CalibrationFailed(RuntimeError):
    """The images do not allow a calibration (exit status 1); the message says why."""


def board_corners(corners: tuple[int, int], square: float) -> np.ndarray:
    """Inner corners ``(cols * rows, 3)`` of a checkerboard in its own frame [m], centred, row by row (OpenCV's
    order for ``patternSize = corners``), z = 0."""
    grid = np.zeros((corners[0] * corners[1], 3), np.float32)
    grid[:, :2] = np.mgrid[0:corners[0], 0:corners[1]].T.reshape(-1, 2) * square
    grid[:, :2] -= grid[:, :2].mean(axis=0)
    return grid


def find_corners(image: np.ndarray, corners: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners ``(n, 2)`` of the board in one grey image (OpenCV's order), or None.

    ``cv2.findChessboardCornersSB`` (OpenCV >= 4.0; ~0.03 px on renders): its time is bounded, unlike
    ``findChessboardCorners``'s when the board has other dimensions than asked."""
    image = image if image.dtype == np.uint8 else cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
    found, points = cv2.findChessboardCornersSB(image, corners, flags=cv2.CALIB_CB_NORMALIZE_IMAGE
                                                | cv2.CALIB_CB_ACCURACY)
    return points.reshape(-1, 2).astype(np.float64) if found else None


def _consistent(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The right corners in the left corners' order: a detector may start a (180°-symmetric) grid of corners at
    the opposite end in the other image; then the order is reversed."""
    return right[::-1].copy() if np.dot(left[-1] - left[0], right[-1] - right[0]) < 0 else right


@dataclass(frozen=True)
class StereoCalibrationResult:
    rig: StereoRig
    rms_left: float
    rms_right: float
    rms_stereo: float
    views: int
    worst_view: tuple[str, float]
    epipolar_rms: float
    epipolar_max: float

    def report(self) -> dict:
        """The report written to calibration_report.yaml (pixels, metres)."""
        def camera(c: CameraCalibration) -> dict:
            return {"fx": float(c.camera_matrix[0, 0]), "fy": float(c.camera_matrix[1, 1]),
                    "cx": float(c.camera_matrix[0, 2]), "cy": float(c.camera_matrix[1, 2]),
                    "distortion": [float(v) for v in c.distortion]}
        return {"views": self.views,
                "reprojection_rms_px": {"left": self.rms_left, "right": self.rms_right, "stereo": self.rms_stereo},
                "worst_view": {"pair": self.worst_view[0], "rms_px": self.worst_view[1]},
                "rectified_epipolar_error_px": {"rms": self.epipolar_rms, "max": self.epipolar_max},
                "baseline_m": self.rig.baseline,
                "left": camera(self.rig.left), "right": camera(self.rig.right),
                "rotation_right_from_left": self.rig.rotation.tolist(),
                "translation_right_from_left_m": self.rig.translation.tolist()}


def stereo_calibrate(views: list[tuple[str, np.ndarray, np.ndarray]], corners: tuple[int, int], square: float,
                     sizes: tuple[tuple[int, int], tuple[int, int]]) -> StereoCalibrationResult:
    """Calibrate from ``(name, left corners, right corners)`` per pair; ``sizes``: (width, height) per camera."""
    if len(views) < MIN_VIEWS:
        raise CalibrationFailed(f"calibration failed: the board ({corners[0]}x{corners[1]} inner corners) was found "
                                f"in both images of {len(views)} pair(s); at least {MIN_VIEWS} are needed "
                                "(check --board)")
    grid = board_corners(corners, square)
    objects = [grid] * len(views)
    image_points = [[v[k].astype(np.float32).reshape(-1, 1, 2) for v in views] for k in (1, 2)]
    fits = [cv2.calibrateCamera(objects, points, size, None, None) for points, size in zip(image_points, sizes)]
    (rms_left, k_left, d_left, *_), (rms_right, k_right, d_right, *_) = fits
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 200, 1e-9)
    rms_stereo, k_left, d_left, k_right, d_right, rotation, translation, *_ = cv2.stereoCalibrate(
        objects, *image_points, k_left, d_left, k_right, d_right, sizes[0], criteria=criteria,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS)
    rig = StereoRig(CameraCalibration(*sizes[0], k_left, d_left.ravel(), camera_name="left"),
                    CameraCalibration(*sizes[1], k_right, d_right.ravel(), camera_name="right"),
                    rotation, translation.ravel())
    # Per view: reprojection error of the board pose fitted in the left camera, seen through the stereo rig.
    worst = ("", 0.0)
    rectification = Rectification.from_rig(rig)
    epipolar = []
    for name, left, right in views:
        _, rvec, tvec = cv2.solvePnP(grid, left, k_left, d_left)
        board_left = (cv2.Rodrigues(rvec)[0] @ grid.T.astype(float)).T + tvec.ravel()
        error = []
        for points, k, d, r, t in ((left, k_left, d_left, np.eye(3), np.zeros(3)),
                                   (right, k_right, d_right, rotation, translation.ravel())):
            projected, _ = cv2.projectPoints(board_left @ r.T + t, np.zeros(3), np.zeros(3), k, d)
            error.append(np.linalg.norm(projected.reshape(-1, 2) - points, axis=1))
        rms = float(np.sqrt(np.mean(np.concatenate(error) ** 2)))
        worst = max(worst, (name, rms), key=lambda item: item[1])
        axis = rectification.epipolar_axis
        epipolar.append(rectification.rectify(left, "left")[:, axis] - rectification.rectify(right, "right")[:, axis])
    epipolar = np.abs(np.concatenate(epipolar))
    return StereoCalibrationResult(rig, float(rms_left), float(rms_right), float(rms_stereo), len(views), worst,
                                   float(np.sqrt(np.mean(epipolar ** 2))), float(epipolar.max()))


def _board(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match or min(int(v) for v in match.groups()) < 2:
        raise argparse.ArgumentTypeError(f"'{text}' is not COLSxROWS inner corners (e.g. 9x6), each >= 2")
    return int(match.group(1)), int(match.group(2))


def run(arguments: argparse.Namespace) -> int:
    source = open_source(Path(arguments.input), 1.0, arguments.left_topic, arguments.right_topic,
                         arguments.sync_tolerance)
    corners = arguments.board

    def detect(load):
        left, right = load()
        found = [find_corners(image, corners) for image in (left, right)]
        return [image.shape[::-1] for image in (left, right)], found

    jobs = ((index, stamp, lambda load=load: detect(load), poses) for index, stamp, load, poses in source.jobs())
    views, sizes, pairs = [], None, 0
    with closing(decoded(jobs, arguments.workers, 2 * arguments.workers + 2)) as detected:
        for index, _, future, _ in detected:
            try:
                shape, (left, right) = future.result()
            except SkippedPair:
                continue
            pairs += 1
            if sizes is None:
                sizes = shape
            elif shape != sizes:
                raise InputError(f"pair {index}: image sizes {shape} differ from the first pair's {sizes}")
            if left is not None and right is not None:
                views.append((str(index), left, _consistent(left, right)))
    print(f"board found in both images of {len(views)} of {pairs} pairs")
    result = stereo_calibrate(views, corners, arguments.square, sizes or ((0, 0), (0, 0)))
    ros = result.rig.with_ros_rectification()
    output = Path(arguments.output_dir)
    output.mkdir(parents=True, exist_ok=True)
    report = yaml.safe_dump(result.report(), sort_keys=False, default_flow_style=None)
    for name, text in (("left.yaml", camera_calibration_yaml(ros.left)),
                       ("right.yaml", camera_calibration_yaml(ros.right)), ("calibration_report.yaml", report)):
        write_atomically(output / name, lambda temporary, text=text: temporary.write_text(text))
    print(report.rstrip())
    print(f"-> {output / 'left.yaml'}, {output / 'right.yaml'}, {output / 'calibration_report.yaml'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="needle_stereo_calibrate", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", help="folder with left/ and right/ board images, an .mcap file or a rosbag2 folder")
    parser.add_argument("--board", type=_board, required=True, metavar="COLSxROWS",
                        help="inner corners of the checkerboard, e.g. 9x6 (an odd and an even number is best)")
    parser.add_argument("--square", type=positive, required=True, help="side of a square [m]")
    parser.add_argument("--output-dir", default=".", help="where left.yaml, right.yaml and calibration_report.yaml "
                        "are written (default: the working directory)")
    parser.add_argument("--left-topic", default="left/image_raw", help="Image or CompressedImage topic of a bag")
    parser.add_argument("--right-topic", default="right/image_raw", help="Image or CompressedImage topic of a bag")
    parser.add_argument("--sync-tolerance", type=non_negative, default=0.002,
                        help="largest stamp difference of a pair [s]")
    parser.add_argument("--workers", type=positive_int, default=min(4, os.cpu_count() or 1), help="detection threads")
    arguments = parser.parse_args(argv)
    return command_status("needle_stereo_calibrate", run, arguments,
                          (InputError, BagReadError, CalibrationError, OSError), (CalibrationFailed,))


if __name__ == "__main__":
    sys.exit(main())
