"""The CameraInfo decoder (needle_common.cdr) against rclpy's serializer and the mcap_ros2 writer: the same stamp,
frame, size, distortion model and D, K, R, P for every alignment of the fields after the two strings and every
length of D; what is no CameraInfo is a ValueError."""
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, RegionOfInterest
from std_msgs.msg import Header

from needle_common.cdr import camera_info

SEC, NANOSEC = 1_700_000_001, 234_500_001
K = [1200.5, 0.0, 720.25, 0.0, 1199.75, 540.125, 0.0, 0.0, 1.0]
R = [0.999, -0.01, 0.02, 0.0101, 0.9999, -0.003, -0.02, 0.0032, 0.9998]
P = [1100.0, 0.0, 700.0, -55.5, 0.0, 1100.0, 530.0, 0.0, 0.0, 0.0, 1.0, 0.0]
D = {0: [], 1: [-0.25], 5: [-0.25, 0.125, 1e-3, -2e-4, 0.0625], 8: [0.1 * k - 0.3 for k in range(8)]}


def fields(frame: str, model: str, d: list[float]) -> dict:
    return {"header": Header(stamp=Time(sec=SEC, nanosec=NANOSEC), frame_id=frame), "height": 1080, "width": 1440,
            "distortion_model": model, "d": d, "k": K, "r": R, "p": P, "binning_x": 2, "binning_y": 3,
            "roi": RegionOfInterest(x_offset=1, y_offset=2, height=3, width=4, do_rectify=True)}


def check(decoded, frame: str, model: str, d: list[float]) -> None:
    assert decoded.stamp_ns == SEC * 1_000_000_000 + NANOSEC and decoded.frame_id == frame
    assert (decoded.height, decoded.width, decoded.distortion_model) == (1080, 1440, model)
    assert decoded.d.tolist() == d and decoded.k.tolist() == K and decoded.r.tolist() == R
    assert decoded.p.tolist() == P


@pytest.mark.parametrize("frame", ["", "l", "ab", "abc", "left_optical", "left_optic"])
@pytest.mark.parametrize("model", ["", "equidistant", "plumb_bob", "rational_polynomial"])
@pytest.mark.parametrize("count", sorted(D))
def test_reads_rclpys_camera_info(frame, model, count):
    data = serialize_message(CameraInfo(**fields(frame, model, D[count])))
    for message in (data, memoryview(data)):  # a subscription's bytes, a bag's view
        check(camera_info(message), frame, model, D[count])


def test_reads_what_the_mcap_ros2_writer_wrote(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    type_name = "sensor_msgs/msg/CameraInfo"
    path = tmp_path / "infos.mcap"
    cases = [("left_optical", "plumb_bob", D[5]), ("r", "equidistant", D[1]), ("", "", D[0])]
    with open(path, "wb") as stream:
        writer = Writer(stream)
        schema = writer.register_msgdef(type_name, get_typestore(Stores.ROS2_JAZZY).generate_msgdef(
            type_name, ros_version=2)[0])
        for frame, model, d in cases:
            message = fields(frame, model, d)
            message["header"] = {"stamp": {"sec": SEC, "nanosec": NANOSEC}, "frame_id": frame}
            message["roi"] = {"x_offset": 1, "y_offset": 2, "height": 3, "width": 4, "do_rectify": True}
            writer.write_message("/left/camera_info", schema, message)
        writer.finish()
    with open(path, "rb") as stream:
        decoded = [camera_info(message.data) for _, _, message in make_reader(stream).iter_messages()]
    assert len(decoded) == len(cases)
    for info, case in zip(decoded, cases):
        check(info, *case)


def test_what_is_no_camera_info_is_a_value_error():
    data = serialize_message(CameraInfo(**fields("left_optical", "plumb_bob", D[5])))
    with pytest.raises(ValueError, match="little-endian CDR"):
        camera_info(b"\x00\x00" + data[2:])  # big endian
    for end in (20, 40, 60, 100, len(data) - 120):  # cut in the frame_id, before the model, in D, before K, in P
        with pytest.raises(ValueError, match="truncated"):
            camera_info(data[:end])
    long_model = bytearray(data)
    long_model[40:44] = b"\xff\xff\xff\x7f"  # the distortion model's length (after frame_id, height, width)
    with pytest.raises(ValueError, match="truncated"):
        camera_info(bytes(long_model))
