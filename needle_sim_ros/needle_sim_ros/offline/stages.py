"""The three pipeline nodes as message-in/message-out stages for the offline pipeline (no executor, no threads).

Each stage holds the same ROS-free core as its node and translates messages exactly as the node does:

* :class:`SimulatorStage` — ``needle_simulator`` in simulated time: :class:`NeedleSimulation` advanced
  deterministically (up to min(clock, newest pose stamp)), a ``wrench`` per step (base frame) and a ``needle/shape``
  at ``rates.shape_hz``. The node publishes shapes when its clock passes the due time; here they are due on the same
  rate counted in integration steps from the first pose, so that a measurement stamped on that grid meets a model
  shape of the very same instant. The two high-rate outputs are serialized straight from arrays
  (:mod:`needle_sim_ros.messages.cdr`, :mod:`needle_common.cdr`).
* :class:`StereoStage` — ``needle_stereo``: its images (raw, or image_transport's compressed topics), left/right
  pairing by approximate time and :class:`needle_vision.pipeline.StereoNeedlePipeline`, publishing
  ``needle/measured_shape``.
* :class:`ComparisonStage` — ``needle_compare``: stamp pairing, extrinsic and centerline distances
  (:mod:`needle_sim_ros.comparison`), publishing ``shape_error``.
"""
from __future__ import annotations

import math
import time
from collections import Counter
from typing import Any, NamedTuple

import numpy as np

from geometry_msgs.msg import TwistStamped, WrenchStamped
from needle_interfaces.msg import NeedleShape
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from needle_vision.calibration.rig import CalibrationError
from needle_vision.streams.image_codec import ImageFormatError, SerializedImage
from needle_vision.streams.pairing import StampPairer as FramePairer
from needle_common.bag_reader import absolute_topic
from needle_common.cdr import PoseStamped, needle_shape
from needle_common.parameters import ParameterError
from needle_vision.front_end import StereoFrontEnd
from needle_vision.parameters import validate_all
from needle_vision.pipeline import FrameStatus

from needle_sim_ros.comparison import ComparedPair, ComparisonSession
from needle_sim_ros.inputs import USED_POSES, InputRejected, SimulatorInputs
from needle_sim_ros.messages import cdr
from needle_sim_ros.messages.centerline_display import ComparisonDisplay
from needle_sim_ros.messages.shape import Stamp, Tag, shape_arrays, shape_error_cdr, stamp_ns, stamp_of
from needle_sim_ros.model import ModelShape
from needle_sim_ros.simulation import simulation_from_parameters, step_wrenches


class MeasuredShape(NamedTuple):
    """A ``needle/measured_shape``: its header, centerline and serialized NeedleShape."""

    header: Header | Tag
    points: np.ndarray
    arc_length: np.ndarray
    data: bytes

    @classmethod
    def recorded(cls, msg: NeedleShape, data: bytes) -> "MeasuredShape":
        """A recorded one (``msg`` decoded from ``data``)."""
        points, arc_length, _ = shape_arrays(msg)
        return cls(msg.header, points, arc_length, data)


class SimulatorStage:
    """``needle_simulator`` on recorded input, deterministically, built by
    :func:`needle_sim_ros.simulation.simulation_from_parameters` as in the node (offline every step is integrated:
    no ``loop.max_catch_up``)."""

    def __init__(self, p: dict[str, Any]) -> None:
        self.p = p
        self.sim = simulation_from_parameters(p)
        self.sim.max_catch_up = math.inf
        self.inputs = SimulatorInputs(self.sim, p["frames.world"], p["frames.base"])  # simulated time: stamps kept
        self.shape_every = max(1, int(round(1.0 / (p["rates.shape_hz"] * p["integrator.dt"]))))
        self.rejected: Counter[str] = Counter()
        self.core_seconds = 0.0  # wall time in NeedleSimulation.advance (base trajectory, steps, reaction wrench)
        self._steps_since_start = 0

    # --- inputs (as NeedleSimulatorNode.on_pose / on_tip_load in simulated time) ------------------------------
    def on_pose(self, pose: PoseStamped, now_ns: int) -> None:
        started = self.sim.started
        try:
            verdict = self.inputs.offer_pose(pose.frame_id, pose.stamp_ns * 1e-9, pose.position, pose.orientation,
                                             now_ns * 1e-9).verdict
        except InputRejected as error:
            self.rejected[error.kind] += 1
            return
        if not started and self.sim.started:
            self._steps_since_start = 0
        if verdict not in USED_POSES:
            self.rejected[f"base pose {verdict.value}"] += 1

    def on_twist(self, msg: TwistStamped, now_ns: int) -> None:
        try:
            self.inputs.on_twist(msg, now_ns * 1e-9)
        except InputRejected as error:
            self.rejected[error.kind] += 1

    def on_tip_load(self, msg: WrenchStamped, now_ns: int) -> None:
        try:
            self.inputs.on_tip_load(msg)
        except InputRejected as error:
            self.rejected[error.kind] += 1

    # --- outputs ---------------------------------------------------------------------------------------------
    def advance(self, now_ns: int) -> tuple[list[bytes], list[tuple[int, ModelShape]]]:
        """Integrate up to the clock ``now_ns`` (deterministic rule); returns the CDR bytes of a WrenchStamped (base
        frame) per step and, per shape period, a :class:`ModelShape` with the number of steps before it."""
        if not self.sim.started:
            return [], []
        start = time.perf_counter()
        records = self.sim.advance(now_ns * 1e-9, deterministic=True)
        self.core_seconds += time.perf_counter() - start
        if not records:
            return [], []
        wrenches = cdr.wrench_stamped_many(self.p["frames.base"], step_wrenches(records))
        first = self.shape_every - self._steps_since_start % self.shape_every
        self._steps_since_start += len(wrenches)
        return wrenches, [(steps, self.sim.shape(self.p["output.shape_samples"]))
                          for steps in range(first, len(wrenches) + 1, self.shape_every)]

    def statistics(self) -> dict[str, Any]:
        stats = self.sim.statistics
        return {"steps": stats.steps, "failed_steps": stats.failed_steps, "skipped_time_s": stats.skipped_time,
                "max_newton_iterations": stats.max_newton_iterations, **stats.take_step_time_ms(empty=None),
                "rejected_inputs": dict(self.rejected)}


class StereoStage:
    """``needle_stereo`` (:mod:`needle_vision.ros.stereo_node`) on recorded images."""

    def __init__(self, values: dict[str, Any]) -> None:
        self.values = values
        self.front = StereoFrontEnd(values)
        self.pairer = FramePairer(values["sync_tolerance"], values["sync_queue_size"])
        self.outcomes: Counter[str] = Counter()
        #: the bag's image topics the node subscribes to (image_transport's names)
        suffix = "/compressed" if values["image_transport"] == "compressed" else ""
        self.image_topics = (f"/left/image_raw{suffix}", f"/right/image_raw{suffix}")

    @property
    def base_pose_topic(self) -> str:
        """The absolute topic of the node's ``base_pose.topic`` subscription (a bag's root namespace), or ''."""
        return absolute_topic(self.values["base_pose.topic"]) if self.values["base_pose.topic"] else ""

    def on_base_pose(self, pose: PoseStamped) -> None:
        """As the node: the base pose stored in the output frame; an unusable one is counted."""
        try:
            self.front.add_base_pose(pose)
        except ValueError as error:
            self.outcomes[f"base pose ignored: {error}"] += 1

    @property
    def has_background(self) -> bool:
        return self.front.pipeline is not None and self.front.pipeline.backgrounds is not None

    def on_camera_info(self, side: str, msg: CameraInfo) -> None:
        """As the node: (re)build the pipeline when both cameras' calibrations are known and one changed."""
        try:
            self.front.on_camera_info(side, msg)
        except CalibrationError:
            self.outcomes["camera_info unusable"] += 1

    def on_image(self, side: str, image: SerializedImage) -> list[MeasuredShape]:
        pair = self.pairer.push(side, image.stamp, image)
        if pair is None:
            return []
        pipeline = self.front.pipeline
        if pipeline is None:
            self.outcomes["skipped: no calibration yet"] += 1
            return []
        left = pair.left
        self.front.image_frame = left.frame_id
        try:
            images = [left.gray(), pair.right.gray()]
        except ImageFormatError:
            self.outcomes["skipped: decode error"] += 1
            return []
        result = pipeline.process(pair.stamp, *images)
        rejected = result.status is FrameStatus.REJECTED
        self.outcomes[f"rejected: {result.reason}" if rejected else result.status.value] += 1
        if result.status is not FrameStatus.MEASURED:
            return []
        m = result.measurement
        frame = self.values["output_frame"] or left.frame_id
        data = needle_shape(left.sec, left.nanosec, frame, NeedleShape.SOURCE_STEREO, m.points, m.tangents,
                            m.arc_length, uncertainty=m.uncertainty)
        return [MeasuredShape(Tag(Stamp(left.sec, left.nanosec), frame), m.points, m.arc_length, data)]

    def statistics(self) -> dict[str, Any]:
        return {"pairs": dict(self.outcomes), "unpaired_frames": self.pairer.dropped}


class ComparisonStage:
    """``needle_compare`` (:mod:`needle_sim_ros.nodes.compare_node`) on the model and measured shapes: the same
    :class:`needle_sim_ros.comparison.ComparisonSession`."""

    def __init__(self, v: dict[str, Any]) -> None:
        if v["measured_input"] != "shape":
            raise ParameterError("needle_compare: the offline pipeline compares measured/shape only "
                                 "(parameter 'measured_input' must be 'shape')")
        self.values = v
        self.session = ComparisonSession(v)
        self.display = ComparisonDisplay(v["display.rate"], v["display.tube_radius"], self.session.model_from_camera)

    def on_model(self, shape: ModelShape, frame_id: str) -> list[tuple[str, Any]]:
        stamp = stamp_of(shape.t)
        return self.outputs(self.session.add_model(stamp_ns(stamp), frame_id, Tag(stamp, frame_id),
                                                   shape.line.points, shape.line.arc_length))

    def on_measured(self, shape: MeasuredShape) -> list[tuple[str, Any]]:
        header = shape.header
        return self.outputs(self.session.add_measurement(stamp_ns(header.stamp), header.frame_id, header, shape.points,
                                                         shape.arc_length))

    def outputs(self, compared: list[ComparedPair]) -> list[tuple[str, Any]]:
        """As the node publishes them, serialized: ('shape_error', ShapeError) per comparison, then its display
        topics' Path and Marker messages (:class:`ComparisonDisplay`)."""
        result: list[tuple[str, bytes]] = []
        for pair in compared:
            result.append(("shape_error", shape_error_cdr(pair.result, pair.model_tag, pair.measured_tag)))
            result.extend(self.display.outputs(pair).items())
        return result


def stereo_values(values: dict[str, Any]) -> dict[str, Any]:
    """The stereo node's values with its checks across parameters."""
    return validate_all({k: v for k, v in values.items() if k != "use_sim_time"})
