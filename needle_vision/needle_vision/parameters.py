"""Parameters of the needle_sim executables, without ROS: one declaration layer and one params-file loader.

:class:`ParamSpec` declares a parameter (name, type given by its default, default, range, choices, meaning with the
unit in brackets); :func:`load_params_file` reads a ROS 2 params file (``/**``, node-name and namespaced sections,
wildcards, several nodes in one file) and checks it as strictly as ``rcl`` does plus the specs' ranges, so a file
that a node would refuse is refused by the offline tools too, with one message naming the file, the parameter and
the problem (:class:`ParameterError`; unknown names suggest the nearest known one; a name like none of a node's
in a shared ``/**`` section or a ``-p`` is only warned about). :func:`check_ros_arguments`
applies it to the ``--params-file`` arguments of a node's command line before ``rclpy.init``. The nodes declare
each spec with a ``ParameterDescriptor`` built from it (ROS side: ``needle_vision.ros.ros_parameters``, used by every
node of the suite).

Below: the parameters of ``needle_stereo`` and of the offline stereo command (:data:`SPECS`).
"""
from __future__ import annotations

import difflib
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, NamedTuple, Sequence

import numpy as np
import yaml

from needle_vision.detection.background import ContrastThreshold
from needle_vision.streams.base_pose import BasePoseStore
from needle_vision.detection.centerline import CenterlineConfig
from needle_vision.matching.correspondence import MatchingConfig
from needle_vision.streams.package_files import resolve_path
from needle_vision.pipeline import StereoConfig
from needle_vision.matching.reconstruction import ReconstructionConfig
from needle_vision.matching.tracking import TrackingConfig
from needle_vision.transform import RigidTransform

# Parameters every rclpy node has (accepted in any node's section).
ROS_BUILTIN = ("use_sim_time", "start_type_description_service")
# Nodes of the suite (a section for another name is probably a typo: warned) and the pipeline tools' section.
KNOWN_NODES = ("needle_simulator", "needle_stereo", "needle_compare", "needle_replay", "needle_pipeline")
_TOPIC_TOKEN = re.compile(r"^(~|[A-Za-z_][A-Za-z0-9_]*|\{[A-Za-z_][A-Za-z0-9_]*\})$")


class ParameterError(ValueError):
    """A parameter value or params file is invalid; the message names the file and parameter."""


def valid_topic_name(name: str) -> bool:
    """A ROS 2 topic name (relative, absolute or private): tokens of letters, digits and '_' not starting with a
    digit, separated by single '/', no trailing '/'."""
    if not isinstance(name, str) or not name or name.endswith("/") and name != "/":
        return False
    tokens = name[1:].split("/") if name.startswith("/") else name.split("/")
    return name != "/" and all(_TOPIC_TOKEN.match(t) for t in tokens) and "~" not in tokens[1:]


TOPIC_CHECK = (valid_topic_name, "not a valid ROS 2 topic name (letters, digits, '_' and '/', no leading digit)")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, default (its type is the parameter's type), meaning with unit, valid values.

    ``low``/``high`` bound numbers (and every element of number arrays); ``choices`` lists valid values;
    ``length`` fixes an array's length; ``check`` is an extra predicate with the message shown when it fails.
    ``dynamic`` parameters may change while a node runs; ``allow_infinite`` admits +-inf (e.g. "no limit").
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: Sequence[Any] | None = None
    length: int | None = None
    check: tuple[Callable[[Any], bool], str] | None = None
    dynamic: bool = False
    allow_infinite: bool = False

    @property
    def is_list(self) -> bool:
        return isinstance(self.default, (list, tuple))

    @property
    def value_type(self) -> type:
        """bool, int, float or str (of the elements, for a list; an empty default list holds floats)."""
        sample = (self.default[0] if self.default else 0.0) if self.is_list else self.default
        return bool if isinstance(sample, bool) else int if isinstance(sample, int) else \
            float if isinstance(sample, float) else str

    def validate(self, value: Any, strict: bool = False) -> Any:
        """The value (converted to the parameter's type) if valid, else ParameterError naming the parameter.
        ``strict``: types as ROS 2 requires them (an integer is no float: write 1.0)."""
        def fail(reason: str) -> None:
            raise ParameterError(f"parameter '{self.name}' = {value!r}: {reason} ({self.description})")

        expected = self.value_type
        is_list = isinstance(value, (list, tuple, np.ndarray))
        if self.is_list != is_list:
            fail(f"expected a list of {expected.__name__}" if self.is_list else "expected a single value")
        values = list(value) if is_list else [value]
        for v in values:
            numeric = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            integral = isinstance(v, (int, np.integer)) and not isinstance(v, bool)
            if expected is float and not (numeric and (integral is False or not strict)) \
                    or expected is int and not (integral or not strict and numeric and float(v).is_integer()) \
                    or expected in (str, bool) and not isinstance(v, expected):
                fail(f"expected {'a list of ' if self.is_list else ''}{expected.__name__}"
                     + (" (write 1.0, not 1)" if expected is float and integral else ""))
            if numeric and math.isnan(v) or numeric and math.isinf(v) and not self.allow_infinite:
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
        return [expected(v) for v in values] if self.is_list else expected(value)


def _set_by_ros(name: str) -> bool:
    """Whether rclpy itself declares the parameter on every node (sim time, QoS overrides)."""
    return name in ROS_BUILTIN or name.startswith("qos_overrides.")


def nearest_name(name: str, known: Iterable[str]) -> str | None:
    """The known name ``name`` is probably a misspelling of (difflib, ratio >= 0.6), if any."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return close[0] if close else None


def unknown_name_error(name: str, known: Iterable[str], where: str = "") -> ParameterError:
    """'unknown parameter X (did you mean Y?)' with the nearest known name (difflib)."""
    close = nearest_name(name, known)
    hint = f" (did you mean '{close}'?)" if close else ""
    return ParameterError(f"{where}unknown parameter '{name}'{hint}")


def _foreign(name: str, known: Iterable[str], where: str, warn: Callable[[str], None]) -> bool:
    """A name given to every node (a ``-p`` or a wildcard section) that resembles none of this node's: another
    package's (e.g. a parent launch's global ``robot_name``), ignored as rclpy ignores it, with a warning naming it.
    False for a probable misspelling (the caller refuses it with the suggestion)."""
    if nearest_name(name, known) is not None:
        return False
    _warn_once(warn, f"{where}parameter '{name}' is not one of this node's (nor close to one): ignored")
    return True


def _readable_file_or_empty(path: str) -> bool:
    if path == "":
        return True
    try:
        return resolve_path(path).is_file()
    except FileNotFoundError:
        return False


def _nonzero_quaternion(pose: list[float]) -> bool:
    return len(pose) == 7 and math.hypot(*pose[3:]) > 1e-9


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
              check=(_nonzero_quaternion, "quaternion must be non-zero")),
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
              choices=("sensor_data", "reliable")),
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
              "prior on the change of bending; experimental, issue 39) instead of smoothing the per-point "
              "triangulation, which stays its initial guess and fallback"),
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
        reconstruction=ReconstructionConfig(min_depth=values["reconstruction.min_depth"],
                                            max_depth=values["reconstruction.max_depth"],
                                            outlier_sigma=values["reconstruction.outlier_sigma"],
                                            outlier_floor=values["reconstruction.outlier_floor"],
                                            smoothing_length=values["reconstruction.smoothing_length"],
                                            sample_spacing=values["reconstruction.sample_spacing"],
                                            max_length=values["reconstruction.max_length"],
                                            max_image_scatter=values["reconstruction.max_image_scatter"],
                                            max_uncertainty=values["reconstruction.max_uncertainty"],
                                            curve_fit=values["reconstruction.curve_fit"],
                                            base_point=np.array(values["base_point"])),
        background_frames=values["background.frames"],
        background_learning_rate=values["background.learning_rate"],
        tracking=TrackingConfig(values["tracking.window"], values["tracking.max_gap"])
        if values["tracking.enabled"] else None,
        auto_polarity=values["needle_polarity"] == "auto")


def base_pose_store(values: dict[str, Any]) -> BasePoseStore:
    """An empty store of base poses with the validated ``base_pose.max_age`` and ``base_pose.offset``."""
    return BasePoseStore(values["base_pose.max_age"], values["base_pose.offset"])


def output_from_left(values: dict[str, Any]) -> RigidTransform:
    """Pose of the raw left optical frame in the output frame: ``output_transform`` when ``output_frame`` is
    set, else the identity (the points stay in the raw left optical frame)."""
    if not values["output_frame"]:
        return RigidTransform()
    return RigidTransform.from_xyz_quaternion(values["output_transform"])




# Declarations used when load_params_file is given none (the stereo node's, for needle_stereo_offline).
NODE_SPECS: dict[str, Sequence[ParamSpec]] = {"needle_stereo": SPECS}


def _print_warning(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


_warned: set[str] = set()


def _warn_once(warn: Callable[[str], None], message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        warn(message)


class _RclLoader(yaml.SafeLoader):
    """YAML as rcl reads params files: also '1e9' and '1.0e9' are floats (YAML 1.1 needs an exponent sign)."""


_RclLoader.add_implicit_resolver("tag:yaml.org,2002:float",
                                 re.compile(r"^[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$"), list("-+0123456789."))


def _read_document(path: Path) -> Any:
    """The parsed YAML of a params file; ParameterError naming the file for every way reading can fail."""
    if not path.exists():
        raise ParameterError(f"params file '{path}': no such file")
    if path.is_dir():
        raise ParameterError(f"params file '{path}': is a directory, not a file")
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as error:
        raise ParameterError(f"params file '{path}': cannot read: {error.strerror or error}") from error
    except UnicodeDecodeError as error:
        raise ParameterError(f"params file '{path}': not UTF-8 text (byte {error.start}); is it a YAML file?"
                             ) from error
    try:
        return yaml.load(text, Loader=_RclLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise ParameterError(f"params file '{path}': malformed YAML{where}: {problem}") from error


def _sections(document: dict, path: Path, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], dict]]:
    """(node name pattern as tokens, ros__parameters tree) of every section, namespaces nested or in the key."""
    found = []
    for key, value in document.items():
        tokens = prefix + tuple(t for t in str(key).split("/") if t)
        name = "/" + "/".join(tokens)
        if key == "ros__parameters":
            if not prefix:
                raise ParameterError(f"params file '{path}': 'ros__parameters' must be under a node name "
                                     "(e.g. '/**:' or 'needle_simulator:')")
            if not isinstance(value, dict):
                raise ParameterError(f"params file '{path}': '{name}/ros__parameters' must be a mapping of "
                                     f"parameter names to values, got {type(value).__name__}")
            found.append((prefix, value))
        elif isinstance(value, dict) and value:
            found += _sections(value, path, tokens)
        else:
            owner = "/" + "/".join(prefix) if prefix else name
            node = prefix[-1] if prefix else key
            raise ParameterError(f"params file '{path}': section '{owner}' has no 'ros__parameters' (expected "
                                 f"'{node}: {{ros__parameters: {{name: value}}}}')")
    return found


def _pattern_matches(pattern: tuple[str, ...], tokens: tuple[str, ...]) -> bool:
    """rcl's node-name wildcards: '**' any number of tokens, '*' within one token."""
    if not pattern:
        return not tokens
    if pattern[0] == "**":
        return any(_pattern_matches(pattern[1:], tokens[k:]) for k in range(len(tokens) + 1))
    if not tokens:
        return False
    regex = "^" + ".*".join(map(re.escape, pattern[0].split("*"))) + "$"
    return bool(re.match(regex, tokens[0])) and _pattern_matches(pattern[1:], tokens[1:])


def _flat_values(tree: dict, path: Path, section: str, prefix: str = "") -> dict[str, Any]:
    """Dotted names -> values, each a scalar or a list of one scalar type as ROS 2 parameters are."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        where = f"params file '{path}', section '{section}': parameter '{name}'"
        if isinstance(value, dict):
            if not value:
                raise ParameterError(f"{where}: empty mapping has no value")
            flat.update(_flat_values(value, path, section, name + "."))
            continue
        items = value if isinstance(value, list) else [value]
        if value is None or any(v is None for v in items):
            raise ParameterError(f"{where}: no value (null)")
        kinds = {type(v) for v in items}
        if not kinds <= {bool, int, float, str}:
            raise ParameterError(f"{where}: lists may hold only numbers, strings or booleans, not "
                                 f"{', '.join(sorted(k.__name__ for k in kinds - {bool, int, float, str}))}")
        if len(kinds) > 1:
            hint = " (write 1.0, not 1)" if kinds == {int, float} else ""
            raise ParameterError(f"{where} = {value!r}: a list must hold one type, not "
                                 f"{' and '.join(sorted(k.__name__ for k in kinds))}{hint}")
        flat[name] = value
    return flat


def load_params_file(path: str | Path, node_name: str = "needle_stereo", specs: Sequence[ParamSpec] | None = None,
                     namespace: str = "/", warn: Callable[[str], None] = _print_warning,
                     known_elsewhere: Iterable[str] = (), require_section: bool = True) -> dict[str, Any]:
    """The values for node ``node_name`` (in ``namespace``) from a ROS 2 params file, dotted names, sections applied in
    file order as rcl does. The whole file is checked as rcl checks it; with ``specs`` (default: :data:`NODE_SPECS`)
    the node's values are validated too: unknown names suggest the nearest known one, except that in a wildcard
    section (``/**``) names in ``known_elsewhere`` belong to other nodes started with the same file and names like
    none of the node's are another package's (warned about and ignored, as rclpy ignores them). An empty file, a
    section for no node of the suite or (``require_section``) a file without a section for this node is warned
    about. Raises ParameterError naming the file."""
    path = Path(path)
    specs = NODE_SPECS.get(node_name) if specs is None else specs
    document = _read_document(path)
    if document is None:
        _warn_once(warn, f"params file '{path}' is empty: no parameters set")
        return {}
    if not isinstance(document, dict):
        raise ParameterError(f"params file '{path}': expected a mapping of node names to "
                             f"{{ros__parameters: ...}}, got {type(document).__name__}")
    fq_tokens = tuple(t for t in namespace.split("/") if t) + (node_name,)
    by_name = {spec.name: spec for spec in specs or ()}
    others = set(known_elsewhere)
    values: dict[str, Any] = {}
    applied = False
    for pattern, tree in _sections(document, path):
        section = "/" + "/".join(pattern)
        flat = _flat_values(tree, path, section)
        if not any(_pattern_matches(pattern, (node,)) or _pattern_matches(pattern, fq_tokens) for node in KNOWN_NODES):
            close = difflib.get_close_matches(pattern[-1], KNOWN_NODES, n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            _warn_once(warn, f"params file '{path}': section '{section}' is for no node of needle_sim{hint}; ignored")
        if not _pattern_matches(pattern, fq_tokens):
            continue
        applied = True
        for name, value in flat.items():
            where = f"params file '{path}', node '{node_name}': "
            if specs is not None and name not in by_name:
                if _set_by_ros(name) or "*" in section and (name in others or _foreign(name, by_name, where, warn)):
                    continue
                raise unknown_name_error(name, by_name, where)
            try:
                values[name] = by_name[name].validate(value, strict=True) if specs is not None else value
            except ParameterError as error:
                raise ParameterError(where + str(error)) from error
    if not applied and require_section:
        _warn_once(warn, f"params file '{path}' has no section for node '{node_name}' (nor '/**'): it sets nothing")
    return values


class RosArguments(NamedTuple):
    """The parts of a command line's ``--ros-args`` that set a node's parameters."""

    params_files: list[str]
    node_name: str | None                   # the __node remap, if any
    namespace: str
    overrides: list[tuple[str | None, str]]  # (node the rule is for, or None for every node; name) of -p/--param


def ros_arguments(argv: Sequence[str]) -> RosArguments:
    """Params files, node name remap, namespace and parameter overrides from the ``--ros-args`` parts of argv."""
    parsed = RosArguments([], None, "/", [])
    inside, k = False, 0
    while k < len(argv):
        arg = argv[k]
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif inside and arg == "--params-file" and k + 1 < len(argv):
            parsed.params_files.append(argv[k + 1])
            k += 1
        elif inside and arg in ("-p", "--param") and k + 1 < len(argv):
            target, _, name = argv[k + 1].partition(":=")[0].rpartition(":")
            parsed.overrides.append((target or None, name))
            k += 1
        elif inside and arg in ("-r", "--remap") and k + 1 < len(argv):
            rule = argv[k + 1].split(":", 1)[-1] if argv[k + 1].count(":=") and ":__" in argv[k + 1] else argv[k + 1]
            if rule.startswith("__node:="):
                parsed = parsed._replace(node_name=rule.split(":=", 1)[1])
            elif rule.startswith("__ns:="):
                parsed = parsed._replace(namespace=rule.split(":=", 1)[1])
            k += 1
        k += 1
    return parsed


def check_ros_arguments(argv: Sequence[str], node_name: str, specs: Sequence[ParamSpec] | None,
                        warn: Callable[[str], None] = _print_warning, known_elsewhere: Iterable[str] = ()) -> None:
    """Check every ``--params-file`` of a node's command line with :func:`load_params_file` before rclpy reads
    it (rcl's own parser would fail with a traceback), and the names of its ``-p name:=value`` overrides (rclpy
    would ignore an undeclared one silently); raises ParameterError. A ``-p`` rule without a node prefix reaches
    every node started with the command line: names in ``known_elsewhere`` belong to the others. A ``-p`` name
    (and a wildcard section's) that resembles none of the node's is warned about and ignored; a misspelling of one
    is refused with the suggestion."""
    parsed = ros_arguments(argv)
    node = parsed.node_name or node_name
    for path in parsed.params_files:
        load_params_file(path, node, specs, parsed.namespace, warn, known_elsewhere)
    names = {spec.name for spec in (NODE_SPECS.get(node) if specs is None else specs) or ()}
    others = set(known_elsewhere)
    for target, name in parsed.overrides:
        if not names or target not in (None, node) or name in names or _set_by_ros(name) \
                or target is None and name in others:
            continue
        where = f"parameter override '-p {name}:=...' for node '{node}': "
        if not _foreign(name, names, where, warn):
            raise unknown_name_error(name, names, where)
