"""CDR (XCDR1 little endian, as a bag or a raw subscription gives them) without rclpy message objects (rclpy
builds six Python objects per pose): decoding of the input messages, and :class:`Writer` with the NeedleShape
encoder (the simulator's other outputs: :mod:`needle_sim_ros.messages.cdr`). No ROS here.

An encoder writes exactly the bytes of ``rclpy.serialization.serialize_message`` for the equivalent message
(needle_sim_ros's test_cdr checks them): encapsulation 0x0001, primitives aligned to their size from the payload's
start, strings as uint32 length (with the NUL) + bytes + NUL, sequences as uint32 count + elements, zero padding,
and the trailing zero bytes of rmw_fastrtps's size estimate (a float64 sequence aligned to 8 even when empty).
Nodes publish them with ``Publisher.publish(bytes)``; why and what it saves: docs/design_notes.md.
"""
from __future__ import annotations

import struct
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from needle_common.transforms import quaternions_from_x_axes

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


class Writer:
    """A little-endian CDR payload with alignment relative to its start."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0
        self.estimated_size = 0  # rmw_fastrtps's size estimate: never less than ``size``

    def add(self, data: bytes) -> None:
        """Bytes as they are (no alignment)."""
        self.parts.append(data)
        self.size += len(data)
        self.estimated_size += len(data)

    def align(self, boundary: int) -> None:
        padding = -self.size % boundary
        self.estimated_size += -self.estimated_size % boundary - padding
        if padding:
            self.add(b"\x00" * padding)

    def pack(self, fmt: str, alignment: int, *values) -> None:
        """Primitives of one size (struct format without byte order), aligned to it."""
        self.align(alignment)
        self.add(struct.pack("<" + fmt, *values))

    def uint32(self, value: int) -> None:
        self.pack("I", 4, value)

    def time(self, sec: int, nanosec: int) -> None:
        self.pack("iI", 4, sec, nanosec)

    def string(self, text: str) -> None:
        data = text.encode() + b"\x00"
        self.uint32(len(data))
        self.add(data)

    def header(self, sec: int, nanosec: int, frame_id: str) -> None:
        """A std_msgs/Header."""
        self.time(sec, nanosec)
        self.string(frame_id)

    def doubles(self, values: np.ndarray) -> None:
        """Consecutive float64 values (a fixed-size struct of doubles, or a sequence's elements)."""
        values = np.ascontiguousarray(values, dtype="<f8")
        if values.size:
            self.align(8)
            self.add(values.tobytes())

    def sequence(self, values: np.ndarray, per_element: int) -> None:
        """uint32 element count, then the elements' doubles: structs of ``per_element`` doubles each (Point,
        Vector3, Pose)."""
        values = np.asarray(values, dtype=float).reshape(-1)
        self.uint32(values.size // per_element)
        self.doubles(values)

    def float64_sequence(self, values: np.ndarray) -> None:
        """uint32 count, then the float64 values (the size estimate aligns them even when there are none)."""
        self.sequence(values, 1)
        self.estimated_size += -self.estimated_size % 8

    def bytes(self) -> bytes:
        return ENCAPSULATION + b"".join(self.parts) + bytes(self.estimated_size - self.size)


def needle_shape(sec: int, nanosec: int, frame_id: str, source: str, points: np.ndarray, tangents: np.ndarray,
                 arc_length: np.ndarray, tip_position: np.ndarray | None = None,
                 tip_orientation: np.ndarray | None = None, uncertainty: np.ndarray | None = None) -> bytes:
    """needle_interfaces/msg/NeedleShape, the suite's one: ``length`` = the last arc length; the tip pose by default
    the last point, oriented with x along the last tangent (a measured centerline has no twist). The layout of its
    frame, source and sizes (:func:`_needle_shape_layout`) filled with the stamp and the values."""
    tip_position = points[-1] if tip_position is None else tip_position
    tip_orientation = quaternions_from_x_axes(tangents[-1]) if tip_orientation is None else tip_orientation
    length = float(arc_length[-1]) if len(arc_length) else 0.0
    blocks = [np.asarray(values, dtype=float).reshape(-1) for values in (
        points, tangents, arc_length, np.zeros(0) if uncertainty is None else uncertainty)]
    blocks.append(np.concatenate([tip_position, tip_orientation, [length]]).astype(float))
    template, starts = _needle_shape_layout(frame_id, source, tuple(block.size for block in blocks))
    data = bytearray(template)
    struct.pack_into("<iI", data, len(ENCAPSULATION), sec, nanosec)
    for start, block in zip(starts, blocks):
        data[start:start + 8 * block.size] = block.astype("<f8").tobytes()
    return bytes(data)


def needle_shape_points(data: bytes | memoryview) -> tuple[int, np.ndarray]:
    """(stamp [ns], points (n, 3) [m], a copy) of a NeedleShape, as :func:`needle_shape` lays it out."""
    stamp, offset = header(data)
    offset = aligned(cdr_string(data, offset)[1], 4)  # after the source
    (count,) = struct.unpack_from("<I", data, offset)
    offset = aligned(offset + 4, 8) if count else offset + 4
    return stamp, np.frombuffer(data, "<f8", 3 * count, offset).reshape(-1, 3).copy()


class _Layout(Writer):
    """A :class:`Writer` that notes where each block of doubles starts in the serialized bytes."""

    def __init__(self) -> None:
        super().__init__()
        self.starts: list[int] = []

    def doubles(self, values: np.ndarray) -> None:
        if np.size(values):
            self.align(8)
        self.starts.append(len(ENCAPSULATION) + self.size)
        super().doubles(values)


@lru_cache(maxsize=64)
def _needle_shape_layout(frame_id: str, source: str, sizes: tuple[int, ...]) -> tuple[bytes, tuple[int, ...]]:
    """The bytes of a NeedleShape with a zero stamp and zero values of blocks of these sizes, and where each block
    starts (a model shape's layout is the same at every output: ~20 us of encoding less each)."""
    layout = _Layout()
    layout.header(0, 0, frame_id)
    layout.string(source)
    layout.sequence(np.zeros(sizes[0]), 3)  # points
    layout.sequence(np.zeros(sizes[1]), 3)  # tangents
    layout.float64_sequence(np.zeros(sizes[2]))  # arc length
    layout.float64_sequence(np.zeros(sizes[3]))  # uncertainty
    layout.doubles(np.zeros(sizes[4]))  # tip pose and length
    return layout.bytes(), tuple(layout.starts)
