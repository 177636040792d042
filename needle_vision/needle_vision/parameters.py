"""The parameters of ``needle_stereo`` (and of the offline command): one table with defaults, meanings,
ranges and checks, without ROS. The node declares each with a ``ParameterDescriptor`` built from this table;
the offline command reads the same names from a ROS 2 params file.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import yaml

from needle_vision.background import ContrastThreshold
from needle_vision.centerline import CenterlineConfig
from needle_vision.correspondence import MatchingConfig
from needle_vision.pipeline import StereoConfig
from needle_vision.reconstruction import ReconstructionConfig
from needle_vision.tracking import TrackingConfig
from needle_vision.transform import RigidTransform


class ParameterError(ValueError):
    """A parameter value is invalid; the message names the parameter."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, default (its type is the parameter's type), meaning with unit, valid values."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: Sequence[Any] | None = None
    length: int | None = None
    check: tuple[Callable[[Any], bool], str] | None = None

    def validate(self, value: Any) -> Any:
        """The value if valid, else ParameterError naming the parameter."""
        def fail(reason: str) -> None:
            raise ParameterError(f"parameter '{self.name}' = {value!r}: {reason} ({self.description})")

        expected = type(self.default[0]) if isinstance(self.default, list) else type(self.default)
        values = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value]
        if isinstance(self.default, list) != isinstance(value, (list, tuple, np.ndarray)):
            fail("expected a list" if isinstance(self.default, list) else "expected a single value")
        for v in values:
            numeric = isinstance(v, (int, float)) and not isinstance(v, bool)
            if expected is float and not numeric or expected is int and not (numeric and float(v).is_integer()) \
                    or expected in (str, bool) and not isinstance(v, expected):
                fail(f"expected {expected.__name__}")
            if numeric and not math.isfinite(v):
                fail("must be finite")
            if numeric and self.low is not None and v < self.low:
                fail(f"must be >= {self.low:g}")
            if numeric and self.high is not None and v > self.high:
                fail(f"must be <= {self.high:g}")
        if self.length is not None and len(values) != self.length:
            fail(f"expected {self.length} values, got {len(values)}")
        if self.choices is not None and value not in self.choices:
            fail(f"must be one of {', '.join(map(str, self.choices))}")
        if self.check is not None and not self.check[0](value):
            fail(self.check[1])
        return [expected(v) for v in values] if isinstance(self.default, list) else expected(value)


def _readable_file_or_empty(path: str) -> bool:
    return path == "" or os.path.isfile(path)


def _nonzero_quaternion(pose: list[float]) -> bool:
    return len(pose) == 7 and math.hypot(*pose[3:]) > 1e-9


SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("left_calibration_file", "", "camera_calibration YAML of the left camera; empty: calibration "
              "from the left/camera_info topic", check=(_readable_file_or_empty, "file not found")),
    ParamSpec("right_calibration_file", "", "camera_calibration YAML of the right camera; empty: calibration "
              "from the right/camera_info topic", check=(_readable_file_or_empty, "file not found")),
    ParamSpec("output_frame", "", "frame_id of the published cloud and shape; empty: the left image's frame_id "
              "(raw left optical frame)"),
    ParamSpec("output_transform", [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "fixed pose of the raw left optical "
              "frame in output_frame: x, y, z [m], qx, qy, qz, qw", length=7,
              check=(_nonzero_quaternion, "quaternion must be non-zero")),
    ParamSpec("base_point", [0.0, 0.0, 0.0], "point near the needle base (clamp point A) in output_frame [m]; "
              "the centerline end nearer to it is the base", length=3),
    ParamSpec("image_qos", "sensor_data", "QoS of the image and camera_info subscriptions: sensor_data (best "
              "effort, also matches reliable publishers) or reliable (large images arrive whole or not at all)",
              choices=("sensor_data", "reliable")),
    ParamSpec("sync_tolerance", 0.002, "largest stamp difference of a left/right pair [s]", 0.0, 1.0),
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
    unknown = set(values) - {spec.name for spec in SPECS}
    if unknown:
        raise ParameterError(f"unknown parameter(s): {', '.join(sorted(unknown))}")
    result = {spec.name: spec.validate(values.get(spec.name, spec.default)) for spec in SPECS}
    if result["reconstruction.max_depth"] <= result["reconstruction.min_depth"]:
        raise ParameterError(f"parameter 'reconstruction.max_depth' = {result['reconstruction.max_depth']}: must "
                             f"exceed reconstruction.min_depth = {result['reconstruction.min_depth']}")
    if (result["left_calibration_file"] == "") != (result["right_calibration_file"] == ""):
        raise ParameterError("parameter 'left_calibration_file'/'right_calibration_file': give both files or "
                             "neither (then both cameras' camera_info topics are used)")
    return result


def stereo_config(values: dict[str, Any]) -> StereoConfig:
    """The pipeline settings from validated parameter values."""
    return StereoConfig(
        threshold=ContrastThreshold(polarity=-1 if values["needle_polarity"] == "bright" else 1,
                                    relative=values["detection.relative_threshold"],
                                    absolute=values["detection.absolute_threshold"],
                                    downsample=values["detection.downsample"]),
        centerline=CenterlineConfig(profile_half_width=values["detection.profile_half_width"],
                                    min_profile_fraction=values["detection.min_profile_fraction"],
                                    min_length_px=values["detection.min_length"]),
        matching=MatchingConfig(min_epipolar_angle_deg=values["matching.min_epipolar_angle"],
                                max_epipolar_error_px=values["matching.max_epipolar_error"]),
        reconstruction=ReconstructionConfig(min_depth=values["reconstruction.min_depth"],
                                            max_depth=values["reconstruction.max_depth"],
                                            outlier_sigma=values["reconstruction.outlier_sigma"],
                                            outlier_floor=values["reconstruction.outlier_floor"],
                                            smoothing_length=values["reconstruction.smoothing_length"],
                                            sample_spacing=values["reconstruction.sample_spacing"],
                                            max_length=values["reconstruction.max_length"],
                                            max_image_scatter=values["reconstruction.max_image_scatter"],
                                            base_point=np.array(values["base_point"])),
        background_frames=values["background.frames"],
        background_learning_rate=values["background.learning_rate"],
        tracking=TrackingConfig(values["tracking.window"], values["tracking.max_gap"])
        if values["tracking.enabled"] else None,
        auto_polarity=values["needle_polarity"] == "auto")


def output_from_left(values: dict[str, Any]) -> RigidTransform:
    return RigidTransform.from_xyz_quaternion(values["output_transform"])


def _flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def load_params_file(path: str | Path, node_name: str = "needle_stereo") -> dict[str, Any]:
    """Parameter values of ``node_name`` (or ``/**``) from a ROS 2 params file (nested keys become dotted)."""
    try:
        document = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as error:
        raise ParameterError(f"cannot read params file '{path}': {error}") from error
    values: dict[str, Any] = {}
    for key in ("/**", node_name, "/" + node_name):
        section = document.get(key, {}) if isinstance(document, dict) else {}
        values.update(_flatten(section.get("ros__parameters", {}) if isinstance(section, dict) else {}))
    return values
