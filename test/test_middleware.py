"""The middleware is real: custom messages and a 1 kHz wrench stream cross an OS process boundary."""
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from message_samples import SAMPLES

PUBLISHER = str(Path(__file__).with_name("publish_samples.py"))


@pytest.fixture
def node(ros_env):
    rclpy.init()
    node = rclpy.create_node("middleware_test")
    yield node
    node.destroy_node()
    rclpy.shutdown()


def start_publisher(ros_env, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, PUBLISHER, *args], env=ros_env, stdout=subprocess.PIPE, text=True)


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_samples_set_every_field(name):
    """Guard for the round-trip test: every field of every sample differs from its default value."""
    sample = SAMPLES[name]()
    default = type(sample)()
    unset = [f for f in sample.get_fields_and_field_types() if getattr(sample, f) == getattr(default, f)]
    assert not unset, f"{name}: fields left at default: {unset}"


def test_custom_messages_round_trip_across_processes(node, ros_env):
    received = {}
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    for name, make in SAMPLES.items():
        node.create_subscription(type(make()), f"sample/{name}", lambda m, n=name: received.setdefault(n, m), reliable)
    publisher = start_publisher(ros_env, "samples")
    try:
        deadline = time.monotonic() + 30.0
        while len(received) < len(SAMPLES) and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        publisher.kill()
        publisher.wait()
    assert sorted(received) == sorted(SAMPLES), "not every message type arrived"
    for name, make in SAMPLES.items():
        assert received[name] == make(), f"{name} changed on the way"


def test_1khz_wrench_stream_has_no_loss_under_reliable_qos(node, ros_env):
    count = 3000  # 3 s at 1 kHz
    qos = QoSProfile(depth=count, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
    sequence = []
    node.create_subscription(WrenchStamped, "wrench_stream", lambda m: sequence.append(int(m.wrench.force.x)), qos)
    publisher = start_publisher(ros_env, "wrench", "--count", str(count), "--rate", "1000")
    try:
        deadline = time.monotonic() + 40.0
        while len(sequence) < count and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.01)
        out, _ = publisher.communicate(timeout=20)
    finally:
        publisher.kill()
    assert publisher.returncode == 0, out
    assert sequence == list(range(count)), \
        f"received {len(sequence)} of {count}, in order: {sequence == sorted(sequence)}"
    elapsed = float(out.split(" in ")[1].split()[0])
    assert elapsed < count / 1000.0 * 1.1, f"publisher could not hold 1 kHz: {elapsed:.3f} s for {count} messages"


def test_polled_subscriptions_deliver_like_an_executor(node):
    """The simulator's polled input (``nodes.polling``): the wait set reports the subscription that has a message,
    ``drain`` hands each message to the callback with its message info if the callback takes one (rclpy's own rule),
    and the kept wait set serves every wait."""
    from needle_sim_ros.nodes.polling import MessageWaiter, PolledCallbackGroup, drain

    plain, with_info = [], []
    group = PolledCallbackGroup()
    subscriptions = [node.create_subscription(WrenchStamped, "polled", plain.append, 10, callback_group=group),
                     node.create_subscription(WrenchStamped, "polled_info", lambda msg, info: with_info.append(
                         (msg, info)), 10, callback_group=group)]
    publishers = [node.create_publisher(WrenchStamped, topic, 10) for topic in ("polled", "polled_info")]
    waiter = MessageWaiter(subscriptions, node.context)
    assert waiter.wait(0.01) == []
    for round_ in range(3):
        publishers[round_ % 2].publish(WrenchStamped())
        deadline = time.monotonic() + 5.0
        while not (ready := waiter.wait(0.1)) and time.monotonic() < deadline:
            pass
        assert ready == [subscriptions[round_ % 2]]
        assert drain(ready[0]) == 1
    waiter.close()
    assert len(plain) == 2 and all(isinstance(msg, WrenchStamped) for msg in plain)
    assert len(with_info) == 1 and isinstance(with_info[0][0], WrenchStamped)
    assert with_info[0][1]["received_timestamp"] > 0


SHM_PROBE = """
import rclpy
rclpy.init()
node = rclpy.create_node("shm_probe")
print(*sorted({line.split()[-1] for line in open("/proc/self/maps") if "/dev/shm/" in line}))
"""


def test_the_suites_participants_open_no_shared_memory_port(ros_env):
    """The test domain's Fast DDS participants talk over UDP only (conftest.py): while a node of it is up, its process
    maps no shared-memory port of the domain's port range (7400 + 250 * domain ...) (its own mappings: ports left
    in /dev/shm by other runs on the machine do not count). A participant stopped or killed while holding such a
    port's lock could hang every later one (eProsima/Fast-DDS#1144); rmw_fastrtps's own LOCALHOST range opens them."""
    domain = int(ros_env["ROS_DOMAIN_ID"])
    ports = range(7400 + 250 * domain, 7400 + 250 * (domain + 1))
    probe = subprocess.run([sys.executable, "-c", SHM_PROBE], env=ros_env, capture_output=True, text=True, timeout=60)
    assert probe.returncode == 0, probe.stderr
    opened = {int(port) for port in re.findall(r"fastrtps_port(\d+)", probe.stdout)}
    assert not opened & set(ports), sorted(opened & set(ports))
