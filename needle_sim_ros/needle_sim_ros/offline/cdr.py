"""CDR encoding of the offline pipeline's high-rate outputs straight from numpy arrays.

The simulator stage writes a WrenchStamped per 1 ms step and a NeedleShape per shape period. Building rclpy
messages (a Python object per point) and serializing them costs ~1 ms per shape and ~50 us per wrench, as much as
the model itself; these encoders write the same bytes from the arrays in a few microseconds. They produce exactly
what ``rclpy.serialization.serialize_message`` produces for the message built by
``needle_sim_ros.nodes.shape_messages.needle_shape_msg`` / the simulator node's wrench (checked by the tests):
XCDR1 little endian (encapsulation 0x0001), primitives aligned to their size from the start of the payload,
strings as uint32 length (with the terminating NUL) + bytes + NUL, sequences as uint32 count + elements.
"""
from __future__ import annotations

import struct

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian


class _Buffer:
    """Little-endian CDR payload with alignment relative to its start."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0

    def _add(self, data: bytes) -> None:
        self.parts.append(data)
        self.size += len(data)

    def align(self, boundary: int) -> None:
        padding = -self.size % boundary
        if padding:
            self._add(b"\x00" * padding)

    def uint32(self, value: int) -> None:
        self.align(4)
        self._add(struct.pack("<I", value))

    def time(self, sec: int, nanosec: int) -> None:
        self.align(4)
        self._add(struct.pack("<iI", sec, nanosec))

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
        """uint32 element count, then the elements' doubles (``per_element`` doubles each)."""
        values = np.asarray(values, dtype=float).reshape(-1)
        self.uint32(values.size // per_element)
        self.doubles(values)

    def bytes(self) -> bytes:
        return ENCAPSULATION + b"".join(self.parts)


def wrench_stamped(sec: int, nanosec: int, frame_id: str, force: np.ndarray, torque: np.ndarray) -> bytes:
    """geometry_msgs/msg/WrenchStamped."""
    buffer = _Buffer()
    buffer.time(sec, nanosec)
    buffer.string(frame_id)
    buffer.doubles(np.concatenate([force, torque]))
    return buffer.bytes()


def needle_shape(sec: int, nanosec: int, frame_id: str, source: str, points: np.ndarray, tangents: np.ndarray,
                 arc_length: np.ndarray, tip_position: np.ndarray, tip_orientation: np.ndarray,
                 uncertainty: np.ndarray | None = None) -> bytes:
    """needle_interfaces/msg/NeedleShape with ``length`` = the last arc length (as ``needle_shape_msg``)."""
    buffer = _Buffer()
    buffer.time(sec, nanosec)
    buffer.string(frame_id)
    buffer.string(source)
    buffer.sequence(points, 3)
    buffer.sequence(tangents, 3)
    buffer.sequence(arc_length, 1)
    buffer.sequence(np.zeros(0) if uncertainty is None else uncertainty, 1)
    length = float(arc_length[-1]) if len(arc_length) else 0.0
    buffer.doubles(np.concatenate([tip_position, tip_orientation, [length]]))
    return buffer.bytes()
