"""The shipped display layouts against the pipeline on a bag (no browser, no RViz needed): every topic and frame
the Foxglove layout (share/needle_sim_ros/config/foxglove/needle_compare.json) references is in a comparison log;
every topic the RViz config (share/needle_sim_ros/rviz/needle.rviz) displays is in the running graph with the type
its display shows and a publisher its subscription can match, and every frame it names is on /tf or /tf_static."""
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from ament_index_python.packages import get_package_share_directory
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from visualization_msgs.msg import Marker

from test_end_to_end import DYNAMIC, DYNAMIC_SLICE, REPO, decode_with_mcap_ros2, main_job
from needle_sim_ros.offline.pipeline import OfflinePipeline
from needle_sim_ros.parameters.experiment import experiment_for_bag
from workspaces import build_tf2_msgs, environment_with

LAYOUT = Path(get_package_share_directory("needle_sim_ros")) / "config" / "foxglove" / "needle_compare.json"
RVIZ = Path(get_package_share_directory("needle_sim_ros")) / "rviz" / "needle.rviz"
# The message type each RViz 2 display class subscribes to (rviz_default_plugins, jazzy).
RVIZ_DISPLAY_TYPES = {"rviz_default_plugins/Marker": "visualization_msgs/msg/Marker",
                      "rviz_default_plugins/Path": "nav_msgs/msg/Path",
                      "rviz_default_plugins/PoseArray": "geometry_msgs/msg/PoseArray",
                      "rviz_default_plugins/Wrench": "geometry_msgs/msg/WrenchStamped",
                      "rviz_default_plugins/PointCloud2": "sensor_msgs/msg/PointCloud2",
                      "rviz_default_plugins/Image": "sensor_msgs/msg/Image"}


def layout_references(layout: dict) -> tuple[set[str], set[str]]:
    """(topics, frames) a Foxglove layout refers to: 3D panel topics, plot message paths, followed/grid frames."""
    topics, frames = set(), set()
    for panel_id, config in layout["configById"].items():
        topics |= set(config.get("topics", {}))
        topics |= {re.match(r"(/[^.\[{]+)", path["value"]).group(1) for path in config.get("paths", [])}
        frames |= {config[key] for key in ("followTf",) if config.get(key)}
        frames |= {layer["frameId"] for layer in config.get("layers", {}).values() if layer.get("frameId")}
    return topics, frames


def rviz_references(config: dict) -> tuple[dict[str, tuple[str, str]], set[str]]:
    """({topic: (display class, reliability)}, frames) of an RViz 2 config: display topics, fixed/reference/target
    frames."""
    topics, frames = {}, set()

    def visit(node) -> None:
        if isinstance(node, dict):
            if isinstance(node.get("Topic"), dict):
                topics[node["Topic"]["Value"]] = (node["Class"], node["Topic"]["Reliability Policy"])
            frames.update(str(node[key]) for key in ("Fixed Frame", "Reference Frame", "Target Frame")
                          if key in node and not str(node[key]).startswith("<"))
            for value in node.values():
                visit(value)
        elif isinstance(node, list):
            for value in node:
                visit(value)
    visit(config)
    return topics, frames


def graph_snapshot(expected: set[str]) -> dict[str, tuple[list[str], list[str]]]:
    """{topic: (types, reliability of each publisher)} as this process's node discovers the graph: once every
    ``expected`` topic has a publisher, or after 30 s (discovery takes longer on a loaded host)."""
    import rclpy
    from rclpy.qos import ReliabilityPolicy
    rclpy.init()
    node = rclpy.create_node("layout_graph_probe")
    try:
        end = time.monotonic() + 30.0
        while time.monotonic() < end and not all(node.count_publishers(name) for name in expected):
            rclpy.spin_once(node, timeout_sec=0.1)
        return {name: (types, ["reliable" if info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                               else "best_effort" for info in node.get_publishers_info_by_topic(name)])
                for name, types in node.get_topic_names_and_types()}
    finally:
        node.destroy_node()
        rclpy.shutdown()


@pytest.fixture(scope="module")
def pipeline_log(ros_env, tmp_path_factory):
    """needle_bringup on a slice of the dynamic bag, with tf2_msgs available (as on any ROS 2 install); its log,
    its output and the graph (topics, types, publishers' reliability) seen at the end."""
    env = environment_with(build_tf2_msgs(), ros_env)
    tmp = tmp_path_factory.mktemp("foxglove")
    bag = main_job.slice_bag(DYNAMIC, tmp / "slice.mcap", 0.0, DYNAMIC_SLICE, background_frames=1)
    log = tmp / "needle_compare.mcap"
    bringup = subprocess.Popen([sys.executable, "-m", "needle_sim_ros.nodes.bringup", "--experiment",
                                str(REPO / "config" / "experiments" / "dynamic_pitch.yaml"), "--ros-args",
                                "-p", "use_sim_time:=true", "-p", f"log.path:={log}"],
                               env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        replay = subprocess.run([sys.executable, "-m", "needle_sim_ros.nodes.replay_node", str(bag), "--clock", "200",
                                 "--rate", "0.5", "--topics", "/base_pose", "/left/image_raw", "/right/image_raw",
                                 "--wait-for-subscribers", "60", "--delay", "1.0"],
                                env=env, capture_output=True, text=True, timeout=120)
        assert replay.returncode == 0, replay.stdout + replay.stderr
        graph = graph_snapshot(set(rviz_references(yaml.safe_load(RVIZ.read_text()))[0]))
    finally:
        bringup.send_signal(signal.SIGINT)
        output, _ = bringup.communicate(timeout=30)
    assert bringup.returncode == 0, output
    messages: dict[str, list] = {}
    with open(log, "rb") as stream:
        for _, channel, _, decoded in make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            messages.setdefault(channel.topic, []).append(decoded)
    return messages, output, graph


def test_every_topic_and_frame_of_the_layout_is_in_the_pipeline_log(pipeline_log):
    messages, output, _ = pipeline_log
    layout = json.loads(LAYOUT.read_text())
    topics, frames = layout_references(layout)
    assert {"/shape_error", "/wrench", "/compare/model/marker", "/compare/measured/marker"} <= topics
    missing = {t for t in topics if not messages.get(t)}
    assert not missing, f"layout topics without messages in the log: {missing} (log has {sorted(messages)})\n{output}"
    tf_frames = {name for topic in ("/tf", "/tf_static") for msg in messages.get(topic, [])
                 for t in msg.transforms for name in (t.header.frame_id, t.child_frame_id)}
    assert frames <= tf_frames, (frames, tf_frames)
    # Every frame_id the log's display messages use is in its TF (Foxglove can place them).
    used = {msg.header.frame_id for topic in topics for msg in messages[topic]}
    assert used <= tf_frames, (used, tf_frames)


def test_the_logged_tubes_surround_the_logged_centerlines(pipeline_log):
    """Each tube vertex lies one tube radius from its centerline (Path), within the chord sag of the sampling."""
    messages, _, _ = pipeline_log
    for kind in ("model", "measured"):
        path, marker = messages[f"/compare/{kind}/path"][-1], messages[f"/compare/{kind}/marker"][-1]
        assert marker.type == Marker.TRIANGLE_LIST
        stamps = [(m.header.stamp.sec, m.header.stamp.nanosec) for m in (marker, path)]
        assert stamps[0] == stamps[1]
        line = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in path.poses])
        vertices = np.array([[p.x, p.y, p.z] for p in marker.points])
        distance = np.min(np.linalg.norm(vertices[:, None, :] - line[None, :, :], axis=2), axis=1)
        np.testing.assert_allclose(distance, 0.000635, rtol=0.02)


def test_every_topic_and_frame_of_the_rviz_config_is_in_the_pipeline(pipeline_log):
    messages, output, graph = pipeline_log
    topics, frames = rviz_references(yaml.safe_load(RVIZ.read_text()))
    assert {"/needle/marker", "/needle/path", "/wrench", "/compare/measured/marker"} <= set(topics)
    for topic, (display, reliability) in topics.items():
        assert topic in graph, f"RViz shows {topic}: not in the graph ({sorted(graph)})\n{output}"
        types, publishers = graph[topic]
        assert RVIZ_DISPLAY_TYPES[display] in types, (topic, display, types)
        # a reliable subscription receives nothing from a best-effort publisher
        assert reliability == "Best Effort" or "best_effort" not in publishers, (topic, reliability, publishers)
    tf_frames = {name for topic in ("/tf", "/tf_static") for msg in messages.get(topic, [])
                 for t in msg.transforms for name in (t.header.frame_id, t.child_frame_id)}
    assert {"world", "needle_base"} <= frames <= tf_frames, (frames, tf_frames)


def test_every_topic_of_the_layout_is_in_an_offline_log(tmp_path):
    """needle_offline and needle_batch write most logs: they hold the layout's topics too (the compared centerlines
    at display.rate, as needle_compare records them), in the frame the layout follows (no TF in an offline log)."""
    log = tmp_path / "offline.mcap"
    OfflinePipeline(experiment_for_bag(DYNAMIC)).run(DYNAMIC, log, duration=DYNAMIC_SLICE)
    messages = decode_with_mcap_ros2(log)
    topics, frames = layout_references(json.loads(LAYOUT.read_text()))
    missing = {t for t in topics if not messages.get(t)}
    assert not missing, f"layout topics without messages in the offline log: {missing} (log has {sorted(messages)})"
    shown = [t for t in topics if t.startswith("/compare/")]
    assert {msg.header.frame_id for topic in shown for msg in messages[topic]} == {"world"} and "world" in frames
    assert len(messages["/compare/measured/marker"]) == len(messages["/shape_error"]) == 3
