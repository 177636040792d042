"""CDR encoding of the simulator's outputs straight from numpy arrays, without rclpy message objects, by the rules
and the :class:`~needle_common.cdr.Writer` of :mod:`needle_common.cdr` (which also encodes NeedleShape and decodes;
images: :func:`needle_vision.streams.image_codec.deserialize_image`)."""
from __future__ import annotations

import math
import struct
from functools import lru_cache
from typing import Callable

import numpy as np

from needle_common.cdr import ENCAPSULATION, Writer


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


def _aligned_header(sec: int, nanosec: int, frame_id: str) -> bytes:
    """A header's bytes padded to the 8-byte grid, as they precede a block of doubles at the payload's start."""
    prefix = Writer()
    prefix.header(sec, nanosec, frame_id)
    prefix.align(8)
    return b"".join(prefix.parts)


def pose_array(sec: int, nanosec: int, frame_id: str, points: np.ndarray, quaternions: np.ndarray) -> bytes:
    """geometry_msgs/msg/PoseArray of poses at points (n, 3) with orientations (n, 4) (x, y, z, w)."""
    buffer = Writer()
    buffer.header(sec, nanosec, frame_id)
    buffer.sequence(np.hstack([points, quaternions]), 7)
    return buffer.bytes()


def path(sec: int, nanosec: int, frame_id: str, points: np.ndarray, quaternions: np.ndarray) -> bytes:
    """nav_msgs/msg/Path whose poses (n) all carry the path's header."""
    buffer = Writer()
    buffer.header(sec, nanosec, frame_id)
    buffer.uint32(len(points))
    poses = np.ascontiguousarray(np.hstack([points, quaternions]), dtype="<f8").reshape(-1, 7)
    if len(poses):  # the first pose may start 4 bytes off the 8-byte grid; each after it starts on it
        buffer.header(sec, nanosec, frame_id)
        buffer.doubles(poses[0])
    if len(poses) > 1:  # the same header bytes and padding before every later pose: one block
        head = np.frombuffer(_aligned_header(sec, nanosec, frame_id), np.uint8)
        block = np.empty((len(poses) - 1, head.size + 56), np.uint8)
        block[:, :head.size] = head
        block[:, head.size:] = poses[1:].view(np.uint8)
        buffer.add(block.tobytes())
    return buffer.bytes()


def triangle_list_marker(sec: int, nanosec: int, frame_id: str, namespace: str, marker_id: int,
                         vertices: np.ndarray, color: tuple[float, float, float, float]) -> bytes:
    """visualization_msgs/msg/Marker TRIANGLE_LIST (type 11), action ADD, identity pose, unit scale, one color,
    the triangles' vertices (3k, 3) in the header frame; all other fields empty."""
    buffer = Writer()
    buffer.header(sec, nanosec, frame_id)
    buffer.string(namespace)
    buffer.pack("iii", 4, marker_id, 11, 0)
    buffer.doubles(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]))  # pose, scale
    buffer.pack("ffff", 4, *color)
    buffer.time(0, 0)  # lifetime: forever
    buffer.pack("B", 1, 0)  # frame_locked
    buffer.sequence(vertices, 3)  # points
    buffer.uint32(0)  # colors
    buffer.string("")  # texture_resource
    buffer.header(0, 0, "")  # texture: CompressedImage header, format, data
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
    buffer = Writer()
    buffer.header(sec, nanosec, frame_id)
    buffer.string(image_format)
    buffer.uint32(len(data))
    buffer.add(bytes(data))
    return buffer.bytes()


def needle_state(sec: int, nanosec: int, frame_id: str, insertion_depth: float, inserted_length: float,
                 tip_force_x: float, tip_force_y: float, tip_force_z: float, axial_force: float,
                 kinetic_energy: float, elastic_energy: float) -> bytes:
    """needle_interfaces/msg/NeedleState."""
    buffer = Writer()
    buffer.header(sec, nanosec, frame_id)
    buffer.doubles(np.array([insertion_depth, inserted_length, tip_force_x, tip_force_y, tip_force_z, axial_force,
                             kinetic_energy, elastic_energy]))
    return buffer.bytes()


def shape_error(sec: int, nanosec: int, frame_id: str, model_stamp: tuple[int, int],
                measurement_stamp: tuple[int, int], rmse: float, max_error: float, tip_error: float,
                matched_samples: int, errors: np.ndarray, arc_length: np.ndarray) -> bytes:
    """needle_interfaces/msg/ShapeError; the stamps as (sec, nanosec)."""
    buffer = Writer()
    buffer.header(sec, nanosec, frame_id)
    buffer.time(*model_stamp)
    buffer.time(*measurement_stamp)
    buffer.doubles(np.array([rmse, max_error, tip_error]))
    buffer.uint32(matched_samples)
    buffer.float64_sequence(errors)
    buffer.float64_sequence(arc_length)
    return buffer.bytes()
