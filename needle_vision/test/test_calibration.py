"""Calibration files and camera_info: round trips, recovery of the extrinsics from R/P, clear errors."""
from dataclasses import replace

import numpy as np
import pytest
import yaml

from needle_vision.calibration.rig import (CalibrationError, CameraCalibration, StereoRig, calibration_from_camera_info,
                                           camera_calibration_yaml, camera_info_fields, load_camera_calibration)
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
