"""Needle centerline <-> ROS messages (NeedleShape, ShapeError, Time), serialized ones by :mod:`needle_common.cdr`
and :mod:`needle_sim_ros.messages.cdr`."""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from needle_interfaces.msg import NeedleShape
from std_msgs.msg import Header

from needle_common.cdr import needle_shape
from needle_sim_ros.messages import cdr
from needle_sim_ros.model import ModelShape


class Stamp(NamedTuple):
    """The fields of a builtin_interfaces/Time, without building the message (~5 us each)."""

    sec: int
    nanosec: int


class Tag(NamedTuple):
    """The fields of a std_msgs/Header (what the comparison reads of a shape's header)."""

    stamp: Stamp
    frame_id: str


def stamp_of(seconds: float) -> Stamp:
    """The stamp of a time [s]: whole seconds and the rounded nanoseconds (at most 999 999 999)."""
    sec = math.floor(seconds)
    return Stamp(sec, min(int(round((seconds - sec) * 1e9)), 999_999_999))


def stamp_ns(stamp) -> int:
    """A builtin_interfaces/Time (or :class:`Stamp`) in nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def model_shape_cdr(shape: ModelShape, frame_id: str) -> bytes:
    """The simulator's ``needle/shape`` message (NeedleShape, source ``model``) of a shape output, serialized."""
    stamp = stamp_of(shape.t)
    return needle_shape(stamp.sec, stamp.nanosec, frame_id, NeedleShape.SOURCE_MODEL, shape.line.points,
                        shape.line.tangents, shape.line.arc_length, shape.tip_position, shape.tip_orientation)


def shape_arrays(msg: NeedleShape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (n,3), arc_length (n,), uncertainty (n,) or empty) of a NeedleShape."""
    points = np.array([[p.x, p.y, p.z] for p in msg.points], dtype=float).reshape(-1, 3)
    return points, np.asarray(msg.arc_length, dtype=float), np.asarray(msg.uncertainty, dtype=float)


def time_msg(seconds: float) -> Time:
    sec, nanosec = stamp_of(seconds)
    return Time(sec=sec, nanosec=nanosec)


def shape_error_cdr(result, model_header: Header | Tag, measured_header: Header | Tag) -> bytes:
    """The serialized ShapeError of one comparison (:class:`needle_sim_ros.comparison.ShapeComparison`) in the model
    frame, stamped with the measurement (zero padding: the same bytes in every run)."""
    stamp, model = measured_header.stamp, model_header.stamp
    return cdr.shape_error(stamp.sec, stamp.nanosec, model_header.frame_id, (model.sec, model.nanosec),
                           (stamp.sec, stamp.nanosec), result.rmse, result.max_error, result.tip_error,
                           result.matched_samples, result.errors, result.arc_length)
