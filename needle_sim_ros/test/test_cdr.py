"""The hand-written CDR encoders (:mod:`needle_sim_ros.messages.cdr`, :func:`needle_common.cdr.needle_shape`) byte
for byte against rclpy.

Every encoder's bytes must equal ``rclpy.serialization.serialize_message`` of the equivalent rclpy message, built
field by field here, for every field the encoder writes (Jazzy's full ``visualization_msgs/Marker`` included). The
frame ids have lengths 0 to 11 so that every padding before the following 4- and 8-byte fields occurs; the
sequences are empty, single or long. The decoders read what ``serialize_message`` writes.

rclpy does not write the alignment padding: those bytes hold whatever its freshly allocated buffer held. So the
reference bytes come from serializer processes whose allocator fills new memory with a known byte (glibc's
``MALLOC_PERTURB_``, thread caches off): filled with 0x00 they are what the encoders must write (zero padding), and
a second fill (0xef) shows which bytes rclpy left unwritten.
"""
import os
import pickle
import struct
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Pose, PoseArray, PoseStamped, Quaternion, Vector3, WrenchStamped
from nav_msgs.msg import Path
from needle_interfaces.msg import NeedleShape, NeedleState, ShapeError
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MeshFile

from needle_common.cdr import needle_shape
from needle_sim_ros.messages import cdr
from needle_sim_ros.messages.centerline_display import COLORS, centerline_display
from needle_common.transforms import quaternions_from_x_axes
from needle_sim_ros.messages.geometry import polyline_tangents, tube_triangles
from needle_vision.streams.image_codec import deserialize_image
from needle_sim_ros.messages.shape import shape_error_cdr, time_msg

FRAMES = ("", "w", "ab", "abc", "world", "abcdefg", "needle_base")  # with the NUL: 1, 2, 3, 4, 6, 8, 12 bytes
COUNTS = (0, 1, 3, 50)
SEC, NANOSEC = 1_700_000_001, 234_500_001
#: Jazzy's visualization_msgs/msg/Marker, in wire order: the encoder writes every one of these fields.
JAZZY_MARKER_FIELDS = {
    "header": "std_msgs/Header", "ns": "string", "id": "int32", "type": "int32", "action": "int32",
    "pose": "geometry_msgs/Pose", "scale": "geometry_msgs/Vector3", "color": "std_msgs/ColorRGBA",
    "lifetime": "builtin_interfaces/Duration", "frame_locked": "boolean",
    "points": "sequence<geometry_msgs/Point>", "colors": "sequence<std_msgs/ColorRGBA>",
    "texture_resource": "string", "texture": "sensor_msgs/CompressedImage",
    "uv_coordinates": "sequence<visualization_msgs/UVCoordinate>", "text": "string", "mesh_resource": "string",
    "mesh_file": "visualization_msgs/MeshFile", "mesh_use_embedded_materials": "boolean"}
SERIALIZER = """
import pickle, struct, sys
from rclpy.serialization import serialize_message
while size := sys.stdin.buffer.read(4):
    messages = pickle.loads(sys.stdin.buffer.read(struct.unpack("<I", size)[0]))
    reply = pickle.dumps([serialize_message(m) for m in messages])
    sys.stdout.buffer.write(struct.pack("<I", len(reply)) + reply)
    sys.stdout.buffer.flush()
"""
FILLS = {"zeroed": 0xff, "marked": 0x10}  # MALLOC_PERTURB_ value: new memory is filled with its complement


class Serializer:
    """``serialize_message`` in a process whose new memory is filled with ``fill ^ 0xff``."""

    def __init__(self, fill: int) -> None:
        env = {**os.environ, "MALLOC_PERTURB_": str(fill), "GLIBC_TUNABLES": "glibc.malloc.tcache_count=0"}
        self.process = subprocess.Popen([sys.executable, "-c", SERIALIZER], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, env=env)

    def __call__(self, messages: list) -> list[bytes]:
        request = pickle.dumps(messages)
        self.process.stdin.write(struct.pack("<I", len(request)) + request)
        self.process.stdin.flush()
        size = struct.unpack("<I", self.process.stdout.read(4))[0]
        return pickle.loads(self.process.stdout.read(size))

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait(timeout=10)


@pytest.fixture(scope="module")
def serializers():
    processes = {name: Serializer(fill) for name, fill in FILLS.items()}
    yield processes
    for process in processes.values():
        process.close()


def rclpy_bytes(serializers, messages: list) -> list[tuple[bytes, list[int]]]:
    """serialize_message's bytes of each message with the padding zeroed, and the positions rclpy left unwritten
    (0x00 in one fill, 0xef in the other; every written byte is the same in both)."""
    result = []
    for zeroed, marked in zip(serializers["zeroed"](messages), serializers["marked"](messages)):
        assert len(zeroed) == len(marked)
        unwritten = [i for i, (a, b) in enumerate(zip(zeroed, marked)) if a != b]
        assert all(zeroed[i] == 0x00 and marked[i] == 0xef for i in unwritten)
        result.append((zeroed, unwritten))
    return result


def assert_rclpy_bytes(serializers, encoded: list[bytes], messages: list) -> None:
    """Each encoding is byte for byte serialize_message's, with zero padding."""
    assert len(encoded) == len(messages)
    for ours, message, (reference, _) in zip(encoded, messages, rclpy_bytes(serializers, messages)):
        assert ours == reference, f"{type(message).__name__}: first difference at byte " + str(
            next((i for i, (a, b) in enumerate(zip(ours, reference)) if a != b), min(len(ours), len(reference))))


def test_the_reference_serializers_expose_rclpys_unwritten_padding(serializers):
    # closed form: encapsulation (4) + stamp (8) + frame length (4) + "" with its NUL (1): 3 bytes to the next
    # 4-byte boundary of the payload, then the doubles of NeedleState 8-aligned from the payload's start
    state = NeedleState(header=Header(stamp=Time(sec=1, nanosec=2), frame_id=""))
    [(reference, unwritten)] = rclpy_bytes(serializers, [state])
    assert unwritten == [17, 18, 19] and len(reference) == 4 + 16 + 8 * 8


def header(frame: str) -> Header:
    return Header(stamp=Time(sec=SEC, nanosec=NANOSEC), frame_id=frame)


def pose(position, quaternion) -> Pose:
    return Pose(position=Point(x=position[0], y=position[1], z=position[2]),
                orientation=Quaternion(x=quaternion[0], y=quaternion[1], z=quaternion[2], w=quaternion[3]))


def test_wrench_stamped_many_is_rclpys_wrench_stamped(serializers):
    rng = np.random.default_rng(1)
    times = np.array([1_700_000_001.2345, 12.9999999999, 0.0, 3.0000000004, 7.5])
    for frame in FRAMES:
        wrenches = rng.normal(size=(times.size, 6))
        messages = []
        for t, values in zip(times, wrenches):
            message = WrenchStamped(header=Header(stamp=time_msg(t), frame_id=frame))
            message.wrench.force = Vector3(x=values[0], y=values[1], z=values[2])
            message.wrench.torque = Vector3(x=values[3], y=values[4], z=values[5])
            messages.append(message)
        assert_rclpy_bytes(serializers, cdr.wrench_stamped_many(frame, zip(times, wrenches[:, :3], wrenches[:, 3:])),
                           messages)


def test_pose_array_and_path_are_rclpys(serializers):
    encoded, messages = [], []
    for frame in FRAMES:
        for count in COUNTS:
            rng = np.random.default_rng(count + len(frame))
            points, quaternions = rng.normal(size=(count, 3)), rng.normal(size=(count, 4))
            poses = [pose(p, q) for p, q in zip(points, quaternions)]
            encoded += [cdr.pose_array(SEC, NANOSEC, frame, points, quaternions),
                        cdr.path(SEC, NANOSEC, frame, points, quaternions)]
            messages += [PoseArray(header=header(frame), poses=poses),
                         Path(header=header(frame), poses=[PoseStamped(header=header(frame), pose=p) for p in poses])]
    assert_rclpy_bytes(serializers, encoded, messages)


def test_jazzy_marker_has_the_fields_the_encoder_writes():
    assert Marker.get_fields_and_field_types() == JAZZY_MARKER_FIELDS
    assert MeshFile.get_fields_and_field_types() == {"filename": "string", "data": "sequence<uint8>"}
    assert CompressedImage.get_fields_and_field_types() == {"header": "std_msgs/Header", "format": "string",
                                                            "data": "sequence<uint8>"}


def triangle_list(frame: str, namespace: str, marker_id: int, vertices: np.ndarray, color) -> Marker:
    """The Marker the encoder describes, every one of Jazzy's fields set explicitly."""
    return Marker(header=header(frame), ns=namespace, id=marker_id, type=Marker.TRIANGLE_LIST, action=Marker.ADD,
                  pose=pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]), scale=Vector3(x=1.0, y=1.0, z=1.0),
                  color=ColorRGBA(r=color[0], g=color[1], b=color[2], a=color[3]),
                  lifetime=Duration(sec=0, nanosec=0), frame_locked=False,
                  points=[Point(x=v[0], y=v[1], z=v[2]) for v in vertices], colors=[], texture_resource="",
                  texture=CompressedImage(header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""), format="",
                                          data=b""),
                  uv_coordinates=[], text="", mesh_resource="", mesh_file=MeshFile(filename="", data=b""),
                  mesh_use_embedded_materials=False)


def test_triangle_list_marker_is_rclpys_full_jazzy_marker(serializers):
    encoded, messages = [], []
    color = (0.1, 0.55, 0.8, 0.25)  # float32 on the wire: both round the same doubles
    for frame in FRAMES:
        for count in COUNTS:
            for namespace in ("", "needle", "abc", "measured"):
                vertices = np.random.default_rng(count).normal(size=(3 * count, 3))
                marker_id = -7 if count else 2**31 - 1
                encoded.append(cdr.triangle_list_marker(SEC, NANOSEC, frame, namespace, marker_id, vertices, color))
                messages.append(triangle_list(frame, namespace, marker_id, vertices, color))
    assert_rclpy_bytes(serializers, encoded, messages)


def test_compressed_image_message_is_rclpys(serializers):
    encoded, messages = [], []
    for frame in FRAMES:
        for image_format, size in (("png", 0), ("jpeg", 1), ("mono8; png compressed ", 7), ("", 8), ("png", 13)):
            data = bytes(np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8))
            encoded.append(cdr.compressed_image_message(SEC, NANOSEC, frame, image_format, data))
            messages.append(CompressedImage(header=header(frame), format=image_format, data=data))
    assert_rclpy_bytes(serializers, encoded, messages)


def test_needle_state_is_rclpys(serializers):
    encoded, messages = [], []
    for frame in FRAMES:
        values = np.random.default_rng(len(frame)).normal(size=8)
        encoded.append(cdr.needle_state(SEC, NANOSEC, frame, *values))
        messages.append(NeedleState(header=header(frame), insertion_depth=values[0], inserted_length=values[1],
                                    tip_force=Vector3(x=values[2], y=values[3], z=values[4]), axial_force=values[5],
                                    kinetic_energy=values[6], elastic_energy=values[7]))
    assert_rclpy_bytes(serializers, encoded, messages)


def test_needle_shape_is_rclpys(serializers):
    encoded, messages = [], []
    for frame in FRAMES:
        for count in COUNTS:
            for source in (NeedleShape.SOURCE_MODEL, NeedleShape.SOURCE_STEREO, "x"):
                for with_uncertainty in (False, True):
                    rng = np.random.default_rng(count)
                    points, tangents = rng.normal(size=(count, 3)), rng.normal(size=(count, 3))
                    arc, tip, quaternion = np.cumsum(rng.random(count)), rng.normal(size=3), rng.normal(size=4)
                    uncertainty = rng.random(count) if with_uncertainty else None
                    encoded.append(needle_shape(SEC, NANOSEC, frame, source, points, tangents, arc, tip,
                                                quaternion, uncertainty))
                    messages.append(NeedleShape(
                        header=header(frame), source=source, points=[Point(x=p[0], y=p[1], z=p[2]) for p in points],
                        tangents=[Vector3(x=v[0], y=v[1], z=v[2]) for v in tangents], arc_length=arc.tolist(),
                        uncertainty=[] if uncertainty is None else uncertainty.tolist(),
                        tip_pose=pose(tip, quaternion), length=float(arc[-1]) if count else 0.0))
                    if count:  # a measured shape's default tip pose: the last point along the last tangent
                        assert needle_shape(SEC, NANOSEC, frame, source, points, tangents, arc,
                                            uncertainty=uncertainty) == needle_shape(
                            SEC, NANOSEC, frame, source, points, tangents, arc, points[-1],
                            quaternions_from_x_axes(tangents[-1]), uncertainty)
    assert_rclpy_bytes(serializers, encoded, messages)


def test_shape_error_is_rclpys(serializers):
    encoded, messages = [], []
    for frame in FRAMES:
        for count in COUNTS:
            rng = np.random.default_rng(count)
            result = SimpleNamespace(rmse=rng.random(), max_error=rng.random(), tip_error=rng.random(),
                                     matched_samples=count, errors=rng.random(count), arc_length=rng.random(count))
            model, measured = header(frame), Header(stamp=Time(sec=SEC + 1, nanosec=7), frame_id="camera")
            encoded.append(shape_error_cdr(result, model, measured))
            messages.append(ShapeError(header=Header(stamp=measured.stamp, frame_id=frame), model_stamp=model.stamp,
                                       measurement_stamp=measured.stamp, rmse=result.rmse, max_error=result.max_error,
                                       tip_error=result.tip_error, matched_samples=count,
                                       errors=result.errors.tolist(), arc_length=result.arc_length.tolist()))
    assert_rclpy_bytes(serializers, encoded, messages)


def test_centerline_display_is_rclpys_path_and_marker(serializers):
    s = np.linspace(0.0, 0.27, 20)
    points = np.column_stack([s, 0.01 * np.sin(10 * s), -0.2 * s**2])
    radius = 0.000635
    tangents = polyline_tangents(points)
    poses = [pose(p, q) for p, q in zip(points, quaternions_from_x_axes(tangents))]
    encoded, messages = [], []
    for frame in FRAMES:
        for kind in ("model", "measured"):
            displayed = centerline_display(SEC, NANOSEC, frame, kind, points, radius)
            assert list(displayed) == [f"compare/{kind}/path", f"compare/{kind}/marker"]
            encoded += displayed.values()
            messages += [Path(header=header(frame), poses=[PoseStamped(header=header(frame), pose=p) for p in poses]),
                         triangle_list(frame, kind, 0, tube_triangles(points, tangents, radius), COLORS[kind])]
    assert_rclpy_bytes(serializers, encoded, messages)


@pytest.mark.parametrize("encoding, shape, step", [("rgb8", (5, 7, 3), 24), ("mono8", (3, 2), 3),
                                                   ("mono16", (1, 1, 2), 2), ("bgr8", (0, 0, 3), 0)])
def test_image_decoder_reads_rclpys_image(encoding, shape, step):
    height, width = shape[:2]
    rows = np.random.default_rng(2).integers(0, 255, size=(height, width * shape[2] if len(shape) == 3 else width),
                                             dtype=np.uint8)
    data = np.pad(rows, ((0, 0), (0, step - rows.shape[1]))).tobytes()
    for frame in FRAMES:
        message = Image(header=header(frame), height=height, width=width, encoding=encoding, is_bigendian=0,
                        step=step, data=data)
        decoded = deserialize_image(serialize_message(message), compressed=False)
        assert (decoded.sec, decoded.nanosec, decoded.frame_id) == (SEC, NANOSEC, frame)
        fields = decoded.fields
        assert (fields["height"], fields["width"], fields["encoding"], fields["is_bigendian"], fields["step"]) == (
            height, width, encoding, False, step)
        assert fields["data"].tobytes() == data and not fields["data"].flags.owndata
