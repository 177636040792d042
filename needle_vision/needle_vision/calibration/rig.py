"""Stereo calibration of the two cameras of seed 000, Sec. III-A, as ROS stores it.

A camera is described by its ``camera_info`` (``camera_calibration`` YAML file or ``sensor_msgs/CameraInfo``):
intrinsics ``K``, distortion ``D``, and the stereo rectification ``R`` and projection ``P``. The two cameras'
``R``/``P`` together encode the extrinsics; :meth:`StereoRig.from_camera_calibrations` recovers the rotation and
translation between the raw optical frames from them, so the pipeline can re-rectify the rig its own way (see
:mod:`needle_vision.calibration.rectification`) and never assumes parallel cameras.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np
import yaml

from needle_common.message_fields import field_getter
from needle_common.package_files import resolve_path
from needle_common.transforms import RigidTransform

#: Distortion models of ``sensor_msgs/CameraInfo`` handled by OpenCV's standard camera model -> allowed lengths.
DISTORTION_MODELS = {"plumb_bob": (5,), "rational_polynomial": (8, 12, 14)}


class CalibrationError(ValueError):
    """Missing, malformed or inconsistent calibration; the message says which camera and which field."""


def _matrix(values: Any, shape: tuple[int, int], what: str) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.size != shape[0] * shape[1]:
        raise CalibrationError(f"{what}: expected {shape[0]}x{shape[1]} values, got {array.size}")
    array = array.reshape(shape)
    if not np.all(np.isfinite(array)):
        raise CalibrationError(f"{what}: values must be finite")
    return array


def _check_rotation(rotation: np.ndarray, what: str) -> None:
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5) or np.linalg.det(rotation) <= 0:
        raise CalibrationError(f"{what}: not a rotation matrix")


@dataclass(frozen=True)
class CameraCalibration:
    """One camera's ``camera_info``: image size [px], ``K`` (3x3), distortion, ``R`` (3x3) and ``P`` (3x4)."""

    width: int
    height: int
    camera_matrix: np.ndarray
    distortion: np.ndarray
    distortion_model: str = "plumb_bob"
    rectification: np.ndarray = field(default_factory=lambda: np.eye(3))
    projection: np.ndarray | None = None  # None: [K | 0] (monocular)
    camera_name: str = "camera"

    def __post_init__(self) -> None:
        name = self.camera_name
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CalibrationError(f"camera '{name}': image size {self.width}x{self.height} must be positive")
        k = _matrix(self.camera_matrix, (3, 3), f"camera '{name}' camera_matrix")
        if k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], [0, 0, 1]) or k[1, 0] != 0 or k[0, 1] != 0:
            raise CalibrationError(f"camera '{name}' camera_matrix: needs fx, fy > 0, zero skew, last row 0 0 1")
        if self.distortion_model not in DISTORTION_MODELS:
            raise CalibrationError(f"camera '{name}': distortion_model '{self.distortion_model}' is not supported "
                                   f"(supported: {', '.join(DISTORTION_MODELS)})")
        d = np.asarray(self.distortion, dtype=float).ravel()
        if d.size not in DISTORTION_MODELS[self.distortion_model] or not np.all(np.isfinite(d)):
            raise CalibrationError(f"camera '{name}': {self.distortion_model} needs "
                                   f"{' or '.join(map(str, DISTORTION_MODELS[self.distortion_model]))} finite "
                                   f"distortion coefficients, got {d.size}")
        r = _matrix(self.rectification, (3, 3), f"camera '{name}' rectification_matrix")
        _check_rotation(r, f"camera '{name}' rectification_matrix")
        p = np.hstack([k, np.zeros((3, 1))]) if self.projection is None else \
            _matrix(self.projection, (3, 4), f"camera '{name}' projection_matrix")
        if p[0, 0] <= 0 or p[1, 1] <= 0:
            raise CalibrationError(f"camera '{name}' projection_matrix: needs fx', fy' > 0")
        for attribute, value in (("width", int(self.width)), ("height", int(self.height)), ("camera_matrix", k),
                                 ("distortion", d), ("rectification", r), ("projection", p)):
            object.__setattr__(self, attribute, value)

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) [px], the order OpenCV expects."""
        return self.width, self.height


# --- camera_calibration YAML and sensor_msgs/CameraInfo -----------------------------------------------------

def load_camera_calibration(path: str | Path) -> CameraCalibration:
    """Read a ``camera_calibration`` YAML file (``image_width``, ``camera_matrix: {rows, cols, data}``, ...); the path
    may be a ``package://<package>/<path>`` name (:mod:`needle_common.package_files`)."""
    try:
        path = resolve_path(path)
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise CalibrationError(f"cannot read calibration file '{path}': {error}") from error
    if not isinstance(data, dict):
        raise CalibrationError(f"calibration file '{path}' is not a YAML mapping")
    try:
        return CameraCalibration(
            width=data["image_width"], height=data["image_height"],
            camera_matrix=data["camera_matrix"]["data"],
            distortion=data["distortion_coefficients"]["data"],
            distortion_model=data.get("distortion_model", "plumb_bob"),
            rectification=data.get("rectification_matrix", {"data": np.eye(3).ravel().tolist()})["data"],
            projection=data["projection_matrix"]["data"] if "projection_matrix" in data else None,
            camera_name=str(data.get("camera_name", path.stem)))
    except (KeyError, TypeError) as error:
        raise CalibrationError(f"calibration file '{path}': missing or malformed field {error}") from error
    except CalibrationError as error:
        raise CalibrationError(f"calibration file '{path}': {error}") from error


def camera_calibration_yaml(calibration: CameraCalibration) -> str:
    """The YAML text ``camera_calibration`` writes for this camera."""
    def block(matrix: np.ndarray) -> dict:
        matrix = np.atleast_2d(matrix)
        return {"rows": matrix.shape[0], "cols": matrix.shape[1], "data": [float(v) for v in matrix.ravel()]}
    return yaml.safe_dump({
        "image_width": calibration.width, "image_height": calibration.height,
        "camera_name": calibration.camera_name,
        "camera_matrix": block(calibration.camera_matrix),
        "distortion_model": calibration.distortion_model,
        "distortion_coefficients": block(calibration.distortion[None, :]),
        "rectification_matrix": block(calibration.rectification),
        "projection_matrix": block(calibration.projection)}, sort_keys=False, default_flow_style=None)


def camera_info_fields(calibration: CameraCalibration) -> dict[str, Any]:
    """The ``sensor_msgs/CameraInfo`` fields (without header) as plain Python values."""
    return {"width": calibration.width, "height": calibration.height,
            "distortion_model": calibration.distortion_model, "d": calibration.distortion.tolist(),
            "k": calibration.camera_matrix.ravel().tolist(), "r": calibration.rectification.ravel().tolist(),
            "p": calibration.projection.ravel().tolist()}


def calibration_from_camera_info(info: Mapping[str, Any] | Any, camera_name: str = "camera") -> CameraCalibration:
    """From ``sensor_msgs/CameraInfo`` fields, given as a mapping or any object with those attributes."""
    get = field_getter(info)
    k = np.asarray(get("k"), dtype=float)
    if k.size != 9 or not np.any(k):
        raise CalibrationError(f"camera '{camera_name}': camera_info has no intrinsics (K is empty or zero): "
                               "the camera is not calibrated")
    p = np.asarray(get("p"), dtype=float)
    return CameraCalibration(width=int(get("width")), height=int(get("height")), camera_matrix=k,
                             distortion=np.asarray(get("d"), dtype=float),
                             distortion_model=str(get("distortion_model")) or "plumb_bob",
                             rectification=np.asarray(get("r"), dtype=float) if np.any(get("r")) else np.eye(3),
                             projection=p if np.any(p) else None, camera_name=camera_name)


# --- the stereo rig -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class StereoRig:
    """Two calibrated cameras and the rigid motion between their raw optical frames.

    ``rotation``/``translation``: ``x_right = rotation @ x_left + translation`` [m] (OpenCV's ``R``, ``T``).
    ``world_from_left``: pose of the left optical frame in a world frame (used by the renderer; the measurement
    reports in the left optical frame or the frame configured by the node).
    """

    left: CameraCalibration
    right: CameraCalibration
    rotation: np.ndarray
    translation: np.ndarray
    world_from_left: RigidTransform = field(default_factory=RigidTransform)

    def __post_init__(self) -> None:
        rotation = _matrix(self.rotation, (3, 3), "stereo rotation")
        _check_rotation(rotation, "stereo rotation")
        translation = _matrix(self.translation, (3, 1), "stereo translation").ravel()
        if np.linalg.norm(translation) < 1e-6:
            raise CalibrationError("stereo translation: the baseline is zero (the two cameras coincide)")
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "translation", translation)

    @property
    def baseline(self) -> float:
        """Distance between the two optical centres [m]."""
        return float(np.linalg.norm(self.translation))

    @property
    def left_from_right(self) -> RigidTransform:
        """Pose of the right optical frame in the left one."""
        return RigidTransform(self.rotation, self.translation).inverse()

    @classmethod
    def from_camera_calibrations(cls, left: CameraCalibration, right: CameraCalibration,
                                 world_from_left: RigidTransform | None = None) -> "StereoRig":
        """Recover the extrinsics from the two cameras' rectification ``R`` and projection ``P``.

        ROS stereo calibration stores ``R_i`` (raw -> common rectified orientation) and ``P_i = K'[I | t_i]``
        with ``t_left = 0``. Hence ``x_rect = R_l x_l`` and ``x_rect + t_r = R_r x_r`` give
        ``rotation = R_rᵀ R_l`` and ``translation = R_rᵀ t_r`` with ``t_r = K'^-1 P_r[:, 3]``.
        """
        if np.linalg.norm(left.projection[:, 3]) > 1e-9 * max(1.0, np.abs(left.projection).max()):
            raise CalibrationError(f"camera '{left.camera_name}' (left): projection_matrix has a non-zero 4th "
                                   "column; left and right calibration files may be swapped")
        for side, camera in (("left", left), ("right", right)):
            if np.linalg.cond(camera.projection[:, :3]) > 1e12:
                raise CalibrationError(f"camera '{camera.camera_name}' ({side}): projection_matrix is singular "
                                       "(its first three columns K' are not invertible)")
        t_right = np.linalg.solve(right.projection[:, :3], right.projection[:, 3])
        if np.linalg.norm(t_right) < 1e-6:
            raise CalibrationError(f"camera '{right.camera_name}' (right): projection_matrix has no baseline "
                                   "(P[0,3] and P[1,3] are zero): this is a monocular calibration, not a stereo one")
        if not np.allclose(left.projection[:2, :2], right.projection[:2, :2], rtol=1e-6, atol=1e-9):
            raise CalibrationError(f"cameras '{left.camera_name}' and '{right.camera_name}': the projection "
                                   "matrices have different rectified focal lengths; they are not one stereo pair")
        if abs(t_right[2]) > 1e-6 * np.linalg.norm(t_right):
            raise CalibrationError(f"camera '{right.camera_name}': projection_matrix has a translation along the "
                                   "optical axis (P[2,3] != 0), which no rectified stereo pair has")
        return cls(left, right, right.rectification.T @ left.rectification, right.rectification.T @ t_right,
                   world_from_left or RigidTransform())

    def with_ros_rectification(self) -> "StereoRig":
        """This rig with ``R``/``P`` filled as ROS ``camera_calibration`` writes them (``stereoRectify`` with
        ``CALIB_ZERO_DISPARITY`` and ``alpha = 0``): the form of the calibration files and ``camera_info``."""
        r1, r2, p1, p2, *_ = cv2.stereoRectify(
            self.left.camera_matrix, self.left.distortion, self.right.camera_matrix, self.right.distortion,
            self.left.image_size, self.rotation, self.translation.reshape(3, 1),  # OpenCV 5 needs a 3x1 T
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0)
        return replace(self, left=replace(self.left, rectification=r1, projection=p1),
                       right=replace(self.right, rectification=r2, projection=p2))


# --- the rig from camera_info topics ------------------------------------------------------------------------

def rig_from_camera_infos(left: Mapping[str, Any] | Any, right: Mapping[str, Any] | Any) -> StereoRig:
    """The rig of the two cameras' ``sensor_msgs/CameraInfo`` (message objects or mappings of their fields);
    CalibrationError names the camera and field when they do not make a stereo pair."""
    try:
        return StereoRig.from_camera_calibrations(calibration_from_camera_info(left, "left"),
                                                  calibration_from_camera_info(right, "right"))
    except (cv2.error, np.linalg.LinAlgError) as error:
        raise CalibrationError(f"camera_info: {error}") from error


class CameraInfoRig:
    """The rig of the latest ``camera_info`` of each camera, remade only when one of them changes (cameras publish
    the same calibration with every frame)."""

    FIELDS = ("width", "height", "distortion_model", "d", "k", "r", "p")

    def __init__(self) -> None:
        self._infos: dict[str, Any] = {}
        self._keys: dict[str, tuple] = {}

    def offer(self, side: str, info: Mapping[str, Any] | Any) -> StereoRig | None:
        """Take ``side``'s camera_info; the new rig when both cameras are known and this one changed, else None.
        CalibrationError when the two do not make a stereo rig (once per change)."""
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        get = field_getter(info)
        key = tuple(str(get(name)) if name == "distortion_model" else tuple(np.asarray(get(name), float).ravel())
                    for name in self.FIELDS)
        if self._keys.get(side) == key:
            return None
        self._infos[side], self._keys[side] = info, key
        if len(self._infos) < 2:
            return None
        return rig_from_camera_infos(self._infos["left"], self._infos["right"])
