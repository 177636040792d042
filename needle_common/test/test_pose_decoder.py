"""The one PoseStamped decoder (needle_common.cdr) against rclpy's serializer and the mcap_ros2 writer: the same
stamp, frame and pose for every alignment of the pose after the frame_id; what is no PoseStamped is a ValueError."""
import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from needle_common.cdr import pose_stamped

FRAMES = ("", "w", "ab", "abc", "world", "abcdefg", "needle_base")  # with the NUL: 1, 2, 3, 4, 6, 8, 12 bytes
SEC, NANOSEC = 1_700_000_001, 234_500_001
POSITION, QUATERNION = [0.1, -0.2, 0.3], [0.5, 0.5, -0.5, 0.5]


def serialized(frame: str) -> bytes:
    return serialize_message(PoseStamped(
        header=Header(stamp=Time(sec=SEC, nanosec=NANOSEC), frame_id=frame),
        pose=Pose(position=Point(x=POSITION[0], y=POSITION[1], z=POSITION[2]),
                  orientation=Quaternion(x=QUATERNION[0], y=QUATERNION[1], z=QUATERNION[2], w=QUATERNION[3]))))


@pytest.mark.parametrize("frame", FRAMES)
def test_reads_rclpys_pose_stamped(frame):
    for data in (serialized(frame), memoryview(serialized(frame))):  # a subscription's bytes, a bag's view
        decoded = pose_stamped(data)
        assert decoded.stamp_ns == SEC * 1_000_000_000 + NANOSEC and decoded.frame_id == frame
        assert decoded.stamp == pytest.approx(SEC + NANOSEC * 1e-9, abs=1e-6)  # float64 resolution at 1.7e9 s
        assert decoded.position.tolist() == POSITION and decoded.orientation.tolist() == QUATERNION
        assert not decoded.position.flags.writeable  # a view of the message, not a copy


def test_reads_what_the_mcap_ros2_writer_wrote(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    type_name = "geometry_msgs/msg/PoseStamped"
    path = tmp_path / "poses.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        schema = writer.register_msgdef(type_name, get_typestore(Stores.ROS2_JAZZY).generate_msgdef(
            type_name, ros_version=2)[0])
        for frame_id in ("", "w", "world_frame"):
            writer.write_message("/base_pose", schema, {
                "header": {"stamp": {"sec": 12, "nanosec": 250_000_000}, "frame_id": frame_id},
                "pose": {"position": {"x": 0.1, "y": -0.2, "z": 0.3},
                         "orientation": {"x": 0.5, "y": 0.5, "z": 0.5, "w": 0.5}}})
        writer.finish()
    with open(path, "rb") as stream:
        poses = [pose_stamped(message.data) for _, _, message in make_reader(stream).iter_messages()]
    assert [pose.frame_id for pose in poses] == ["", "w", "world_frame"]
    for pose in poses:
        assert pose.stamp == 12.25 and pose.position.tolist() == [0.1, -0.2, 0.3]
        assert pose.orientation.tolist() == [0.5, 0.5, 0.5, 0.5]


@pytest.mark.parametrize("data, message", [
    (b"\x00\x00\x00\x00" + bytes(60), "little-endian CDR"),  # big endian
    (b"\x00\x01\x00\x00" + bytes(8), "little-endian CDR"),  # shorter than a header
    (b"\x00\x01\x00\x00" + bytes(20), "truncated"),  # no pose after the header
    (b"\x00\x01\x00\x00" + bytes(8) + b"\xff\xff\xff\x7f" + bytes(60), "truncated"),  # frame_id longer than the data
])
def test_what_is_no_pose_stamped_is_a_value_error(data, message):
    with pytest.raises(ValueError, match=message):
        pose_stamped(data)


def test_a_frame_id_that_is_not_utf8_matches_no_frame():
    data = bytearray(serialized("ab"))
    data[16] = 0xFF
    assert pose_stamped(bytes(data)).frame_id == "\ufffdb"
    np.testing.assert_array_equal(pose_stamped(bytes(data)).position, POSITION)
