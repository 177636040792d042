"""CDR encoding of the simulator's outputs straight from numpy arrays, without rclpy message objects (decoding:
:mod:`needle_common.cdr`, images :func:`needle_vision.streams.image_codec.deserialize_image`).

Each encoder writes exactly the bytes of ``rclpy.serialization.serialize_message`` for the equivalent message
(test_cdr checks them): XCDR1 little endian (encapsulation 0x0001), primitives aligned to their size from the
payload's start, strings as uint32 length (with the NUL) + bytes + NUL, sequences as uint32 count + elements, zero
padding, and the trailing zero bytes of rmw_fastrtps's size estimate (a float64 sequence aligned to 8 even when
empty). Nodes publish them with ``Publisher.publish(bytes)``; why and what it saves: docs/design_notes.md.
"""
from __future__ import annotations

import math
import struct
from functools import lru_cache
from typing import Callable

import numpy as np

from needle_common.cdr import ENCAPSULATION


_STAMP = struct.Struct("<iI")  # a header's stamp


class _Buffer:
    """Little-endian CDR payload with alignment relative to its start."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0
        self.estimated_size = 0  # rmw_fastrtps's size estimate: never less than ``size``

    def _add(self, data: bytes) -> None:
        self.parts.append(data)
        self.size += len(data)
        self.estimated_size += len(data)

    def align(self, boundary: int) -> None:
        padding = -self.size % boundary
        self.estimated_size += -self.estimated_size % boundary - padding
        if padding:
            self._add(b"\x00" * padding)

    def pack(self, fmt: str, alignment: int, *values) -> None:
        """Primitives of one size (struct format without byte order), aligned to it."""
        self.align(alignment)
        self._add(struct.pack("<" + fmt, *values))

    def uint32(self, value: int) -> None:
        self.pack("I", 4, value)

    def time(self, sec: int, nanosec: int) -> None:
        self.pack("iI", 4, sec, nanosec)

    def string(self, text: str) -> None:
        data = text.encode() + b"\x00"
        self.uint32(len(data))
        self._add(data)

    def doubles(self, values: np.ndarray) -> None:
        """Consecutive float64 values (a fixed-size struct of doubles, or a sequence's elements)."""
        values = np.ascontiguousarray(values, dtype="<f8")
        if values.size:
            self.align(8)
            self._add(values.tobytes())

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


@lru_cache(maxsize=8)
def _wrench_layout(frame_id: str) -> tuple[bytes, bytes, Callable[..., bytes]]:
    """A WrenchStamped of this frame as one struct: the encapsulation, the stamp, the bytes from the frame_id's
    length to the doubles (fixed per frame) and the Wrench; returns those two fixed parts and the struct's pack."""
    head = ENCAPSULATION + _aligned_header(0, 0, frame_id)
    return head[:4], head[12:], struct.Struct(f"<4siI{len(head) - 12}s6d").pack


def wrench_stamped_many(frame_id: str, wrenches) -> list[bytes]:
    """geometry_msgs/msg/WrenchStamped of each (time [s], force (3,), torque (3,)) in ``wrenches``, stamped as
    ``time_msg`` stamps the time. One struct per frame packs each message at once (~1 us per message)."""
    encapsulation, middle, pack = _wrench_layout(frame_id)
    floor = math.floor
    messages = []
    for t, force, torque in wrenches:
        t = float(t)
        sec = floor(t)
        messages.append(pack(encapsulation, sec, min(round((t - sec) * 1e9), 999_999_999), middle, *force, *torque))
    return messages


def _header(buffer: _Buffer, sec: int, nanosec: int, frame_id: str) -> None:
    buffer.time(sec, nanosec)
    buffer.string(frame_id)


def _aligned_header(sec: int, nanosec: int, frame_id: str) -> bytes:
    """A header's bytes padded to the 8-byte grid, as they precede a block of doubles at the payload's start."""
    prefix = _Buffer()
    _header(prefix, sec, nanosec, frame_id)
    prefix.align(8)
    return b"".join(prefix.parts)


def pose_array(sec: int, nanosec: int, frame_id: str, points: np.ndarray, quaternions: np.ndarray) -> bytes:
    """geometry_msgs/msg/PoseArray of poses at points (n, 3) with orientations (n, 4) (x, y, z, w)."""
    buffer = _Buffer()
    _header(buffer, sec, nanosec, frame_id)
    buffer.sequence(np.hstack([points, quaternions]), 7)
    return buffer.bytes()


def path(sec: int, nanosec: int, frame_id: str, points: np.ndarray, quaternions: np.ndarray) -> bytes:
    """nav_msgs/msg/Path whose poses (n) all carry the path's header."""
    buffer = _Buffer()
    _header(buffer, sec, nanosec, frame_id)
    buffer.uint32(len(points))
    poses = np.ascontiguousarray(np.hstack([points, quaternions]), dtype="<f8").reshape(-1, 7)
    if len(poses):  # the first pose may start 4 bytes off the 8-byte grid; each after it starts on it
        _header(buffer, sec, nanosec, frame_id)
        buffer.doubles(poses[0])
    if len(poses) > 1:  # the same header bytes and padding before every later pose: one block
        head = np.frombuffer(_aligned_header(sec, nanosec, frame_id), np.uint8)
        block = np.empty((len(poses) - 1, head.size + 56), np.uint8)
        block[:, :head.size] = head
        block[:, head.size:] = poses[1:].view(np.uint8)
        buffer._add(block.tobytes())
    return buffer.bytes()


def triangle_list_marker(sec: int, nanosec: int, frame_id: str, namespace: str, marker_id: int,
                         vertices: np.ndarray, color: tuple[float, float, float, float]) -> bytes:
    """visualization_msgs/msg/Marker TRIANGLE_LIST (type 11), action ADD, identity pose, unit scale, one color,
    the triangles' vertices (3k, 3) in the header frame; all other fields empty."""
    buffer = _Buffer()
    _header(buffer, sec, nanosec, frame_id)
    buffer.string(namespace)
    buffer.pack("iii", 4, marker_id, 11, 0)
    buffer.doubles(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]))  # pose, scale
    buffer.pack("ffff", 4, *color)
    buffer.time(0, 0)  # lifetime: forever
    buffer.pack("B", 1, 0)  # frame_locked
    buffer.sequence(vertices, 3)  # points
    buffer.uint32(0)  # colors
    buffer.string("")  # texture_resource
    _header(buffer, 0, 0, "")  # texture: CompressedImage header, format, data
    buffer.string("")
    buffer.uint32(0)
    buffer.uint32(0)  # uv_coordinates
    buffer.string("")  # text
    buffer.string("")  # mesh_resource
    buffer.string("")  # mesh_file: filename, data
    buffer.uint32(0)
    buffer.pack("B", 1, 0)  # mesh_use_embedded_materials
    return buffer.bytes()


def compressed_image_message(sec: int, nanosec: int, frame_id: str, image_format: str, data: bytes) -> bytes:
    """sensor_msgs/msg/CompressedImage of the encoded image ``data`` in ``image_format`` (image_transport's
    ``png``/``jpeg`` form)."""
    buffer = _Buffer()
    _header(buffer, sec, nanosec, frame_id)
    buffer.string(image_format)
    buffer.uint32(len(data))
    buffer._add(bytes(data))
    return buffer.bytes()


def needle_state(sec: int, nanosec: int, frame_id: str, insertion_depth: float, inserted_length: float,
                 tip_force_x: float, tip_force_y: float, tip_force_z: float, axial_force: float,
                 kinetic_energy: float, elastic_energy: float) -> bytes:
    """needle_interfaces/msg/NeedleState."""
    buffer = _Buffer()
    _header(buffer, sec, nanosec, frame_id)
    buffer.doubles(np.array([insertion_depth, inserted_length, tip_force_x, tip_force_y, tip_force_z, axial_force,
                             kinetic_energy, elastic_energy]))
    return buffer.bytes()


def needle_shape(sec: int, nanosec: int, frame_id: str, source: str, points: np.ndarray, tangents: np.ndarray,
                 arc_length: np.ndarray, tip_position: np.ndarray, tip_orientation: np.ndarray,
                 uncertainty: np.ndarray | None = None) -> bytes:
    """needle_interfaces/msg/NeedleShape with ``length`` = the last arc length (as ``needle_shape_msg``): the
    layout of its frame, source and sizes (:func:`_needle_shape_layout`) filled with the stamp and the values."""
    length = float(arc_length[-1]) if len(arc_length) else 0.0
    blocks = [np.asarray(values, dtype=float).reshape(-1) for values in (
        points, tangents, arc_length, np.zeros(0) if uncertainty is None else uncertainty)]
    blocks.append(np.concatenate([tip_position, tip_orientation, [length]]).astype(float))
    template, starts = _needle_shape_layout(frame_id, source, tuple(block.size for block in blocks))
    data = bytearray(template)
    _STAMP.pack_into(data, len(ENCAPSULATION), sec, nanosec)
    for start, block in zip(starts, blocks):
        data[start:start + 8 * block.size] = block.astype("<f8").tobytes()
    return bytes(data)


class _Layout(_Buffer):
    """A :class:`_Buffer` that notes where each block of doubles starts in the serialized bytes."""

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
    _header(layout, 0, 0, frame_id)
    layout.string(source)
    layout.sequence(np.zeros(sizes[0]), 3)  # points
    layout.sequence(np.zeros(sizes[1]), 3)  # tangents
    layout.float64_sequence(np.zeros(sizes[2]))  # arc length
    layout.float64_sequence(np.zeros(sizes[3]))  # uncertainty
    layout.doubles(np.zeros(sizes[4]))  # tip pose and length
    return layout.bytes(), tuple(layout.starts)


def shape_error(sec: int, nanosec: int, frame_id: str, model_stamp: tuple[int, int],
                measurement_stamp: tuple[int, int], rmse: float, max_error: float, tip_error: float,
                matched_samples: int, errors: np.ndarray, arc_length: np.ndarray) -> bytes:
    """needle_interfaces/msg/ShapeError; the stamps as (sec, nanosec)."""
    buffer = _Buffer()
    _header(buffer, sec, nanosec, frame_id)
    buffer.time(*model_stamp)
    buffer.time(*measurement_stamp)
    buffer.doubles(np.array([rmse, max_error, tip_error]))
    buffer.uint32(matched_samples)
    buffer.float64_sequence(errors)
    buffer.float64_sequence(arc_length)
    return buffer.bytes()
