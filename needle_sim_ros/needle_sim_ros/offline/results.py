"""Reading a pipeline log back (the live ``needle_compare`` recording or an offline run's MCAP) with the ``mcap``
ROS 2 decoder (no rclpy), plus the ground truth of a synthetic bag, as plain arrays for plots and reports.

The comparison's error against the measurement mixes two errors; for the synthetic bags the ground truth separates
them: :func:`versus_ground_truth` measures the model and the measurement each against the true centerline at the
measurement instants (same distance as the comparison: RMS of point-to-centerline distances).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from geometry_msgs.msg import WrenchStamped
from needle_interfaces.msg import NeedleShape, ShapeError
from rclpy.serialization import deserialize_message

from needle_sim_ros.comparison import CenterlineSamples, compare_centerlines
from needle_common.bag_reader import BagReader

NS = 1_000_000_000
MODEL_TOPIC, MEASURED_TOPIC = "/needle/shape", "/needle/measured_shape"
ERROR_TOPIC, WRENCH_TOPIC = "/shape_error", "/wrench"
TRUTH_SHAPE_TOPIC, TRUTH_WRENCH_TOPIC = "/ground_truth/shape", "/ground_truth/wrench"


def _time_ns(time) -> int:
    return int(time.sec) * NS + int(time.nanosec)


def _stamp(header) -> int:
    return _time_ns(header.stamp)


def _points(shape) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in shape.points], dtype=float).reshape(-1, 3)


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


MESSAGE_TYPES = {MODEL_TOPIC: NeedleShape, MEASURED_TOPIC: NeedleShape, ERROR_TOPIC: ShapeError,
                 WRENCH_TOPIC: WrenchStamped, TRUTH_SHAPE_TOPIC: NeedleShape, TRUTH_WRENCH_TOPIC: WrenchStamped}


def _decoded(reader: BagReader, topics: set[str]):
    """(topic, message) of ``topics``, deserialized by rclpy's C code (the mcap library's dynamic Python decoder
    took 2.3 s for the 7800 messages of a 6.2 s dynamic_pitch log)."""
    for message in reader.messages(topics):
        yield message.topic, deserialize_message(bytes(message.data), MESSAGE_TYPES[message.topic])


def _wrench(messages: list) -> WrenchSeries | None:
    if not messages:
        return None
    return WrenchSeries(np.array([_stamp(m.header) for m in messages], dtype=np.int64),
                        np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z] for m in messages]),
                        np.array([[m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z] for m in messages]))


def read_pipeline_log(log: str | Path, bag: str | Path | None = None) -> PipelineLog:
    """Decode ``log`` (model/measured shapes, errors, wrench) and, if given, the bag's (.mcap file or bag
    directory) ground truth and start; a corrupt chunk of the bag is skipped (the comparison skipped it already)."""
    truth = BagReader(bag) if bag is not None else None
    result = PipelineLog(start_ns=0)
    wrenches, truth_wrenches, errors = [], [], []
    for topic, msg in _decoded(BagReader(log), {MODEL_TOPIC, MEASURED_TOPIC, ERROR_TOPIC, WRENCH_TOPIC}):
        if topic == MODEL_TOPIC:
            result.model_shapes[_stamp(msg.header)] = _points(msg)
        elif topic == MEASURED_TOPIC:
            result.measured_shapes[_stamp(msg.header)] = _points(msg)
        elif topic == ERROR_TOPIC:
            errors.append(msg)
        else:
            wrenches.append(msg)
    if truth is not None:  # a corrupt chunk is skipped (the pipeline's reader counted it: summary corrupt_chunks)
        for topic, msg in _decoded(truth, {TRUTH_SHAPE_TOPIC, TRUTH_WRENCH_TOPIC}):
            if topic == TRUTH_SHAPE_TOPIC:
                result.truth_shapes[_stamp(msg.header)] = _points(msg)
            else:
                truth_wrenches.append(msg)
    result.start_ns = truth.start_time_ns if truth is not None else min(
        [*result.model_shapes, *result.measured_shapes], default=0)
    errors.sort(key=lambda m: _stamp(m.header))
    result.error_times = np.array([_time_ns(m.measurement_stamp) for m in errors], dtype=np.int64)
    result.model_times = np.array([_time_ns(m.model_stamp) for m in errors], dtype=np.int64)
    result.rmse = np.array([m.rmse for m in errors])
    result.max_error = np.array([m.max_error for m in errors])
    result.tip_error = np.array([m.tip_error for m in errors])
    result.wrench, result.truth_wrench = _wrench(wrenches), _wrench(truth_wrenches)
    return result


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


def wrench_versus_reference(log: PipelineLog) -> dict[str, float | int | None]:
    """RMS and largest error of the simulator's wrench against the bag's reference wrench (``/ground_truth/
    wrench``): force [N] and torque [N m] error magnitudes at the reference stamps inside the simulated span, the
    simulator's wrench interpolated linearly between its steps; ``wrench_reference_rms_n`` is the reference
    force's own RMS magnitude, for scale.  None where either series is missing."""
    model, truth = log.wrench, log.truth_wrench
    keys = ("wrench_force_rms_n", "wrench_force_max_n", "wrench_torque_rms_nm", "wrench_torque_max_nm",
            "wrench_reference_rms_n")
    if model is None or truth is None or model.times.size < 2:
        return {"wrench_samples": 0, **dict.fromkeys(keys)}
    order = np.argsort(model.times)
    times = model.times[order]
    inside = (truth.times >= times[0]) & (truth.times <= times[-1])
    at = truth.times[inside].astype(float)

    def error(model_values: np.ndarray, truth_values: np.ndarray) -> np.ndarray:
        interpolated = np.column_stack([np.interp(at, times.astype(float), model_values[order, i]) for i in range(3)])
        return np.linalg.norm(interpolated - truth_values[inside], axis=1)

    force, torque = error(model.force, truth.force), error(model.torque, truth.torque)
    if force.size == 0:
        return {"wrench_samples": 0, **dict.fromkeys(keys)}
    rms = (lambda values: float(np.sqrt(np.mean(values**2))))
    return {"wrench_samples": int(force.size), "wrench_force_rms_n": rms(force),
            "wrench_force_max_n": float(force.max()), "wrench_torque_rms_nm": rms(torque),
            "wrench_torque_max_nm": float(torque.max()),
            "wrench_reference_rms_n": rms(np.linalg.norm(truth.force[inside], axis=1))}
