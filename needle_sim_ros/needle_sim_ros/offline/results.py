"""A pipeline log (the live ``needle_compare`` recording or an offline run) as plain arrays for plots and reports,
plus the ground truth of a synthetic bag. :class:`LogCollector` reads the CDR bytes as the offline pipeline writes
them, or as :func:`read_pipeline_log` reads them back; :func:`versus_ground_truth` measures the model and the
measurement each against the true centerline (RMS of point-to-centerline distances, as the comparison).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from needle_sim_ros.comparison import CenterlineSamples, compare_centerlines
from needle_common.bag_reader import BagReader
from needle_common.cdr import NS, aligned, header, needle_shape_points

MODEL_TOPIC, MEASURED_TOPIC = "/needle/shape", "/needle/measured_shape"
ERROR_TOPIC, WRENCH_TOPIC = "/shape_error", "/wrench"
TRUTH_SHAPE_TOPIC, TRUTH_WRENCH_TOPIC = "/ground_truth/shape", "/ground_truth/wrench"
TRUTH_TOPICS = (TRUTH_SHAPE_TOPIC, TRUTH_WRENCH_TOPIC)
_STAMPS = struct.Struct("<iIiI")  # a ShapeError's model and measurement stamps
_ERROR_VALUES = struct.Struct("<3d")  # rmse, max and tip error


@dataclass
class WrenchSeries:
    times: np.ndarray  # [ns] header stamps
    force: np.ndarray  # (n, 3) [N]
    torque: np.ndarray  # (n, 3) [N m]


@dataclass
class PipelineLog:
    """Shapes by stamp [ns] ((n, 3) points [m]), the ShapeError series and the wrench of a pipeline log, plus the
    ground truth of the bag when it has one. ``start_ns``: the bag's start (time origin of the plots)."""

    start_ns: int
    model_shapes: dict[int, np.ndarray] = field(default_factory=dict)
    measured_shapes: dict[int, np.ndarray] = field(default_factory=dict)
    truth_shapes: dict[int, np.ndarray] = field(default_factory=dict)
    error_times: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # measurement stamps [ns]
    model_times: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # paired model stamps [ns]
    rmse: np.ndarray = field(default_factory=lambda: np.zeros(0))
    max_error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tip_error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    wrench: WrenchSeries | None = None
    truth_wrench: WrenchSeries | None = None

    def seconds(self, stamps_ns) -> np.ndarray:
        return (np.asarray(stamps_ns, dtype=np.int64) - self.start_ns) / NS


def _wrenches(messages: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """(stamps [ns] (n,), force and torque (n, 6)) of WrenchStamped messages with frame_ids of one length."""
    rows = np.frombuffer(b"".join(messages), np.uint8).reshape(len(messages), -1)
    at = aligned(header(messages[0])[1], 8)
    stamps = np.ascontiguousarray(rows[:, 4:12]).view("<i4").astype(np.int64)
    return stamps[:, 0] * NS + (stamps[:, 1] & 0xFFFFFFFF), np.ascontiguousarray(rows[:, at:at + 48]).view("<f8")


def _error(data: bytes | memoryview) -> tuple:
    """(stamp, measurement stamp, model stamp [ns], rmse, max error, tip error [m]) of a ShapeError."""
    stamp, offset = header(data)
    offset = aligned(offset, 4)
    model_sec, model_nanosec, sec, nanosec = _STAMPS.unpack_from(data, offset)
    return (stamp, sec * NS + nanosec, model_sec * NS + model_nanosec,
            *_ERROR_VALUES.unpack_from(data, aligned(offset + _STAMPS.size, 8)))


class LogCollector:
    """The log's series, message by message (serialized messages of the topics above, others ignored)."""

    def __init__(self) -> None:
        self.shapes: dict[str, dict[int, np.ndarray]] = {MODEL_TOPIC: {}, MEASURED_TOPIC: {}, TRUTH_SHAPE_TOPIC: {}}
        self.wrenches: dict[str, list[bytes]] = {WRENCH_TOPIC: [], TRUTH_WRENCH_TOPIC: []}
        self.errors: list[tuple] = []

    def add(self, topic: str, data: bytes | memoryview) -> None:
        if topic in self.wrenches:
            self.wrenches[topic].append(bytes(data))  # a copy: a view would keep the bag's whole chunk
        elif topic in self.shapes:
            stamp, points = needle_shape_points(data)
            self.shapes[topic][stamp] = points
        elif topic == ERROR_TOPIC:
            self.errors.append(_error(data))

    def add_wrenches(self, topic: str, messages: list[bytes]) -> None:
        """Messages of a wrench topic, in order (decoded together when the log is made)."""
        self.wrenches[topic] += messages

    def log(self, start_ns: int) -> PipelineLog:
        errors = sorted(self.errors, key=lambda error: error[0])
        times = np.array([error[1:3] for error in errors], dtype=np.int64).reshape(-1, 2)
        values = np.array([error[3:] for error in errors], dtype=float).reshape(-1, 3)
        return PipelineLog(start_ns, *(self.shapes[t] for t in (MODEL_TOPIC, MEASURED_TOPIC, TRUTH_SHAPE_TOPIC)),
                           times[:, 0], times[:, 1], values[:, 0], values[:, 1], values[:, 2],
                           *(_series(self.wrenches[t]) for t in (WRENCH_TOPIC, TRUTH_WRENCH_TOPIC)))


def _series(messages: list[bytes]) -> WrenchSeries | None:
    """The series of WrenchStamped messages, decoded in runs of messages of one length (frame_ids as long)."""
    if not messages:
        return None
    blocks = []
    while messages:
        same = next((i for i, data in enumerate(messages) if len(data) != len(messages[0])), len(messages))
        blocks.append(_wrenches(messages[:same]))
        messages = messages[same:]
    values = np.concatenate([block[1] for block in blocks])
    return WrenchSeries(np.concatenate([block[0] for block in blocks]), values[:, :3], values[:, 3:])


def read_pipeline_log(log: str | Path, bag: str | Path | None = None) -> PipelineLog:
    """Decode ``log`` (model/measured shapes, errors, wrench) and, if given, the bag's (.mcap file or bag
    directory) ground truth and start; a corrupt chunk of the bag is skipped (the comparison skipped it already)."""
    collector = LogCollector()
    for message in BagReader(log).messages([MODEL_TOPIC, MEASURED_TOPIC, ERROR_TOPIC, WRENCH_TOPIC]):
        collector.add(message.topic, message.data)
    if bag is None:
        return collector.log(min([*collector.shapes[MODEL_TOPIC], *collector.shapes[MEASURED_TOPIC]], default=0))
    truth = BagReader(bag)
    for message in truth.messages(TRUTH_TOPICS):
        collector.add(message.topic, message.data)
    return collector.log(truth.start_time_ns)


def _rms_distance(reference: np.ndarray, points: np.ndarray) -> float:
    return compare_centerlines(CenterlineSamples(reference), CenterlineSamples(points)).rmse


def versus_ground_truth(log: PipelineLog) -> dict[str, float | int | None]:
    """Mean RMS distance [m] of the paired model shapes and of the measurements to the true centerline, at the
    compared instants whose stamp has a ground-truth shape."""
    model, measured = [], []
    for measurement_ns, model_ns in zip(log.error_times, log.model_times):
        truth = log.truth_shapes.get(int(measurement_ns))
        if truth is None:
            continue
        if int(model_ns) in log.model_shapes:
            model.append(_rms_distance(truth, log.model_shapes[int(model_ns)]))
        if int(measurement_ns) in log.measured_shapes:
            measured.append(_rms_distance(truth, log.measured_shapes[int(measurement_ns)]))
    mean = (lambda values: float(np.mean(values)) if values else None)
    return {"instants": len(model), "model_rmse_mean_m": mean(model), "measurement_rmse_mean_m": mean(measured),
            **wrench_versus_reference(log)}


def wrench_differences(log: PipelineLog) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Model minus reference force [N] and moment [N m] at the reference stamps inside the model's time span (the
    model's wrench interpolated linearly between its steps), and the reference force there; None when either series
    is missing or nothing overlaps."""
    model, reference = log.wrench, log.truth_wrench
    if model is None or reference is None or model.times.size < 2:
        return None
    order = np.argsort(model.times)
    times = model.times[order].astype(float)
    inside = (reference.times >= times[0]) & (reference.times <= times[-1])
    if not np.any(inside):
        return None
    at = reference.times[inside].astype(float)

    def interpolated(values: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(at, times, values[order, i]) for i in range(3)])

    force = reference.force[inside]
    return interpolated(model.force) - force, interpolated(model.torque) - reference.torque[inside], force


def wrench_versus_reference(log: PipelineLog) -> dict[str, float | int | None]:
    """RMS and largest error of the simulator's wrench against the bag's reference wrench (``/ground_truth/
    wrench``): force [N] and torque [N m] error magnitudes (:func:`wrench_differences`); ``wrench_reference_rms_n``
    is the reference force's own RMS magnitude there, for scale.  None where either series is missing."""
    keys = ("wrench_force_rms_n", "wrench_force_max_n", "wrench_torque_rms_nm", "wrench_torque_max_nm",
            "wrench_reference_rms_n")
    differences = wrench_differences(log)
    if differences is None:
        return {"wrench_samples": 0, **dict.fromkeys(keys)}
    force, torque, reference = (np.linalg.norm(values, axis=1) for values in differences)
    rms = (lambda values: float(np.sqrt(np.mean(values**2))))
    return {"wrench_samples": int(force.size), "wrench_force_rms_n": rms(force),
            "wrench_force_max_n": float(force.max()), "wrench_torque_rms_nm": rms(torque),
            "wrench_torque_max_nm": float(torque.max()),
            "wrench_reference_rms_n": rms(reference)}
