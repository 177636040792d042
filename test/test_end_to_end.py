"""End to end on short slices of the bundled synthetic bags (issue 7): the offline batch mode, the main job's
pipeline of separate node processes driven by needle_replay, the single-process bringup, and the written MCAP
decoded message by message by two independent readers (rosbags, and mcap's ROS 2 decoder).

The bags' measurements are synthetic (bags/README.md): a finer, differently damped run of the same ANCF model
rendered by the stereo renderer with sensor noise. The slices start at the bag start so the stereo gets its
needle-free background pair first.
"""
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from needle_sim_ros.experiments.protocols import EXPERIMENTS
from needle_sim_ros import cdr
from needle_sim_ros.offline.cli import main as offline_main
from needle_sim_ros.offline.parameters import experiment_for_bag
from needle_sim_ros.offline.pipeline import OfflinePipeline

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import main_job  # noqa: E402  (scripts/main_job.py: the live pipeline's process handling)

DYNAMIC = REPO / "bags" / "dynamic_pitch.mcap"
STATIC = REPO / "bags" / "static_tip_load.mcap"
DYNAMIC_SLICE = 2.6  # [s] the needle-free pair at 0 s and stereo pairs at 1.5, 2.0 and 2.5 s (pitching from 1 s)
PAPER_RMSE = 0.5e-3  # [m] issue 7's bound (seed 000 reports 0.43 mm against real measurements)
G = 9.81


def test_offline_batch_mode_dynamic_rmse_is_below_half_a_millimetre(offline_dynamic):
    summary = offline_dynamic["summary"]
    comparison = summary["comparison"]
    assert comparison["compared"] == 3 and comparison["unpaired_measurements"] == 0  # every stereo pair compared
    assert comparison["rmse_max_m"] < PAPER_RMSE
    assert summary["simulator"]["failed_steps"] == 0 and summary["simulator"]["skipped_time_s"] == 0.0
    # The error splits into the model's and the stereo's own error against the ground truth; each is below it.
    truth = summary["versus_ground_truth"]
    assert truth["instants"] == 3 and truth["model_rmse_mean_m"] < PAPER_RMSE
    assert truth["measurement_rmse_mean_m"] < PAPER_RMSE
    assert {Path(p).name for p in summary["plots"]} == {"centerlines.png", "error_vs_time.png", "wrench_vs_time.png"}


def test_offline_batch_mode_is_deterministic(offline_dynamic, tmp_path):
    # The same bag slice and parameters give the same comparisons to the last bit (no wall-clock dependence).
    run = OfflinePipeline(experiment_for_bag(DYNAMIC)).run(DYNAMIC, None, duration=DYNAMIC_SLICE)
    first = offline_dynamic["summary"]["comparison"]
    assert len(run.errors) == first["compared"]
    # the summaries accumulate in the pipeline's own order, so equal runs give equal means to the last bit
    assert run.summary["comparison"] == first


def test_a_wrong_youngs_modulus_gives_a_clearly_larger_error():
    # Static bag, 3.1 s: the settled needle under gravity (1.5 s) and with 20 g on the tip (3.0 s).
    # Beam theory (independent of the model): the tip deflects by P L^3 / (3 E I) = 52 mm under 20 g; a model
    # with E 30 % too high deflects 1/1.3 of that, 12 mm less at the tip, and, with the deflection shape
    # s^2 (3L - s), about a third of that as RMS over the needle: ~4 mm. Bound: half of it.
    experiment = experiment_for_bag(STATIC)
    right = OfflinePipeline(experiment).run(STATIC, None, duration=3.1)
    wrong = OfflinePipeline(experiment, {"needle_simulator": {"needle.youngs_modulus": 1.3 * 193e9}}).run(
        STATIC, None, duration=3.1)
    assert [e.header.stamp for e in right.errors] == [e.header.stamp for e in wrong.errors] and len(right.errors) == 2
    loaded_right, loaded_wrong = right.errors[1].rmse, wrong.errors[1].rmse
    radius, length = 0.635e-3, 0.27
    deflection = 0.02 * G * length**3 / (3 * 193e9 * np.pi * radius**4 / 4)
    assert loaded_right < PAPER_RMSE
    assert loaded_wrong > 0.5 * deflection * (1 - 1 / 1.3) / 3
    assert loaded_wrong > 10 * loaded_right


@pytest.mark.parametrize("name", ["dynamic_pitch", "insertion"])
def test_the_protocols_base_velocity_and_acceleration_are_the_derivatives_of_the_pose(name):
    # The ground truth is driven by the closed-form motion; central differences of the pose must match its rates.
    # Step 1e-4 s: truncation ~h^2 |x^(3)| / 6 and round-off ~1e-16 / h (velocity) or 1e-16 / h^2 (acceleration)
    # are far below the bounds of 1e-5 and 1e-3 of the peak rates.
    experiment, h = EXPERIMENTS[name](), 1e-4
    times = np.linspace(0.05, experiment.duration - 0.05, 97)
    if name == "dynamic_pitch":
        rate = "angular"
        value = (lambda t: 2 * np.arctan2(experiment.base(t).orientation[1], experiment.base(t).orientation[3]))
        axis = 1
    else:
        rate, value, axis = "linear", (lambda t: experiment.base(t).position[0]), 0
    velocity = np.array([getattr(experiment.base(t), f"{rate}_velocity")[axis] for t in times])
    acceleration = np.array([getattr(experiment.base(t), f"{rate}_acceleration")[axis] for t in times])
    assert np.allclose(velocity, [(value(t + h) - value(t - h)) / (2 * h) for t in times],
                       atol=1e-5 * np.abs(velocity).max())
    assert np.allclose(acceleration, [(value(t + h) - 2 * value(t) + value(t - h)) / h**2 for t in times],
                       atol=1e-3 * np.abs(acceleration).max())


def test_fast_cdr_encoders_decode_to_the_nodes_messages():
    # The offline pipeline writes the wrench and model shape bytes itself; rclpy must read back exactly the
    # messages the simulator node builds (padding bytes may differ: rclpy leaves them uninitialised).
    from geometry_msgs.msg import WrenchStamped
    from needle_interfaces.msg import NeedleShape
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Header

    from needle_sim_ros.nodes.shape_messages import needle_shape_msg, time_msg
    rng = np.random.default_rng(7)
    stamp = time_msg(1_700_000_001.2345)
    for count, frame, uncertainty in ((50, "world", None), (7, "w", rng.random(7)), (1, "abcdefg", None)):
        points, tangents, arc = rng.random((count, 3)), rng.random((count, 3)), np.cumsum(rng.random(count))
        tip, quaternion = rng.random(3), rng.random(4)
        expected = needle_shape_msg(Header(stamp=stamp, frame_id=frame), "model", points, tangents, arc, tip,
                                    quaternion, uncertainty)
        data = cdr.needle_shape(stamp.sec, stamp.nanosec, frame, "model", points, tangents, arc, tip, quaternion,
                                uncertainty)
        assert deserialize_message(data, NeedleShape) == expected
    from needle_interfaces.msg import NeedleState
    values = rng.random(8)
    state = NeedleState(header=Header(stamp=stamp, frame_id="world"), insertion_depth=values[0],
                        inserted_length=values[1], axial_force=values[5], kinetic_energy=values[6],
                        elastic_energy=values[7])
    state.tip_force.x, state.tip_force.y, state.tip_force.z = values[2:5]
    assert deserialize_message(cdr.needle_state(stamp.sec, stamp.nanosec, "world", *values), NeedleState) == state
    times = np.array([1_700_000_001.2345, 12.9999999999, 0.0, 3.0000000004])
    wrenches = rng.random((times.size, 6))
    encoded = cdr.wrench_stamped_many("needle_base", zip(times, wrenches[:, :3], wrenches[:, 3:]))
    for t, data, values in zip(times, encoded, wrenches):
        wrench = deserialize_message(data, WrenchStamped)
        assert wrench.header == Header(stamp=time_msg(t), frame_id="needle_base")
        assert [wrench.wrench.force.x, wrench.wrench.force.y, wrench.wrench.force.z] == values[:3].tolist()
        assert [wrench.wrench.torque.x, wrench.wrench.torque.y, wrench.wrench.torque.z] == values[3:].tolist()


def test_visualization_encoders_decode_to_rclpy_built_messages():
    # The simulator publishes Path, PoseArray and the Marker tube as CDR bytes; rclpy must read back the messages
    # one would build field by field.
    from geometry_msgs.msg import Point, Pose, PoseArray, PoseStamped, Quaternion
    from nav_msgs.msg import Path as PathMsg
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import ColorRGBA, Header
    from visualization_msgs.msg import Marker

    from needle_sim_ros.nodes.shape_messages import time_msg
    rng = np.random.default_rng(5)
    stamp = time_msg(42.125)
    for count, frame in ((50, "world"), (3, "w"), (1, "abcdefgh")):
        points, quaternions = rng.random((count, 3)), rng.random((count, 4))
        header = Header(stamp=stamp, frame_id=frame)
        poses = [Pose(position=Point(x=p[0], y=p[1], z=p[2]), orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))
                 for p, q in zip(points, quaternions)]
        assert deserialize_message(cdr.pose_array(stamp.sec, stamp.nanosec, frame, points, quaternions),
                                   PoseArray) == PoseArray(header=header, poses=poses)
        assert deserialize_message(cdr.path(stamp.sec, stamp.nanosec, frame, points, quaternions), PathMsg) == \
            PathMsg(header=header, poses=[PoseStamped(header=header, pose=pose) for pose in poses])
        vertices = rng.random((3 * count, 3))
        marker = Marker(header=header, ns="needle", id=7, type=Marker.TRIANGLE_LIST, action=Marker.ADD,
                        color=ColorRGBA(r=0.75, g=0.75, b=0.8, a=1.0),
                        points=[Point(x=v[0], y=v[1], z=v[2]) for v in vertices])
        marker.pose.orientation.w = 1.0
        marker.scale.x = marker.scale.y = marker.scale.z = 1.0
        encoded = cdr.triangle_list_marker(stamp.sec, stamp.nanosec, frame, "needle", 7, vertices,
                                           (0.75, 0.75, 0.8, 1.0))
        # (compared after rclpy's own round trip: the color is float32 on the wire)
        assert deserialize_message(encoded, Marker) == deserialize_message(serialize_message(marker), Marker)


def test_image_and_pose_decoders_read_rclpy_serialized_messages():
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header

    from needle_sim_ros.nodes.shape_messages import time_msg
    pixels = np.random.default_rng(2).integers(0, 255, size=(5, 7, 3), dtype=np.uint8)
    for frame, encoding in (("left_camera_optical_frame", "rgb8"), ("l", "bgr8"), ("", "mono16")):
        message = Image(header=Header(stamp=time_msg(12.5), frame_id=frame), height=5, width=7, encoding=encoding,
                        is_bigendian=0, step=24, data=np.pad(pixels.reshape(5, 21), ((0, 0), (0, 3))).tobytes())
        decoded = cdr.image(serialize_message(message))
        assert decoded.header == message.header
        assert (decoded.height, decoded.width, decoded.encoding, decoded.step) == (5, 7, encoding, 24)
        assert decoded.data.tobytes() == bytes(message.data) and not decoded.data.flags.owndata
    from geometry_msgs.msg import PoseStamped
    for frame in ("", "w", "world", "base_link_x"):
        pose = PoseStamped(header=Header(stamp=time_msg(3.25), frame_id=frame))
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = 0.1, -0.2, 0.3
        orientation = pose.pose.orientation
        orientation.x, orientation.y, orientation.z, orientation.w = 0.5, 0.5, -0.5, 0.5
        decoded = cdr.pose_stamped(serialize_message(pose))
        assert decoded.stamp_ns == 3_250_000_000 and decoded.frame_id == frame
        assert decoded.position.tolist() == [0.1, -0.2, 0.3] and decoded.orientation.tolist() == [0.5, 0.5, -0.5, 0.5]


def decode_with_rosbags(path: Path) -> dict[str, list]:
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(path) as reader:
        for connection in reader.connections:
            typestore.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
        decoded: dict[str, list] = {}
        for connection, _, raw in reader.messages():
            decoded.setdefault(connection.topic, []).append(typestore.deserialize_cdr(raw, connection.msgtype))
    return decoded


def decode_with_mcap_ros2(path: Path) -> dict[str, list]:
    decoded: dict[str, list] = {}
    with open(path, "rb") as stream:
        for _, channel, _, msg in make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            decoded.setdefault(channel.topic, []).append(msg)
    return decoded


def assert_log_decodes_identically(path: Path) -> dict[str, list]:
    """Both readers decode every message of the log, with equal content where it matters for the results."""
    a, b = decode_with_rosbags(path), decode_with_mcap_ros2(path)
    assert {t: len(m) for t, m in a.items()} == {t: len(m) for t, m in b.items()}
    assert {"/needle/shape", "/needle/measured_shape", "/shape_error", "/base_pose", "/wrench"} <= set(a)
    for x, y in zip(a["/shape_error"], b["/shape_error"]):
        assert (x.rmse, x.matched_samples, list(x.errors)) == (y.rmse, y.matched_samples, list(y.errors))
    for x, y in zip(a["/needle/shape"], b["/needle/shape"]):
        assert [(p.x, p.y, p.z) for p in x.points] == [(p.x, p.y, p.z) for p in y.points]
        assert x.header.frame_id == y.header.frame_id == "world" and x.source == y.source == "model"
    assert [w.wrench.force.x for w in a["/wrench"]] == [w.wrench.force.x for w in b["/wrench"]]
    return a


def test_offline_log_decodes_message_by_message_with_two_independent_readers(offline_dynamic):
    decoded = assert_log_decodes_identically(offline_dynamic["dir"] / "pipeline.mcap")
    assert len(decoded["/shape_error"]) == 3 and len(decoded["/wrench"]) == 2600  # one wrench per 1 ms step


def test_live_pipeline_of_node_processes_driven_by_replay(ros_env, tmp_path):
    """The main job: simulator, stereo and comparison in separate processes with use_sim_time, needle_replay
    playing a 2.6 s slice. Played at half speed so that a loaded test machine keeps up; bench/bench_pipeline.py
    measures 1x."""
    result = subprocess.run([sys.executable, str(REPO / "scripts" / "main_job.py"), "--bag",
                             str(DYNAMIC), "--duration", str(DYNAMIC_SLICE), "--rate", "0.5", "--skip-offline",
                             "--output-dir", str(tmp_path)], env=ros_env, capture_output=True, text=True, timeout=400)
    out = tmp_path / "live"
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["comparison"]["compared"] >= 1, result.stdout[-2000:]
    assert summary["comparison"]["rmse_max_m"] < PAPER_RMSE
    assert "RMSE mean" in result.stdout and str(out / "needle_compare.mcap") in result.stdout
    assert_log_decodes_identically(out / "needle_compare.mcap")


def test_bringup_composes_the_three_nodes_in_one_process(ros_env, tmp_path):
    bag = main_job.slice_bag(DYNAMIC, tmp_path / "slice.mcap", 0.0, DYNAMIC_SLICE, background_frames=1)
    log, summary = tmp_path / "bringup.mcap", tmp_path / "bringup.json"
    bringup = subprocess.Popen([sys.executable, "-m", "needle_sim_ros.nodes.bringup", "--experiment",
                                str(REPO / "config" / "experiments" / "dynamic_pitch.yaml"), "--ros-args",
                                "-p", "use_sim_time:=true", "-p", f"log.path:={log}", "-p", f"summary_path:={summary}"],
                               env=ros_env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        replay = subprocess.run([sys.executable, "-m", "needle_sim_ros.nodes.replay_node", str(bag), "--clock", "200",
                                 "--rate", "0.5", "--topics", "/base_pose", "/left/image_raw", "/right/image_raw",
                                 "--wait-for-subscribers", "60", "--delay", "1.0"],
                                env=ros_env, cwd=REPO, capture_output=True, text=True, timeout=120)
        assert replay.returncode == 0, replay.stdout + replay.stderr
        time.sleep(2.0)  # the last stereo pair is processed and compared
    finally:
        bringup.send_signal(signal.SIGINT)
        output, _ = bringup.communicate(timeout=30)
    assert bringup.returncode == 0, output
    assert "running needle_simulator, needle_stereo, needle_compare in one process" in output
    # All three worked in the one process: model shapes, stereo measurements, and each measurement either compared
    # or counted as unpaired (on a loaded machine the composed simulator may lag; bench/bench_pipeline.py measures).
    result = json.loads(summary.read_text())
    decoded = decode_with_mcap_ros2(log)
    measured = len(decoded.get("/needle/measured_shape", []))
    assert len(decoded.get("/needle/shape", [])) > 10 and measured >= 1, output
    assert result["compared"] + result["unpaired_measurements"] == measured, (result, output)


@pytest.fixture(scope="module")
def offline_dynamic(tmp_path_factory):
    directory = tmp_path_factory.mktemp("offline")
    assert offline_main([str(DYNAMIC), "--duration", str(DYNAMIC_SLICE), "--output-dir", str(directory),
                         "--quiet"]) == 0
    return {"dir": directory, "summary": json.loads((directory / "summary.json").read_text())}
