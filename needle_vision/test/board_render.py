"""Synthetic checkerboards for the calibration tests and bench/bench_vision.py: stereo images of a board (rig model
of :mod:`needle_vision.render`: distorted pinhole cameras, lens blur, sensor noise), random board poses, and a
simulated calibration from noisy corners (calibration sensitivity).

Each pixel is traced back through the camera's distortion (``cv2.undistortPoints``) to its viewing ray, the ray
is cut with the board plane, and the board's pattern is sampled there on a ``supersample`` x ``supersample``
grid inside the pixel (area averaging: anti-aliased edges). The board has ``corners + 1`` squares per side, the
first (top-left in board coordinates) black, inside a white margin one square wide; around it, a plain grey
background. Corner positions in board coordinates are :func:`needle_vision.calibration.calibrate.board_corners`.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from needle_vision.calibration.calibrate import board_corners
from needle_vision.calibration.rig import CameraCalibration, StereoRig
from needle_vision.render import Imaging, project_points, world_from_camera
from needle_vision.render import _expose as expose  # the renderer's sensor model (noise, quantisation)
from needle_common.transforms import RigidTransform

BLACK, WHITE, BACKGROUND = 25.0, 215.0, 110.0  # grey levels [DN, 8-bit scale]


def _board_values(board_xy: np.ndarray, corners: tuple[int, int], square: float) -> np.ndarray:
    """Grey level of board-plane points ``(n, 2)`` [m] (board frame: corners centred on the origin)."""
    cols, rows = corners
    # Square indices: the square whose top-left corner is corner (i - 1, j - 1); square (0, 0) is black.
    i = np.floor(np.clip(board_xy[:, 0] / square + (cols - 1) / 2 + 1, -9, cols + 9)).astype(np.int16)
    j = np.floor(np.clip(board_xy[:, 1] / square + (rows - 1) / 2 + 1, -9, rows + 9)).astype(np.int16)
    inside = (i >= 0) & (i <= cols) & (j >= 0) & (j <= rows)
    margin = (i >= -1) & (i <= cols + 1) & (j >= -1) & (j <= rows + 1)
    values = np.where(margin, np.float32(WHITE), np.float32(BACKGROUND))
    return np.where(inside & ((i + j) % 2 == 0), np.float32(BLACK), values)


def _viewing_rays(camera: CameraCalibration, pixels: np.ndarray, step: int = 4) -> np.ndarray:
    """Normalised image coordinates ``(n, 2)`` of raw pixels: ``cv2.undistortPoints`` on a grid every ``step``
    pixels, interpolated bilinearly (the distortion is smooth: < 0.001 px off at ``step`` 4, ~50x faster)."""
    ys, xs = np.mgrid[0:camera.height + 2 * step:step, 0:camera.width + 2 * step:step].astype(np.float64)
    grid = cv2.undistortPoints(np.stack([xs, ys], -1).reshape(-1, 1, 2), camera.camera_matrix, camera.distortion)
    grid = grid.reshape(*xs.shape, 2).astype(np.float32)
    rows = -(-len(pixels) // 4096)  # remap takes maps of at most 32767 columns
    padded = np.zeros((rows * 4096, 2), np.float32)
    padded[:len(pixels)] = pixels / step
    map_x, map_y = (padded[:, k].reshape(rows, 4096) for k in range(2))
    return cv2.remap(grid, map_x, map_y, cv2.INTER_LINEAR).reshape(-1, 2)[:len(pixels)]


def render_board_view(rig: StereoRig, world_from_board: RigidTransform, side: str, corners: tuple[int, int],
                      square: float, rng: np.random.Generator, imaging: Imaging = Imaging(),
                      supersample: int = 3) -> np.ndarray:
    """The mono8 image of camera ``side`` showing the board at ``world_from_board``."""
    camera = rig.left if side == "left" else rig.right
    image = np.full((camera.height, camera.width), BACKGROUND, np.float32)
    cols, rows = corners
    outline = np.array([[x, y, 0.0] for x in (-(cols + 3) / 2, (cols + 3) / 2) for y in (-(rows + 3) / 2,
                                                                                         (rows + 3) / 2)]) * square
    box = project_points(rig, world_from_board.apply(outline), side)
    lo = np.clip(np.floor(box.min(axis=0)).astype(int) - 2, 0, [camera.width, camera.height])
    hi = np.clip(np.ceil(box.max(axis=0)).astype(int) + 2, 0, [camera.width, camera.height])
    if np.any(hi <= lo):
        return expose(image, rng, imaging, "mono8")
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    ys, xs = np.mgrid[lo[1]:hi[1], lo[0]:hi[0]]
    dy, dx = (d.ravel() for d in np.meshgrid(offsets, offsets, indexing="ij"))
    samples = np.stack([xs[..., None] + dx, ys[..., None] + dy], axis=-1).astype(np.float32)  # (h, w, n², 2)
    rays = _viewing_rays(camera, samples.reshape(-1, 2))
    board_from_camera = world_from_board.inverse().compose(world_from_camera(rig, side))
    rotation, origin = board_from_camera.rotation.astype(np.float32), board_from_camera.translation
    direction = rays @ rotation[:, :2].T + rotation[:, 2]  # viewing rays (x, y, 1) in the board frame
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.float32(-origin[2]) / direction[:, 2]
        hit = origin[:2].astype(np.float32) + distance[:, None] * direction[:, :2]
    values = np.where(distance > 0, _board_values(np.nan_to_num(hit), corners, square), np.float32(BACKGROUND))
    image[lo[1]:hi[1], lo[0]:hi[0]] = values.reshape(*xs.shape, -1).mean(axis=-1)
    if imaging.blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), imaging.blur_sigma_px)
    return expose(image, rng, imaging, "mono8")


def render_board_pair(rig: StereoRig, world_from_board: RigidTransform, corners: tuple[int, int], square: float,
                      rng: np.random.Generator, imaging: Imaging = Imaging()) -> tuple[np.ndarray, np.ndarray]:
    """Left and right mono8 images of the board (``corners`` inner corners, ``square`` [m])."""
    return tuple(render_board_view(rig, world_from_board, side, corners, square, rng, imaging)
                 for side in ("left", "right"))


@dataclass(frozen=True)
class SimulatedCalibration:
    """Estimated rig (same world pose as the true one) and the RMS reprojection errors [px] of the fits."""

    rig: StereoRig
    rms_left: float
    rms_right: float
    rms_stereo: float


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
    [m]) held around ``centre`` (world frame [m], default: the middle of the needle's volume), as ROS
    ``camera_calibration`` does (each camera alone, then ``stereoCalibrate`` with the intrinsics fixed); the corner
    noise per coordinate is ``reprojection_rms_px / sqrt(2)``."""
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
