"""Offline batch mode: simulator + stereo + comparison over a bag, as fast as the model steps and deterministic.

The log time is the clock: before a message is delivered the simulator integrates up to it (never past the newest
pose), and every produced message goes through the stages that would receive it live::

    /base_pose, /base_twist, /tip_load ──> SimulatorStage ──> /wrench, /needle/shape ───────┐
    /left|right/image_raw ──> StereoStage ──> /needle/measured_shape ──> ComparisonStage ──> /shape_error
    (or a recorded /needle/measured_shape, e.g. a shape-sensing needle) ────────────────┘

The output MCAP holds what ``needle_compare`` records live, with the same topic names (no TF: the displayed
messages are in the model frame); the same bag and parameters give the same file. The run's series and the bag's
ground truth are collected on the way (:class:`~needle_sim_ros.offline.results.LogCollector`).
"""
from __future__ import annotations

import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from geometry_msgs.msg import TwistStamped, WrenchStamped
from needle_interfaces.msg import NeedleShape
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo

from needle_common.cdr import NS, pose_stamped
from needle_vision.streams.image_codec import deserialize_image

from needle_sim_ros.messages.centerline_display import DISPLAY_TYPES
from needle_sim_ros.messages.shape import model_shape_cdr
from needle_sim_ros.parameters.compare import DISPLAY_TOPICS
from needle_sim_ros.parameters.experiment import ExperimentConfig
from needle_sim_ros.offline.results import MODEL_TOPIC, TRUTH_TOPICS, WRENCH_TOPIC, LogCollector, PipelineLog
from needle_sim_ros.offline.stages import ComparisonStage, MeasuredShape, SimulatorStage, StereoStage, stereo_values
from needle_common.bag_reader import BagReader, BagReadError
from needle_common.qos import OfferedQos
from needle_sim_ros.recording import McapBagWriter, WriterOptions
from needle_sim_ros.recording.playback import EXPECTED_TYPES

# Output topics (as the live pipeline names them) -> (type, offered QoS of the live publisher; /wrench's is set per
# run, as the simulator's qos.wrench).
OUTPUT_TOPICS = {
    **{topic: (EXPECTED_TYPES[topic], OfferedQos(depth=10)) for topic in (
        "/needle/shape", "/needle/measured_shape", "/shape_error", "/base_pose", "/wrench")},
    **{f"/{topic}": (DISPLAY_TYPES[topic.rsplit("/", 1)[1]], OfferedQos(depth=10)) for topic in DISPLAY_TOPICS},
}
INPUT_TYPES = {"/tip_load": WrenchStamped, "/base_twist": TwistStamped, "/left/camera_info": CameraInfo,
               "/right/camera_info": CameraInfo,
               "/needle/measured_shape": NeedleShape}  # besides images and poses (see decode)


# What decoding a damaged message raises (CDR readers: struct/index/unicode errors; rclpy: RuntimeError).
DECODE_ERRORS = (ValueError, RuntimeError, IndexError, struct.error, UnicodeDecodeError, TypeError, OverflowError)


def decode(topic: str, data: bytes, pose_topics: tuple[str, ...] = ("/base_pose",)) -> Any:
    """An input message from its serialized bytes (images and the ``pose_topics``' poses decoded directly, pixels
    uncopied: :func:`needle_vision.streams.image_codec.deserialize_image`, :mod:`needle_common.cdr`)."""
    if topic in pose_topics:  # the most frequent: first
        return pose_stamped(data)
    if topic.endswith(("image_raw", "image_raw/compressed")):
        return deserialize_image(data, compressed=topic.endswith("compressed"))
    return deserialize_message(bytes(data), INPUT_TYPES[topic])


@dataclass
class OfflineRun:
    """Result of one offline run: the summary written as JSON and the run's series (with the bag's ground truth) as
    arrays."""

    summary: dict[str, Any]
    log: PipelineLog


class OfflinePipeline:
    """One run of the three stages over a bag with an experiment's parameters (+ per-node ``overrides``)."""

    def __init__(self, experiment: ExperimentConfig, overrides: dict[str, dict[str, Any]] | None = None,
                 stereo: bool | None = None) -> None:
        overrides = overrides or {}
        self.experiment = experiment
        self.warnings: list[str] = []
        sim_values = experiment.values("needle_simulator", overrides.get("needle_simulator"))
        cmp_values = experiment.values("needle_compare", overrides.get("needle_compare"))
        self.parameters = {"needle_simulator": sim_values, "needle_compare": cmp_values}
        self.simulator = SimulatorStage(sim_values)
        self.comparison = ComparisonStage(cmp_values)
        self.use_stereo = experiment.settings.stereo if stereo is None else stereo
        self.stereo = None
        if self.use_stereo:
            values = stereo_values(experiment.values("needle_stereo", overrides.get("needle_stereo")))
            self.parameters["needle_stereo"] = values
            self.stereo = StereoStage(values)

    def input_topics(self, reader: BagReader) -> list[str]:
        """The recorded input topics (and ground truth); ValueError naming the topic if one has another type than
        the nodes expect."""
        topics = ["/base_pose", "/base_twist", "/tip_load", *TRUTH_TOPICS]
        topics += [*self.stereo.image_topics, "/left/camera_info", "/right/camera_info", self.stereo.base_pose_topic] \
            if self.use_stereo else ["/needle/measured_shape"]
        topics = list(dict.fromkeys(t for t in topics if t in reader.topics))
        for topic, (recorded, expected) in reader.type_mismatches(EXPECTED_TYPES).items():
            if topic in topics:
                raise ValueError(f"bag '{reader.path}': topic '{topic}' has type '{recorded}', expected '{expected}'")
        return topics

    def run(self, bag: Path | BagReader, output: Path | None, start_offset: float = 0.0,
            duration: float | None = None, progress: Callable[[float], None] | None = None,
            stop_on_corrupt: bool = False) -> OfflineRun:
        """Process the bag slice [start + start_offset, + duration] (s), writing the log to ``output`` (.mcap) if given;
        ``progress(seconds)`` hears the bag time done about every 0.1 s of it. Corrupt chunks and undecodable messages
        are skipped and counted (``stop_on_corrupt``: BagReadError; a given reader keeps its own setting)."""
        reader = bag if isinstance(bag, BagReader) else BagReader(bag, stop_on_corrupt)
        bag = reader.path
        undecodable = 0
        topics = self.input_topics(reader)
        if "/base_pose" not in topics:
            raise ValueError(f"bag '{bag}' has no /base_pose topic: nothing drives the simulator")
        begin = reader.start_time_ns + int(round(start_offset * NS))
        end = reader.end_time_ns if duration is None else min(reader.end_time_ns, begin + int(round(duration * NS)))
        if start_offset > 0 and len(self.parameters["needle_simulator"]["fixtures.clamp_interval"]) == 2:
            self.warnings.append("the clamp interval is fixed where the needle lies at the first pose played: a slice "
                                 "that starts late clamps the needle elsewhere than the recording did")
        self.writer = None
        if output is not None:
            self.writer = McapBagWriter(output, WriterOptions(overwrite=True, background=True))
            wrench_qos = OfferedQos(depth=100, reliability="reliable" if self.parameters["needle_simulator"][
                "qos.wrench"] == "reliable" else "best_effort")
            outputs = {**OUTPUT_TOPICS, "/wrench": (OUTPUT_TOPICS["/wrench"][0], wrench_qos)}
            for topic, (type_name, qos) in outputs.items():
                self.writer.add_topic(topic, type_name, (qos,))
        self.collector = LogCollector()
        self.seconds = dict.fromkeys(("simulator", "stereo", "comparison"), 0.0)
        wall_start = time.perf_counter()
        if self.stereo is not None and begin > reader.start_time_ns:
            self._prime_stereo(reader, begin)
        last_progress = begin
        stereo_poses = self.stereo.base_pose_topic if self.stereo is not None else ""
        pose_topics = ("/base_pose", stereo_poses)
        simulator_inputs = {"/base_pose": self.simulator.on_pose, "/base_twist": self.simulator.on_twist,
                            "/tip_load": self.simulator.on_tip_load}
        try:
            for message in reader.messages(topics, start_time_ns=begin):
                now = message.log_time_ns
                if now > end:
                    break
                truth = message.topic in TRUTH_TOPICS  # for the run's log only: no stage receives it
                if not truth:
                    self._advance(now)
                try:
                    msg = self.collector.add(message.topic, message.data) if truth else \
                        decode(message.topic, message.data, pose_topics)
                except DECODE_ERRORS as error:
                    undecodable += 1
                    if stop_on_corrupt:
                        raise BagReadError(f"bag '{bag}': undecodable {message.topic} message at "
                                           f"{now / NS:.9f} s ({error})") from error
                    continue
                if message.topic == stereo_poses:  # the stereo node's base_pose.topic (may be the simulator's)
                    self._timed("stereo", self.stereo.on_base_pose, msg)
                if message.topic in simulator_inputs:
                    self._timed("simulator", simulator_inputs[message.topic], msg, now)
                    if message.topic == "/base_pose":
                        self._write("/base_pose", bytes(message.data), now)
                elif message.topic == "/needle/measured_shape":
                    self._measured(MeasuredShape.recorded(msg, bytes(message.data)), now)
                elif message.topic.endswith("camera_info"):
                    self._timed("stereo", self.stereo.on_camera_info, message.topic.split("/")[1], msg)
                elif not truth and message.topic in self.stereo.image_topics:
                    for shape in self._timed("stereo", self.stereo.on_image, message.topic.split("/")[1], msg):
                        self._measured(shape, now)
                if progress is not None and now - last_progress >= NS // 10:
                    progress((now - begin) / NS)
                    last_progress = now
            self._advance(end)
            if progress is not None:
                progress((end - begin) / NS)
        finally:
            if self.writer is not None:
                self.writer.close()
        wall = time.perf_counter() - wall_start
        simulated = (end - begin) / NS
        stages = {f"{k}_s": v for k, v in self.seconds.items()}
        stages["simulator_core_s"] = self.simulator.core_seconds  # of simulator_s: NeedleSimulation.advance
        summary = {
            "bag": str(bag), "experiment": str(self.experiment.path), "start_offset_s": start_offset,
            "duration_s": simulated, "comparison": self.comparison.session.finish(),
            "simulator": self.simulator.statistics(), "stereo": self.stereo.statistics() if self.stereo else None,
            "timing": {"wall_s": wall, "simulated_s": simulated,
                       "real_time_factor": simulated / wall if wall > 0 else None,
                       **stages, "messages_and_io_s": wall - sum(self.seconds.values())},
            "warnings": self.warnings + [f"skipped {n} {what} of the bag" for n, what in (
                (reader.corrupt_chunks, "corrupt chunk(s)"), (undecodable, "undecodable message(s)")) if n],
            "corrupt_chunks": reader.corrupt_chunks, "undecodable_messages": undecodable}
        return OfflineRun(summary, self.collector.log(reader.start_time_ns))

    def _timed(self, stage: str, function: Callable, *arguments) -> Any:
        """``function(*arguments)``, its wall time added to the stage's."""
        start = time.perf_counter()
        result = function(*arguments)
        self.seconds[stage] += time.perf_counter() - start
        return result

    def _write(self, topic: str, data: bytes, now_ns: int) -> None:
        """Record a serialized output message and collect it for the run's log."""
        self.collector.add(topic, data)
        if self.writer is not None:
            self.writer.write(topic, data, now_ns)

    def _write_wrenches(self, wrenches: list[bytes], now_ns: int) -> None:
        self.collector.add_wrenches(WRENCH_TOPIC, wrenches)
        if self.writer is not None:
            self.writer.write_many(WRENCH_TOPIC, wrenches, now_ns)

    def _compared(self, outputs: list[tuple[str, bytes]], now_ns: int) -> None:
        """The comparison stage's outputs: shape errors and the compared centerlines' display messages."""
        for topic, msg in outputs:
            self._write(f"/{topic}", msg, now_ns)

    def _measured(self, shape: MeasuredShape, now_ns: int) -> None:
        self._write("/needle/measured_shape", shape.data, now_ns)
        self._compared(self._timed("comparison", self.comparison.on_measured, shape), now_ns)

    def _advance(self, now: int) -> None:
        """The simulator integrates up to the clock ``now``: its wrenches and shapes are written in step order, its
        shapes go to the comparison."""
        wrenches, shapes = self._timed("simulator", self.simulator.advance, now)
        frame, written = self.simulator.p["frames.world"], 0
        for steps, shape in shapes:
            self._write_wrenches(wrenches[written:steps], now)
            written = steps
            self._write(MODEL_TOPIC, model_shape_cdr(shape, frame), now)
            self._compared(self._timed("comparison", self.comparison.on_model, shape, frame), now)
        self._write_wrenches(wrenches[written:] if written else wrenches, now)

    def _prime_stereo(self, reader: BagReader, begin: int) -> None:
        """A slice that starts late still needs the needle-free background pairs from the bag's start."""
        topics = [t for t in ("/left/camera_info", "/right/camera_info", *self.stereo.image_topics)
                  if t in reader.topics]
        for message in reader.messages(topics):
            if message.log_time_ns >= begin or self.stereo.has_background:
                return
            msg = decode(message.topic, message.data)
            side = message.topic.split("/")[1]
            if message.topic.endswith("camera_info"):
                self.stereo.on_camera_info(side, msg)
            else:
                self.stereo.on_image(side, msg)
