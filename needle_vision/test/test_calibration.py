"""Calibration files and camera_info: round trips, recovery of the extrinsics from R/P, clear errors."""
from dataclasses import replace

import numpy as np
import pytest
import yaml

import cv2

from needle_vision.calibration.rig import (CalibrationError, CameraCalibration, CameraInfoRig, StereoRig,
                                           calibration_from_camera_info, camera_calibration_yaml, camera_info_fields,
                                           load_camera_calibration, rig_from_camera_infos)
from needle_common.package_files import share_file

CONFIG = share_file("needle_vision", "config/stereo")  # as installed


def test_yaml_round_trip_is_exact(rig, tmp_path):
    ros = rig.with_ros_rectification()
    path = tmp_path / "left.yaml"
    path.write_text(camera_calibration_yaml(ros.left))
    loaded = load_camera_calibration(path)
    for field in ("camera_matrix", "distortion", "rectification", "projection"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(ros.left, field))
    assert (loaded.width, loaded.height, loaded.distortion_model) == (1440, 1080, "plumb_bob")


def test_camera_info_round_trip_keeps_every_field(rig):
    ros = rig.with_ros_rectification()
    fields = camera_info_fields(ros.right)
    assert set(fields) == {"width", "height", "distortion_model", "d", "k", "r", "p"}
    back = calibration_from_camera_info(fields, "right")
    np.testing.assert_array_equal(back.projection, ros.right.projection)
    np.testing.assert_array_equal(back.distortion, ros.right.distortion)


def test_extrinsics_recovered_from_ros_rectification(rig):
    """R/P as camera_calibration writes them (zero-disparity rectification) encode R, T exactly."""
    ros = rig.with_ros_rectification()
    back = StereoRig.from_camera_calibrations(ros.left, ros.right)
    np.testing.assert_allclose(back.rotation, rig.rotation, atol=1e-12)
    np.testing.assert_allclose(back.translation, rig.translation, atol=1e-12)
    assert back.baseline == pytest.approx(0.15, abs=1e-12)  # cameras 150 mm apart by construction


def test_sample_calibration_files_describe_the_default_rig(rig):
    back = StereoRig.from_camera_calibrations(load_camera_calibration(CONFIG / "left.yaml"),
                                              load_camera_calibration(CONFIG / "right.yaml"))
    np.testing.assert_allclose(back.rotation, rig.rotation, atol=1e-12)
    np.testing.assert_allclose(back.translation, rig.translation, atol=1e-12)
    np.testing.assert_array_equal(back.left.camera_matrix, rig.left.camera_matrix)
    np.testing.assert_array_equal(back.right.distortion, rig.right.distortion)
    vergence = np.degrees(np.arccos((np.trace(rig.rotation) - 1) / 2))
    assert 15 < vergence < 19  # toed in ~8.5° per camera: a verged rig, not a parallel one


def test_monocular_calibrations_are_not_a_stereo_pair(rig):
    with pytest.raises(CalibrationError, match="no baseline"):
        StereoRig.from_camera_calibrations(rig.left, rig.right)  # R = I, P = [K|0] for both


def test_swapped_files_are_reported(rig):
    ros = rig.with_ros_rectification()
    with pytest.raises(CalibrationError, match="swapped"):
        StereoRig.from_camera_calibrations(ros.right, ros.left)


def test_mismatched_rectified_focal_lengths_are_reported(rig):
    ros = rig.with_ros_rectification()
    projection = ros.right.projection.copy()
    projection[0, 0] *= 1.01
    with pytest.raises(CalibrationError, match="not one stereo pair"):
        StereoRig.from_camera_calibrations(ros.left, replace(ros.right, projection=projection))


@pytest.mark.parametrize("side", ["left", "right"])
def test_singular_projection_matrix_is_refused_with_the_field_named(rig, side):
    ros = rig.with_ros_rectification()
    cameras = {"left": ros.left, "right": ros.right}
    projection = cameras[side].projection.copy()
    projection[2, :3] = 0.0  # last row of K' zero: fx', fy' > 0 still, but not invertible
    cameras[side] = replace(cameras[side], projection=projection)
    with pytest.raises(CalibrationError, match=f"\\({side}\\): projection_matrix is singular"):
        StereoRig.from_camera_calibrations(cameras["left"], cameras["right"])


@pytest.mark.parametrize("change, message", [
    ({"camera_matrix": np.zeros((3, 3))}, "fx, fy > 0"),
    ({"distortion": [0.1, 0.2]}, "plumb_bob needs 5"),
    ({"distortion_model": "equidistant", "distortion": [0, 0, 0, 0]}, "not supported"),
    ({"rectification": np.diag([1.0, 1.0, 2.0])}, "not a rotation"),
    ({"width": 0}, "must be positive"),
])
def test_malformed_camera_is_rejected_with_the_field_named(rig, change, message):
    with pytest.raises(CalibrationError, match=message):
        replace(rig.left, **change)


def test_missing_field_and_missing_file_name_the_problem(tmp_path, rig):
    data = yaml.safe_load(camera_calibration_yaml(rig.left))
    del data["camera_matrix"]
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match="camera_matrix"):
        load_camera_calibration(path)
    with pytest.raises(CalibrationError, match="cannot read"):
        load_camera_calibration(tmp_path / "absent.yaml")


def test_uncalibrated_camera_info_is_rejected():
    with pytest.raises(CalibrationError, match="not calibrated"):
        calibration_from_camera_info({"width": 640, "height": 480, "distortion_model": "", "d": [], "k": [0.0] * 9,
                                      "r": [0.0] * 9, "p": [0.0] * 12})


def test_camera_info_object_with_attributes_is_accepted(rig):
    class Info:  # a decoded bag message or an rclpy message: fields as attributes
        pass
    info = Info()
    for key, value in camera_info_fields(rig.left).items():
        setattr(info, key, value)
    assert isinstance(calibration_from_camera_info(info), CameraCalibration)


def _camera_info_from_yaml(path) -> dict:
    """CameraInfo fields as a camera driver fills them from its camera_calibration file (read here with plain
    YAML, not with the package's loader)."""
    data = yaml.safe_load(path.read_text())
    return {"width": data["image_width"], "height": data["image_height"], "distortion_model": data["distortion_model"],
            "d": data["distortion_coefficients"]["data"], "k": data["camera_matrix"]["data"],
            "r": data["rectification_matrix"]["data"], "p": data["projection_matrix"]["data"]}


def _pixels(camera, rotation, translation, points) -> np.ndarray:
    """OpenCV's projection of world points (in the left optical frame) into a raw camera image."""
    return cv2.projectPoints(points, cv2.Rodrigues(rotation)[0], translation.astype(float), camera.camera_matrix,
                             camera.distortion)[0].reshape(-1, 2)


def test_the_rig_from_camera_info_projects_as_the_rig_from_the_calibration_files(rig):
    """The shipped calibration files, published as camera_info, give the rig the files give, and both project
    points into the raw images where the renderer's true rig does."""
    from_files = StereoRig.from_camera_calibrations(load_camera_calibration(CONFIG / "left.yaml"),
                                                    load_camera_calibration(CONFIG / "right.yaml"))
    from_infos = rig_from_camera_infos(_camera_info_from_yaml(CONFIG / "left.yaml"),
                                       _camera_info_from_yaml(CONFIG / "right.yaml"))
    points = np.random.default_rng(0).uniform([-0.1, -0.08, 0.4], [0.1, 0.08, 0.6], (200, 3))  # the needle's volume
    identity, zero = np.eye(3), np.zeros(3)
    for measured in (from_files, from_infos):
        for camera, true_camera, rotation, translation in ((measured.left, rig.left, identity, zero),
                                                           (measured.right, rig.right, measured.rotation,
                                                            measured.translation)):
            truth = _pixels(true_camera, *((identity, zero) if true_camera is rig.left else
                                           (rig.rotation, rig.translation)), points)
            np.testing.assert_allclose(_pixels(camera, rotation, translation, points), truth, atol=1e-3)
    np.testing.assert_array_equal(from_infos.rotation, from_files.rotation)
    np.testing.assert_array_equal(from_infos.translation, from_files.translation)


def test_camera_info_rig_is_remade_only_when_a_camera_info_changes(rig):
    ros = rig.with_ros_rectification()
    infos = CameraInfoRig()
    left, right = camera_info_fields(ros.left), camera_info_fields(ros.right)
    assert infos.offer("left", left) is None  # the right camera not known yet
    first = infos.offer("right", right)
    np.testing.assert_allclose(first.translation, rig.translation, atol=1e-12)
    assert infos.offer("left", dict(left)) is None and infos.offer("right", dict(right)) is None  # the same again
    moved = dict(right, p=(np.array(right["p"]) * [1, 1, 1, 1.1, 1, 1, 1, 1, 1, 1, 1, 1]).tolist())
    np.testing.assert_allclose(infos.offer("right", moved).baseline, 1.1 * rig.baseline, rtol=1e-6)
    with pytest.raises(CalibrationError, match="projection_matrix is singular"):
        infos.offer("right", dict(right, p=[*right["p"][:8], 0.0, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="side"):
        infos.offer("centre", left)
