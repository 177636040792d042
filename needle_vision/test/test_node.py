"""needle_stereo as a separate process, driven over ROS 2 from this test (isolated ROS domain)."""
import importlib.util
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip("rclpy", reason="the node test needs ROS 2 (rclpy)")
from ament_index_python.packages import get_package_prefix  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2  # noqa: E402

from vision_shapes import SHAPES, distance_to_curve  # noqa: E402
from needle_common.ros.input_status import InputReports  # noqa: E402
from needle_interfaces.msg import NeedleShape  # noqa: E402
from needle_vision.calibration.rig import camera_info_fields  # noqa: E402
from needle_vision.streams.image_codec import compress_image, image_fields  # noqa: E402

PACKAGE = Path(__file__).resolve().parents[1]
REPO = PACKAGE.parent


def start_node(ros_env: dict, *arguments: str) -> subprocess.Popen:
    """The installed needle_stereo (what ``ros2 run needle_vision needle_stereo`` starts: the sourced install
    space's, whose kernels the install step compiled), from the repository root."""
    executable = Path(get_package_prefix("needle_vision")) / "lib" / "needle_vision" / "needle_stereo"
    return subprocess.Popen([str(executable), "--ros-args", *arguments], env=ros_env, cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.parametrize("arguments, named", [
    (["-p", "sync_tolerance:=-1.0"], "sync_tolerance"),
    (["-p", "detection.downsample:=3"], "detection.downsample"),
    (["-p", "left_calibration_file:=package://needle_vision/config/stereo/right.yaml",
      "-p", "right_calibration_file:=package://needle_vision/config/stereo/left.yaml"],
     "left_calibration_file"),
])
def test_bad_parameter_stops_the_node_naming_it(ros_env, arguments, named):
    process = start_node(ros_env, *arguments)
    output, _ = process.communicate(timeout=60)
    assert process.returncode != 0
    assert f"'{named}" in output


def _stop(node, process: subprocess.Popen) -> str:
    """Destroy the test's node, shut rclpy down, SIGINT the node process; its whole output."""
    node.destroy_node()
    rclpy.shutdown()
    process.send_signal(signal.SIGINT)
    try:
        output, _ = process.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        process.kill()
        output, _ = process.communicate()
    return output


def _waiting(node, reports: InputReports, publishers) -> list[str]:
    """What the node still lacks before our ``publishers``' messages are measured: as ``needle_replay
    --wait-for-nodes /needle_stereo`` waits, its input report matching them and taking input (its kernels loaded),
    and our discovery of its measured shape."""
    return reports.waiting_for(["/needle_stereo"], [p.topic_name for p in publishers]) + (
        ["no measured shape publisher"] if node.count_publishers("needle/measured_shape") < 1 else [])


def _wait_for_node(node, process: subprocess.Popen, publishers, warm_up: float = 1.0) -> None:
    """Spin until the node takes the input of our ``publishers`` (:func:`_waiting`; start-up: imports, kernel
    cache, discovery), check it is alive, then spin ``warm_up`` seconds more."""
    reports, deadline = InputReports(node), time.monotonic() + 60
    while time.monotonic() < deadline and _waiting(node, reports, publishers):
        rclpy.spin_once(node, timeout_sec=0.1)
    assert process.poll() is None, process.stdout.read()
    assert not _waiting(node, reports, publishers)
    reports.close()
    end = time.monotonic() + warm_up
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)


def _image_msg(image: np.ndarray, stamp: float, frame_id: str, encoding: str = "mono8") -> Image:
    fields = image_fields(image, "mono8")
    fields["encoding"] = encoding
    msg = Image(**fields)
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(stamp), int(round(stamp % 1 * 1e9))
    msg.header.frame_id = frame_id
    return msg


def test_node_measures_pairs_and_skips_bad_ones(ros_env, tmp_path, rig, background_frames, renders):
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "background": {"frames": 2}, "output_frame": "world", "warning_period": 0.01, "image_qos": "reliable",
        "output_transform": rig.world_from_left.as_xyz_quaternion()}}}))
    process = start_node(ros_env, "--params-file", str(params))  # calibration from camera_info topics
    rclpy.init()
    node = rclpy.create_node("needle_stereo_test")
    try:
        received = {"shape": [], "cloud": [], "debug": []}
        node.create_subscription(NeedleShape, "needle/measured_shape", received["shape"].append, 10)
        node.create_subscription(PointCloud2, "needle/measured_points", received["cloud"].append, 10)
        node.create_subscription(Image, "needle/debug_image", received["debug"].append, 10)
        statuses = []  # the node's measurement reports
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: statuses.extend(
            {kv.key: kv.value for kv in s.values} | {"level": s.level[0], "message": s.message} for s in m.status
            if s.name == "/needle_stereo: measurement"), 10)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        images = {side: node.create_publisher(Image, f"{side}/image_raw", reliable) for side in ("left", "right")}
        infos = {side: node.create_publisher(CameraInfo, f"{side}/camera_info", reliable) for side in ("left", "right")}
        ros = rig.with_ros_rectification()
        deadline = time.monotonic() + 60  # node start-up (imports, kernel cache) and discovery
        publishers, reports = [*images.values(), *infos.values()], InputReports(node)
        # Like a camera driver, publish camera_info for a while before the images, until the node takes them
        warm_up = time.monotonic() + 1.5
        outputs = ("needle/measured_shape", "needle/measured_points", "needle/debug_image")
        while time.monotonic() < deadline and (time.monotonic() < warm_up or _waiting(node, reports, publishers)
                                               or min(node.count_publishers(topic) for topic in outputs) < 1):
            for side, camera in (("left", ros.left), ("right", ros.right)):
                infos[side].publish(CameraInfo(**camera_info_fields(camera)))
            rclpy.spin_once(node, timeout_sec=0.1)
        assert process.poll() is None and not _waiting(node, reports, publishers), process.stdout.read()
        needle = renders("planar")
        pairs = [(1.00, *background_frames[0]), (1.01, *background_frames[1]), (1.02, *needle),
                 (1.03, needle[0][::2, ::2].copy(), needle[1][::2, ::2].copy()),  # wrong size
                 (1.04, *needle), (1.05, *needle)]
        for stamp, left, right in pairs:
            for side, image, camera in (("left", left, ros.left), ("right", right, ros.right)):
                info = CameraInfo(**camera_info_fields(camera))
                info.header = _image_msg(image, stamp, f"{side}_optical").header
                infos[side].publish(info)
                images[side].publish(_image_msg(image, stamp, f"{side}_optical"))
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.05)
        # a left frame without its right one, then a pair in an encoding the node does not read
        images["left"].publish(_image_msg(needle[0], 1.06, "left_optical"))
        for side in ("left", "right"):
            images[side].publish(_image_msg(needle[0], 1.07, f"{side}_optical", encoding="yuv422"))
        end = time.monotonic() + 30  # the first pair loads compiled kernels; debug images (2.3 MB) trail the shapes
        while time.monotonic() < end and (len(received["shape"]) < 3 or not any(
                image.width == 1440 for image in received["debug"])):  # the half-size pair's may come first
            rclpy.spin_once(node, timeout_sec=0.1)
        end = time.monotonic() + 30
        while time.monotonic() < end and not (statuses and statuses[-1]["pairs_skipped_decode_error"] == "1"):
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        output = _stop(node, process)

    # What became of the pairs, on /diagnostics: WARN in the report after the skip, naming what happened since the
    # previous report.
    assert statuses and statuses[-1]["pairs_skipped_decode_error"] == "1", (statuses[-1:], output)
    last = statuses[-1]
    counted = ("pairs_measured", "pairs_background", "pairs_rejected", "pairs_skipped_decode_error", "frames_unpaired",
               "rejected_bad input")
    assert {k: last.get(k) for k in counted} == {
        "pairs_measured": "3", "pairs_background": "2", "pairs_rejected": "1", "pairs_skipped_decode_error": "1",
        "frames_unpaired": "1", "rejected_bad input": "1"}, statuses
    warned = [status for status in statuses if status["level"] == 1]
    assert any("1 pairs skipped decode error" in status["message"] for status in warned), statuses
    stamps = [shape.header.stamp.sec + shape.header.stamp.nanosec * 1e-9 for shape in received["shape"]]
    assert len(stamps) == 3, output  # the three good needle pairs (reliable transport)
    assert all(abs(stamp - 1.03) > 1e-3 for stamp in stamps)  # nothing for the wrong-size pair
    assert "is 720x540 but its calibration is 1440x1080 (rejected so far: bad input 1)" in output
    shape = received["shape"][0]
    assert shape.header.frame_id == "world" and shape.source == NeedleShape.SOURCE_STEREO
    points = np.array([[p.x, p.y, p.z] for p in shape.points])
    distance, _ = distance_to_curve(points, SHAPES["planar"])
    assert np.sqrt(np.mean(distance ** 2)) < 1e-4
    assert len(shape.uncertainty) == len(points) == len(shape.arc_length) == len(shape.tangents)
    assert shape.length == pytest.approx(shape.arc_length[-1])
    tip_axis = np.array([shape.tangents[-1].x, shape.tangents[-1].y, shape.tangents[-1].z])
    q = shape.tip_pose.orientation  # the tip frame's x axis is the tip tangent
    x_axis = np.array([1 - 2 * (q.y ** 2 + q.z ** 2), 2 * (q.x * q.y + q.w * q.z), 2 * (q.x * q.z - q.w * q.y)])
    np.testing.assert_allclose(x_axis, tip_axis, atol=1e-9)
    cloud = received["cloud"][0]
    assert [f.name for f in cloud.fields] == ["x", "y", "z"] and cloud.width == len(points)
    np.testing.assert_allclose(np.frombuffer(bytes(cloud.data), "<f4").reshape(-1, 3), points, atol=1e-6)
    # Side by side, half size (also published for rejected pairs, e.g. 720 px wide for the half-size pair).
    assert any(image.encoding == "bgr8" and (image.width, image.height) == (1440, 540) for image in received["debug"])


@pytest.mark.compiles_from_empty
@pytest.mark.timeout(1800)
def test_a_cold_kernel_cache_delays_the_measurement_not_the_node(ros_env, tmp_path, background_frames, renders):
    """With an empty numba cache (a first run after ``colcon build --symlink-install``, ``NEEDLE_COMPILE_KERNELS=0``
    or another NUMBA_CACHE_DIR) the kernels compile for ~1 min: the node subscribes and reports at once, with
    ``accepting: false`` until they are loaded, counts the pairs it skips meanwhile, and measures the pairs after.
    Before, it compiled before subscribing: no subscription and no report for that minute, a camera's pairs lost
    uncounted. Takes the cold compilation itself: ~1 min on a quiet host, 11 min and more at a load of 15 on 2 cores."""
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "background": {"frames": 1}, "warning_period": 0.01, "image_qos": "reliable",
        "left_calibration_file": "package://needle_vision/config/stereo/left.yaml",
        "right_calibration_file": "package://needle_vision/config/stereo/right.yaml"}}}))
    process = start_node(dict(ros_env, NUMBA_CACHE_DIR=str(tmp_path / "numba_cache")), "--params-file", str(params))
    rclpy.init()
    node = rclpy.create_node("needle_stereo_cold_test")
    try:
        shapes, statuses = [], {"inputs": [], "measurement": []}
        node.create_subscription(NeedleShape, "needle/measured_shape", shapes.append, 10)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: [
            statuses[s.name.split(": ")[1]].append({kv.key: kv.value for kv in s.values}) for s in m.status
            if s.name in ("/needle_stereo: inputs", "/needle_stereo: measurement")], 10)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        images = {side: node.create_publisher(Image, f"{side}/image_raw", reliable) for side in ("left", "right")}
        reports = InputReports(node)

        def spin_until(done, seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end and not done():
                rclpy.spin_once(node, timeout_sec=0.1)

        def publish(stamp: float, pair) -> None:
            for side, image in zip(("left", "right"), pair):
                images[side].publish(_image_msg(image, stamp, f"{side}_optical"))

        def counted(outcome: str) -> str | None:
            return statuses["measurement"][-1][f"pairs_{outcome}"] if statuses["measurement"] else None

        loading = ["/needle_stereo is not taking input yet"]
        spin_until(lambda: _waiting(node, reports, images.values()) == loading, 30)  # imports and discovery
        assert process.poll() is None, process.stdout.read()
        assert _waiting(node, reports, images.values()) == loading
        publish(1.0, renders("planar"))
        spin_until(lambda: counted("skipped_loading_kernels") == "1", 10)
        assert counted("skipped_loading_kernels") == "1" and statuses["inputs"][-1]["accepting"] == "false"
        spin_until(lambda: not _waiting(node, reports, images.values()), 1500)
        assert not _waiting(node, reports, images.values())
        for stamp, pair in ((2.0, background_frames[0]), (2.1, renders("planar"))):
            publish(stamp, pair)
            spin_until(lambda: False, 0.5)
        spin_until(lambda: shapes and counted("measured") == "1", 30)
    finally:
        output = _stop(node, process)
    assert "Traceback" not in output
    assert len(shapes) == 1 and shapes[0].header.stamp.nanosec == 100_000_000, output
    assert {k: counted(k) for k in ("measured", "background", "skipped_loading_kernels")} == {
        "measured": "1", "background": "1", "skipped_loading_kernels": "1"}, output
    assert "pair at 1.000000 s skipped: the measurement kernels are still loading" in output
    assert "measurement kernels ready in" in output and "s (1 pairs skipped)" in output, output


def test_singular_right_projection_is_refused_without_a_crash(ros_env, rig):
    """camera_info whose right P has a zero last row (fx' > 0 still): the node warns naming the field, lives on."""
    process = start_node(ros_env, "-p", "warning_period:=0.01", "-p", "image_qos:=reliable")
    rclpy.init()
    node = rclpy.create_node("needle_stereo_singular_test")
    try:
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        infos = {side: node.create_publisher(CameraInfo, f"{side}/camera_info", reliable) for side in ("left", "right")}
        ros = rig.with_ros_rectification()
        fields = {side: camera_info_fields(camera) for side, camera in (("left", ros.left), ("right", ros.right))}
        fields["right"]["p"] = list(fields["right"]["p"][:8]) + [0.0] * 4
        # camera_info is subscribed before the kernels load (seconds on a loaded machine), the outputs after them:
        # the node spins, and reads what was sent, once its outputs exist
        _wait_for_node(node, process, infos.values(), warm_up=0.0)
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            for side in ("left", "right"):
                infos[side].publish(CameraInfo(**fields[side]))
            rclpy.spin_once(node, timeout_sec=0.1)
        assert process.poll() is None
    finally:
        output = _stop(node, process)
    assert "Traceback" not in output
    assert "camera 'right' (right): projection_matrix is singular" in output, output


def _compressed_msg(image: np.ndarray, stamp: float, frame_id: str, codec: str = "png",
                    corrupt: bool = False) -> CompressedImage:
    image_format, data = compress_image(image, "mono8", codec)
    msg = CompressedImage(format=image_format, data=data[:len(data) // 50] if corrupt else data)
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(stamp), int(round(stamp % 1 * 1e9))
    msg.header.frame_id = frame_id
    return msg


def test_node_measures_compressed_images_and_counts_every_skipped_pair(ros_env, tmp_path, rig, background_frames,
                                                                        renders):
    """image_transport: compressed: PNG and JPEG (quality 95) CompressedImage pairs on image_transport's
    <image>/compressed topics are measured as the raw ones are; a pair with a corrupt image is counted as a decode
    error, a frame without its partner as unpaired, and the node lives on."""
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "background": {"frames": 2}, "output_frame": "world", "warning_period": 0.01, "image_qos": "reliable",
        "image_transport": "compressed",
        "left_calibration_file": "package://needle_vision/config/stereo/left.yaml",
        "right_calibration_file": "package://needle_vision/config/stereo/right.yaml",
        "output_transform": rig.world_from_left.as_xyz_quaternion()}}}))
    process = start_node(ros_env, "--params-file", str(params))
    rclpy.init()
    node = rclpy.create_node("needle_stereo_compressed_test")
    try:
        shapes, statuses = [], []
        node.create_subscription(NeedleShape, "needle/measured_shape", shapes.append, 10)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: statuses.extend(
            {kv.key: kv.value for kv in s.values} for s in m.status if s.name == "/needle_stereo: measurement"), 10)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        images = {side: node.create_publisher(CompressedImage, f"{side}/image_raw/compressed", reliable)
                  for side in ("left", "right")}
        _wait_for_node(node, process, images.values())
        needle = renders("planar")
        frames = [(1.00, background_frames[0], "png", ()), (1.01, background_frames[1], "png", ()),
                  (1.02, needle, "png", ()), (1.03, needle, "jpeg", ()), (1.04, needle, "png", ("left",)),
                  (1.05, (needle[0], None), "png", ()), (1.06, needle, "png", ())]
        for stamp, pair, codec, corrupt in frames:
            for side, image in zip(("left", "right"), pair):
                if image is not None:
                    images[side].publish(_compressed_msg(image, stamp, f"{side}_optical", codec, side in corrupt))
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.05)
        end = time.monotonic() + 30
        while time.monotonic() < end and not (len(shapes) >= 3 and statuses
                                              and statuses[-1]["pairs_measured"] == "3"):
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        output = _stop(node, process)
    assert "Traceback" not in output
    assert statuses, output
    counted = ("pairs_measured", "pairs_background", "pairs_rejected", "pairs_skipped_decode_error",
               "pairs_skipped_no_calibration", "frames_unpaired")
    assert {k: statuses[-1][k] for k in counted} == {
        "pairs_measured": "3", "pairs_background": "2", "pairs_rejected": "0", "pairs_skipped_decode_error": "1",
        "pairs_skipped_no_calibration": "0", "frames_unpaired": "1"}, (statuses[-1], output)
    assert "pair at 1.040000 s skipped: cannot decode the compressed image" in output
    stamps = [round(shape.header.stamp.sec + shape.header.stamp.nanosec * 1e-9, 3) for shape in shapes]
    assert stamps == [1.02, 1.03, 1.06], output
    for shape in shapes:  # PNG and JPEG alike
        points = np.array([[p.x, p.y, p.z] for p in shape.points])
        distance, _ = distance_to_curve(points, SHAPES["planar"])
        assert np.sqrt(np.mean(distance ** 2)) < 1e-4


def _pose_msg(stamp: float, frame_id: str, position) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(stamp), int(round(stamp % 1 * 1e9))
    msg.header.frame_id = frame_id
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
    msg.pose.orientation.w = 1.0
    return msg


@pytest.mark.parametrize("source", [
    "topic",
    pytest.param("tf", marks=pytest.mark.skipif(
        importlib.util.find_spec("tf2_ros") is None,
        reason="tf2_ros is not installed (no PyPI wheel): the node's TF lookup of base_pose.frame cannot run")),
])
def test_node_tells_base_from_tip_by_the_base_pose(ros_env, tmp_path, rig, background_frames, renders, source):
    """base_point at the tip of the measured needle: without a base pose the shape would start at its tip. The
    base pose (at the shapes' base, the world origin) comes from the base_pose topic, after a non-finite one
    (warned about and ignored), or from TF (frame needle_base)."""
    base_point = SHAPES["planar"][-1]
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "background": {"frames": 1}, "output_frame": "world", "warning_period": 0.01, "image_qos": "reliable",
        "left_calibration_file": "package://needle_vision/config/stereo/left.yaml",
        "right_calibration_file": "package://needle_vision/config/stereo/right.yaml",
        "output_transform": rig.world_from_left.as_xyz_quaternion(), "base_point": base_point.tolist()}}}))
    process = start_node(ros_env, "--params-file", str(params))
    rclpy.init()
    node = rclpy.create_node("needle_stereo_base_test")
    try:
        shapes = []
        node.create_subscription(NeedleShape, "needle/measured_shape", shapes.append, 10)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        images = {side: node.create_publisher(Image, f"{side}/image_raw", reliable) for side in ("left", "right")}
        poses = node.create_publisher(PoseStamped, "base_pose", reliable)
        if source == "tf":
            from tf2_ros import StaticTransformBroadcaster
            from needle_common.ros.tf_output import transform_stamped
            StaticTransformBroadcaster(node).sendTransform(transform_stamped(
                node.get_clock().now().to_msg(), "world", "needle_base", [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]))
        _wait_for_node(node, process, (*images.values(), poses))
        for stamp, (left, right) in ((1.00, background_frames[0]), (1.01, renders("planar")),
                                     (1.02, renders("planar"))):
            if source == "topic":
                poses.publish(_pose_msg(stamp - 0.003, "world", (float("nan"), 0.0, 0.0)))
                poses.publish(_pose_msg(stamp - 0.002, "world", (0.0, 0.0, 0.0)))
                rclpy.spin_once(node, timeout_sec=0.05)
            for side, image in (("left", left), ("right", right)):
                images[side].publish(_image_msg(image, stamp, f"{side}_optical"))
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.05)
        end = time.monotonic() + 10
        while time.monotonic() < end and len(shapes) < 2:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        output = _stop(node, process)
    assert len(shapes) == 2, output
    for shape in shapes:
        first, last = (np.array([p.x, p.y, p.z]) for p in (shape.points[0], shape.points[-1]))
        assert np.linalg.norm(first) < 2e-3 and np.linalg.norm(last - base_point) < 2e-3
    if source == "topic":
        assert "base pose on 'base_pose' ignored: non-finite" in output
