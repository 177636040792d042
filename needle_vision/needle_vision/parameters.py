"""The parameters of ``needle_stereo`` and of the offline stereo command (:data:`SPECS`), declared with the suite's
one parameter system (``needle_common.parameters``), and the pipeline settings built from their values.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from needle_common.package_files import resolve_path
from needle_common.parameters import (QOS_CHOICES, TOPIC_CHECK, ParameterError, ParamSpec, unknown_name_error,
                                      valid_topic_name)
from needle_vision.detection.background import ContrastThreshold
from needle_vision.detection.centerline import CenterlineConfig
from needle_vision.matching.correspondence import MatchingConfig
from needle_vision.pipeline import StereoConfig
from needle_vision.matching.reconstruction import ReconstructionConfig
from needle_vision.matching.tracking import TrackingConfig
from needle_common.transforms import nonzero_quaternion


def _readable_file_or_empty(path: str) -> bool:
    try:
        return path == "" or resolve_path(path).is_file()
    except FileNotFoundError:
        return False


SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("left_calibration_file", "", "camera_calibration YAML of the left camera (a path or "
              "package://<package>/<path>); empty: calibration from the left/camera_info topic",
              check=(_readable_file_or_empty, "file not found")),
    ParamSpec("right_calibration_file", "", "camera_calibration YAML of the right camera (a path or "
              "package://<package>/<path>); empty: calibration from the right/camera_info topic",
              check=(_readable_file_or_empty, "file not found")),
    ParamSpec("output_frame", "", "frame_id of the published cloud and shape; empty: the left image's frame_id "
              "(raw left optical frame)"),
    ParamSpec("output_transform", [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "fixed pose of the raw left optical "
              "frame in output_frame (unused when output_frame is empty): x, y, z [m], qx, qy, qz, qw", length=7,
              check=(lambda pose: nonzero_quaternion(pose[3:]), "quaternion must be non-zero")),
    ParamSpec("left_optical_frame", "stereo_left_optical_frame", "TF frame of the raw left optical frame (z forward, "
              "x right, y down; REP 103): child of output_frame on /tf_static, with output_transform"),
    ParamSpec("right_optical_frame", "stereo_right_optical_frame", "TF frame of the raw right optical frame: child "
              "of left_optical_frame on /tf_static, from the stereo calibration"),
    ParamSpec("base_point", [0.0, 0.0, 0.0], "point near the needle base (clamp point A) in output_frame [m]; "
              "the centerline end nearer to it is the base when neither a fresh base pose nor the previous "
              "frame's base is known", length=3),
    ParamSpec("base_pose.topic", "base_pose", "geometry_msgs/PoseStamped of the needle base or holder (the "
              "simulator's base_pose input), in output_frame or the left optical frame; the centerline end "
              "nearer to it is the base; empty: no subscription",
              check=(lambda name: name == "" or valid_topic_name(name), TOPIC_CHECK[1] + " or empty")),
    ParamSpec("base_pose.frame", "needle_base", "TF frame of the needle base (the simulator's frames.base), "
              "looked up in the output frame at each pair's stamp when tf2_ros is installed; empty: no lookup"),
    ParamSpec("base_pose.max_age", 0.1, "a base pose (topic or TF) farther in time from a pair's stamp is not "
              "used; ordering then falls back to the previous frame's base, then to base_point [s]", 0.0, 60.0),
    ParamSpec("base_pose.offset", [0.0, 0.0, 0.0], "the point taken as the base in the base pose's frame [m] "
              "(e.g. the simulator's flange_offset.position for its base_pose topic)", -10.0, 10.0, length=3),
    ParamSpec("image_qos", "sensor_data", "QoS of the image and camera_info subscriptions: sensor_data (best "
              "effort, also matches reliable publishers) or reliable (large images arrive whole or not at all)",
              choices=QOS_CHOICES),
    ParamSpec("image_transport", "raw", "how the cameras publish their images, as image_transport names it: raw "
              "(sensor_msgs/Image on left|right/image_raw) or compressed (sensor_msgs/CompressedImage, JPEG or PNG "
              "as compressed_image_transport writes them, on left|right/image_raw/compressed)",
              choices=("raw", "compressed")),
    ParamSpec("sync_tolerance", 0.002, "largest stamp difference of a left/right pair (approximate time: "
              "message_filters' slop) [s]", 0.0, 1.0),
    ParamSpec("sync_queue_size", 8, "frames per camera waiting for their partner; the oldest beyond it is dropped "
              "without a partner [-]", 1, 1000),
    ParamSpec("needle_polarity", "auto", "whether the needle looks darker or brighter than the background; auto: "
              "decided from the first frame that shows it", choices=("auto", "dark", "bright")),
    ParamSpec("detection.downsample", 4, "factor of the coarse detection image (1, 2, 4 or 8) [-]",
              choices=(1, 2, 4, 8)),
    ParamSpec("detection.relative_threshold", 0.1, "coarse needle threshold: contrast as a fraction of the "
              "local background brightness [-]", 0.005, 1.0),
    ParamSpec("detection.absolute_threshold", 6.0, "coarse needle threshold: smallest contrast [grey levels "
              "of the image]", 0.0, 65535.0),
    ParamSpec("detection.profile_half_width", 4, "half-length of the sub-pixel cross-section slices [px]; "
              "must cover half the needle's blurred image width", 2, 30),
    ParamSpec("detection.min_profile_fraction", 0.75, "slices with less contrast per needle width than this "
              "fraction of the median are dropped (gaps, partly covered slices at the tips) [-]", 0.05, 1.0),
    ParamSpec("detection.min_length", 40.0, "shortest image centerline accepted as a needle [px]", 5.0, 1e5),
    ParamSpec("detection.max_link_angle", 15.0, "image components whose facing ends differ less than this in "
              "direction are one needle with a hidden stretch between them (e.g. an occluder) [deg]", 0.0, 90.0),
    ParamSpec("matching.min_epipolar_angle", 10.0, "smallest angle between needle and epipolar lines for a "
              "point-wise epipolar match; flatter stretches are placed by continuity [deg]", 1.0, 45.0),
    ParamSpec("matching.max_epipolar_error", 1.0, "largest epipolar residual of a matched point "
              "[rectified px]", 0.05, 50.0),
    ParamSpec("reconstruction.min_depth", 0.05, "triangulated points nearer to the left camera are rejected "
              "[m]", 0.0, 1e3),
    ParamSpec("reconstruction.max_depth", 5.0, "triangulated points farther from the left camera are "
              "rejected [m]", 0.0, 1e3),
    ParamSpec("reconstruction.outlier_sigma", 4.0, "robust standard deviations from the smoothed centerline "
              "beyond which a point is an outlier [-]", 1.0, 100.0),
    ParamSpec("reconstruction.outlier_floor", 0.0005, "distances to the smoothed centerline below which a "
              "point is never an outlier [m]", 0.0, 0.1),
    ParamSpec("reconstruction.smoothing_length", 0.008, "arc length of the local cubic fit smoothing the "
              "centerline [m]", 0.0, 0.2),
    ParamSpec("reconstruction.sample_spacing", 0.001, "arc-length step of the published samples [m]",
              1e-4, 0.1),
    ParamSpec("reconstruction.max_length", 0.3, "a measured centerline longer than this is rejected as "
              "implausible (set it to the needle's free length plus a margin) [m]", 1e-3, 10.0),
    ParamSpec("reconstruction.max_image_scatter", 0.5, "image centerlines scattering more than this across the "
              "curve are rejected as low-confidence detections (a needle scatters ~0.05 px) [px]", 0.01, 100.0),
    ParamSpec("reconstruction.max_uncertainty", 0.001, "samples whose 1-sigma uncertainty exceeds this are flagged "
              "unmeasured (uncertainty -1) [m]", 1e-6, 1.0),
    ParamSpec("reconstruction.curve_fit", False, "fit one smooth 3D curve to both views at once (B-spline with a "
              "bending-energy prior; experimental, issue 39) instead of smoothing the per-point "
              "triangulation, which stays its initial guess and fallback"),
    ParamSpec("reconstruction.needle_radius", 0.0, "the needle's radius: each flat end's disc, seen obliquely, "
              "lengthens the images by up to that radius; the ends are moved back by it (0: unknown, not corrected) "
              "[m]", 0.0, 0.01),
    ParamSpec("background.frames", 10, "first synchronised pairs, needle-free, averaged into the background; "
              "0: bootstrap from the first pair by erasing the needle [-]", 0, 100000),
    ParamSpec("background.learning_rate", 0.0, "running update of the background away from the needle per "
              "measured pair; 0: static (costs ~2 ms per pair when > 0) [-]", 0.0, 1.0),
    ParamSpec("tracking.enabled", False, "estimate sample velocities and accelerations across frames and "
              "add vx..vz, ax..az to the cloud"),
    ParamSpec("tracking.window", 5, "frames in the quadratic fit of the tracking [-]", 3, 1000),
    ParamSpec("tracking.max_gap", 0.05, "a longer gap between measured frames restarts tracking [s]", 0.0, 3600.0),
    ParamSpec("debug_image.enabled", True, "publish the debug image (only while someone subscribes)"),
    ParamSpec("debug_image.downsample", 2, "size reduction of the debug image (1, 2, 4 or 8) [-]",
              choices=(1, 2, 4, 8)),
    ParamSpec("warning_period", 2.0, "shortest interval between two warnings of the same kind [s]", 0.01, 3600.0),
)


def validate_all(values: dict[str, Any]) -> dict[str, Any]:
    """All parameters (defaults for missing ones) validated, including checks across parameters."""
    unknown = sorted(set(values) - {spec.name for spec in SPECS})
    if unknown:
        raise unknown_name_error(unknown[0], (spec.name for spec in SPECS))
    result = {spec.name: spec.validate(values.get(spec.name, spec.default)) for spec in SPECS}
    if result["reconstruction.max_depth"] <= result["reconstruction.min_depth"]:
        raise ParameterError(f"parameter 'reconstruction.max_depth' = {result['reconstruction.max_depth']}: must "
                             f"exceed reconstruction.min_depth = {result['reconstruction.min_depth']}")
    if (result["left_calibration_file"] == "") != (result["right_calibration_file"] == ""):
        raise ParameterError("parameter 'left_calibration_file'/'right_calibration_file': give both files or "
                             "neither (then both cameras' camera_info topics are used)")
    return result


#: The ReconstructionConfig fields set from the parameters ``reconstruction.<field>`` of the same name.
_RECONSTRUCTION = tuple(spec.name.removeprefix("reconstruction.") for spec in SPECS
                        if spec.name.startswith("reconstruction."))


def stereo_config(values: dict[str, Any]) -> StereoConfig:
    """The pipeline settings from validated parameter values."""
    return StereoConfig(
        threshold=ContrastThreshold(polarity=-1 if values["needle_polarity"] == "bright" else 1,
                                    relative=values["detection.relative_threshold"],
                                    absolute=values["detection.absolute_threshold"],
                                    downsample=values["detection.downsample"]),
        centerline=CenterlineConfig(profile_half_width=values["detection.profile_half_width"],
                                    min_profile_fraction=values["detection.min_profile_fraction"],
                                    min_length_px=values["detection.min_length"],
                                    max_link_angle_deg=values["detection.max_link_angle"]),
        matching=MatchingConfig(min_epipolar_angle_deg=values["matching.min_epipolar_angle"],
                                max_epipolar_error_px=values["matching.max_epipolar_error"]),
        reconstruction=ReconstructionConfig(**{name: values[f"reconstruction.{name}"] for name in _RECONSTRUCTION},
                                            base_point=np.array(values["base_point"])),
        background_frames=values["background.frames"],
        background_learning_rate=values["background.learning_rate"],
        tracking=TrackingConfig(values["tracking.window"], values["tracking.max_gap"])
        if values["tracking.enabled"] else None,
        auto_polarity=values["needle_polarity"] == "auto")
