"""Decoding of serialized input messages (CDR: XCDR1 little endian, as a bag or a raw subscription gives them)
without building rclpy message objects (rclpy builds six Python objects per pose). No ROS here."""
from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian
NS = 1_000_000_000
_HEADER = struct.Struct("<iII")  # a std_msgs/Header's stamp (sec, nanosec) and its frame_id's length


def aligned(offset: int, size: int) -> int:
    """``offset`` aligned to ``size`` bytes: CDR aligns from the payload's start, after the 4-byte encapsulation."""
    return offset + -(offset - 4) % size


def header(data: bytes | memoryview) -> tuple[int, int]:
    """(stamp [ns], offset after the frame_id) of a serialized message that starts with a std_msgs/Header."""
    sec, nanosec, length = _HEADER.unpack_from(data, 4)
    return sec * NS + nanosec, 16 + length


class PoseStamped(NamedTuple):
    """A ``geometry_msgs/msg/PoseStamped``: stamp [ns], frame_id, position (3,) [m] and orientation (x, y, z, w),
    the arrays read-only views of the serialized bytes."""

    stamp_ns: int
    frame_id: str
    position: np.ndarray
    orientation: np.ndarray

    @property
    def stamp(self) -> float:
        """The stamp [s]."""
        return self.stamp_ns / 1e9


def pose_stamped(data: bytes | memoryview) -> PoseStamped:
    """Decode a serialized ``geometry_msgs/msg/PoseStamped``; ValueError when it is not one (another encoding, cut
    short). Bytes of the frame_id that are not UTF-8 are replaced (such a frame matches no frame of the suite)."""
    if len(data) < 16 or bytes(data[:2]) != ENCAPSULATION[:2]:
        raise ValueError("not a little-endian CDR PoseStamped message")
    try:
        stamp, offset = header(data)
        frame_id = bytes(data[16:offset - 1]).decode("utf-8", "replace") if offset > 16 else ""
        values = np.frombuffer(data, dtype="<f8", count=7, offset=aligned(offset, 8))
    except (struct.error, ValueError) as error:
        raise ValueError(f"truncated PoseStamped message ({error})") from error
    return PoseStamped(stamp, frame_id, values[:3], values[3:])


class CameraInfo(NamedTuple):
    """The calibration fields of a ``sensor_msgs/msg/CameraInfo`` (binning and ROI are not read): stamp [ns],
    frame_id, image size [px], distortion model and D, K (9), R (9), P (12) as read-only views of the bytes."""

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    distortion_model: str
    d: np.ndarray
    k: np.ndarray
    r: np.ndarray
    p: np.ndarray


def cdr_string(data: bytes | memoryview, offset: int) -> tuple[str, int]:
    """(the CDR string at ``offset``, the offset after it)."""
    (length,) = struct.unpack_from("<I", data, aligned(offset, 4))
    start = aligned(offset, 4) + 4
    if start + length > len(data):
        raise ValueError(f"a string of {length} bytes runs past the message's end")
    return bytes(data[start:start + length - 1]).decode("utf-8", "replace") if length else "", start + length


def _doubles(data: bytes | memoryview, offset: int, count: int) -> tuple[np.ndarray, int]:
    """(``count`` float64 from ``offset`` aligned to 8, the offset after them)."""
    start = aligned(offset, 8)
    return np.frombuffer(data, dtype="<f8", count=count, offset=start), start + 8 * count


def camera_info(data: bytes | memoryview) -> CameraInfo:
    """Decode a serialized ``sensor_msgs/msg/CameraInfo``; ValueError when it is not one (another encoding, cut
    short)."""
    if len(data) < 16 or bytes(data[:2]) != ENCAPSULATION[:2]:
        raise ValueError("not a little-endian CDR CameraInfo message")
    try:
        stamp, _ = header(data)
        frame_id, offset = cdr_string(data, 12)
        height, width = struct.unpack_from("<II", data, aligned(offset, 4))
        distortion_model, offset = cdr_string(data, aligned(offset, 4) + 8)
        (count,) = struct.unpack_from("<I", data, aligned(offset, 4))
        d, offset = _doubles(data, aligned(offset, 4) + 4, count)
        k, offset = _doubles(data, offset, 9)
        r, offset = _doubles(data, offset, 9)
        p, _ = _doubles(data, offset, 12)
    except (struct.error, ValueError) as error:
        raise ValueError(f"truncated CameraInfo message ({error})") from error
    return CameraInfo(stamp, frame_id, height, width, distortion_model, d, k, r, p)
