"""Parameter table: validation with the parameter named, the sample params file, the pipeline settings."""
import cv2
import numpy as np
import pytest

from needle_common.package_files import share_file
from needle_common.parameters import ParameterError, check_ros_arguments, load_params_file
from needle_vision.calibration.rectification import Rectification
from needle_vision.calibration.rig import CalibrationError, camera_info_fields
from needle_vision.front_end import StereoFrontEnd
from needle_vision.parameters import SPECS, stereo_config, validate_all

CONFIG = share_file("needle_vision", "config/needle_stereo.yaml")  # as installed


def test_every_parameter_has_a_description_with_meaning():
    for spec in SPECS:
        assert len(spec.description) > 20, spec.name
        spec.validate(spec.default)  # defaults are valid


def test_sample_params_file_is_complete_and_valid(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # the calibration files are found through the package, from any directory
    values = load_params_file(CONFIG, "needle_stereo", SPECS)
    assert set(values) == {spec.name for spec in SPECS}  # every parameter is documented in the sample
    validated = validate_all(values)
    config = stereo_config(validated)
    assert config.threshold.polarity == 1 and config.background_frames == 10 and config.tracking is None
    text = CONFIG.read_text()
    for spec in SPECS:  # every parameter line has a comment above it
        leaf = spec.name.split(".")[-1]
        line = next(k for k, line in enumerate(text.splitlines()) if line.strip().startswith(leaf + ":"))
        assert "#" in "\n".join(text.splitlines()[max(line - 3, 0):line]), spec.name


@pytest.mark.parametrize("name, value, message", [
    ("sync_tolerance", -0.1, "must be >= 0"),
    ("detection.downsample", 3, "must be one of 1, 2, 4, 8"),
    ("needle_polarity", "grey", "must be one of auto, dark, bright"),
    ("output_transform", [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "quaternion must be non-zero"),
    ("base_point", [0.0, 0.0], "expected 3 values"),
    ("reconstruction.sample_spacing", float("nan"), "must be finite"),
    ("tracking.window", 2.5, "expected int"),
    ("left_calibration_file", "/nonexistent.yaml", "file not found"),
])
def test_bad_values_name_the_parameter(name, value, message):
    with pytest.raises(ParameterError, match=f"parameter '{name}'.*{message}"):
        validate_all({name: value})


def test_cross_checks():
    with pytest.raises(ParameterError, match="reconstruction.max_depth"):
        validate_all({"reconstruction.min_depth": 2.0, "reconstruction.max_depth": 1.0})
    with pytest.raises(ParameterError, match="give both files"):
        validate_all({"left_calibration_file": str(CONFIG)})
    with pytest.raises(ParameterError, match="unknown parameter"):
        validate_all({"detection.downsampling": 4})


def test_tracking_and_polarity_reach_the_pipeline_config():
    config = stereo_config(validate_all({"tracking.enabled": True, "tracking.window": 7, "needle_polarity": "bright",
                                         "base_point": [0.1, 0.2, 0.3], "detection.max_link_angle": 25.0}))
    assert config.tracking.window == 7 and config.threshold.polarity == -1
    assert config.centerline.max_link_angle_deg == 25.0
    np.testing.assert_array_equal(config.reconstruction.base_point, [0.1, 0.2, 0.3])


def test_a_command_line_override_of_an_unknown_name_is_refused_naming_the_nearest_one():
    """rclpy ignores ``-p name:=value`` for a parameter the node does not declare: a typo would go unnoticed."""
    with pytest.raises(ParameterError, match=r"'-p detection.min_lenght:=\.\.\.'.*did you mean 'detection.min_length'"):
        check_ros_arguments(["needle_stereo", "--ros-args", "-p", "detection.min_lenght:=0.01"], "needle_stereo", SPECS)
    # A name like none of the node's (a parent launch's global robot_name): a warning naming it, as rclpy ignores it.
    warnings = []
    check_ros_arguments(["x", "--ros-args", "--param", "needle_stereo:robot_name:=1"], "needle_stereo", SPECS,
                        warnings.append)
    assert len(warnings) == 1 and "'robot_name'" in warnings[0] and "ignored" in warnings[0]
    accepted = [["x", "--ros-args", "-p", "detection.min_length:=0.01", "-p", "use_sim_time:=true",
                 "-p", "qos_overrides./needle/measured_shape.publisher.depth:=5"],
                ["x", "--ros-args", "-p", "needle_simulator:needle.lenght:=0.2"],   # a rule for another node
                ["x", "-p", "nosuch:=1"],                                            # not a ROS argument
                ["x", "--ros-args", "-r", "__node:=cam", "-p", "needle_stereo:nosuch:=1"]]  # renamed node
    for argv in accepted:
        check_ros_arguments(argv, "needle_stereo", SPECS)
    # started together (bringup), a rule without a node prefix reaches every node: names of the others are theirs
    check_ros_arguments(["x", "--ros-args", "-p", "needle.length:=0.2"], "needle_stereo", SPECS,
                        known_elsewhere={"needle.length"})


def test_a_shared_section_may_hold_other_packages_names_but_not_misspellings_of_ours(tmp_path):
    """``/**`` (e.g. a parent launch's SetParameter): a name like none of the node's is warned about and ignored; a
    misspelling of one stays fatal with the suggestion, and a section for this node alone stays strict."""
    path = tmp_path / "shared.yaml"
    path.write_text("/**:\n  ros__parameters:\n    robot_name: psm1\n    detection.min_length: 10.0\n")
    warnings = []
    assert load_params_file(path, "needle_stereo", SPECS, warn=warnings.append) == {"detection.min_length": 10.0}
    assert any("'robot_name'" in w for w in warnings), warnings
    path.write_text("/**:\n  ros__parameters:\n    detection.min_lenght: 10.0\n")
    with pytest.raises(ParameterError, match="did you mean 'detection.min_length'"):
        load_params_file(path, "needle_stereo", SPECS, warn=warnings.append)
    path.write_text("needle_stereo:\n  ros__parameters:\n    robot_name: psm1\n")
    with pytest.raises(ParameterError, match="unknown parameter 'robot_name'"):
        load_params_file(path, "needle_stereo", SPECS, warn=warnings.append)


def test_the_front_end_builds_the_pipeline_of_node_and_offline_tools_and_refuses_an_unusable_rig(rig, monkeypatch,
                                                                                                  tmp_path):
    """Calibration files (a missing one: ParameterError naming the parameters), else both camera_infos (rebuilt only
    on a change); a rig that OpenCV cannot rectify: CalibrationError and no pipeline, one line for every caller."""
    monkeypatch.chdir(tmp_path)
    values = validate_all(load_params_file(CONFIG, "needle_stereo", SPECS))
    assert StereoFrontEnd(values).pipeline.rig.left.width == 1440
    with pytest.raises(ParameterError, match="'left_calibration_file'/'right_calibration_file': .*missing.yaml"):
        StereoFrontEnd(dict(values, left_calibration_file=str(tmp_path / "missing.yaml")))
    front = StereoFrontEnd(validate_all({"base_pose.max_age": 0.5}))
    ros = rig.with_ros_rectification()
    assert front.pipeline is None and front.on_camera_info("left", camera_info_fields(ros.left)) is None
    assert front.on_camera_info("right", camera_info_fields(ros.right)) is not None
    assert front.pipeline.base_poses is front.base_poses and front.base_poses.max_age == 0.5

    def fails(rig):
        raise cv2.error("stereoRectify: bad input")
    monkeypatch.setattr(Rectification, "from_rig", fails)
    moved = dict(camera_info_fields(ros.right), width=1441)
    with pytest.raises(CalibrationError, match="cannot be rectified: .*stereoRectify"):
        front.on_camera_info("right", moved)
    assert front.pipeline is None
