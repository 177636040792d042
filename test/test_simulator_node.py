"""needle_simulator as a real node in its own process, driven and read from this process (issue 4)."""
import math
import subprocess
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
import yaml
from ament_index_python.packages import get_package_prefix
from geometry_msgs.msg import PoseStamped, WrenchStamped
from needle_interfaces.msg import NeedleShape
from needle_interfaces.srv import ApplyPointLoad, ClearPointLoads
from needle_sim_ros.nodes.simulator_node import NeedleSimulatorNode
from nav_msgs.msg import Path as PathMsg
from rclpy.qos import qos_profile_sensor_data
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]
G = 9.81
LENGTH, RADIUS, DENSITY = 0.27, 0.635e-3, 8000.0
WEIGHT = DENSITY * math.pi * RADIUS**2 * LENGTH * G  # [N] 0.0268 N


def installed(package: str, name: str) -> str:
    """The executable that ``ros2 run <package> <name>`` starts: the sourced install space's (install/ or
    install-noble/), found as ros2 run finds it (ament index)."""
    return str(Path(get_package_prefix(package)) / "lib" / package / name)


def simulator_command() -> list[str]:
    return [installed("needle_sim_ros", "needle_simulator")]


def write_params(tmp_path: Path, **overrides) -> Path:
    params = {
        "needle.length": LENGTH, "needle.radius": RADIUS, "needle.density": DENSITY, "needle.elements": 8,
        "needle.gravity": [0.0, 0.0, -G],
        # Heavy mass-proportional damping so the needle settles in ~0.1 s (first mode ~12 Hz, zeta ~ 0.3).
        "damping.rayleigh_alpha": 40.0, "rates.shape_hz": 50.0,
    }
    params.update(overrides)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    return path


class Driver:
    """Test-side node: publishes base poses, records wrenches and shapes, calls services."""

    def __init__(self) -> None:
        self.node = rclpy.create_node("simulator_test_driver")
        self.pose_pub = self.node.create_publisher(PoseStamped, "base_pose", 10)
        self.wrenches: list[WrenchStamped] = []
        self.shapes: list[NeedleShape] = []
        self.node.create_subscription(WrenchStamped, "wrench", self.wrenches.append, qos_profile_sensor_data)
        self.node.create_subscription(NeedleShape, "needle/shape", self.shapes.append, 10)
        self.apply = self.node.create_client(ApplyPointLoad, "needle_simulator/apply_point_load")
        self.clear = self.node.create_client(ClearPointLoads, "needle_simulator/clear_point_loads")

    def pose(self, position=(0.4, 0.0, 0.3), quaternion=(0.0, 0.0, 0.0, 1.0), frame="world", stamp=None) -> None:
        msg = PoseStamped()
        msg.header.frame_id = frame
        msg.header.stamp = stamp or self.node.get_clock().now().to_msg()
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
        self.pose_pub.publish(msg)

    def hold(self, seconds: float, rate: float = 200.0, **pose) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.pose(**pose)
            rclpy.spin_once(self.node, timeout_sec=1.0 / rate)

    def call(self, client, request):
        assert client.wait_for_service(timeout_sec=10.0), "service not available"
        future = client.call_async(request)
        rclpy.spin_until_future_complete(self.node, future, timeout_sec=10.0)
        return future.result()

    def mean_wrench(self, last: int = 100) -> tuple[np.ndarray, np.ndarray]:
        w = self.wrenches[-last:]
        force = np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z] for m in w])
        torque = np.array([[m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z] for m in w])
        return force.mean(axis=0), torque.mean(axis=0)


@pytest.fixture
def simulator(ros_env, tmp_path):
    """Start the simulator with the given parameter overrides; yields a Driver connected to it."""
    processes = []
    rclpy.init()
    driver = Driver()

    def start(**overrides):
        params = str(write_params(tmp_path, **overrides))
        process = subprocess.Popen(simulator_command() + ["--ros-args", "--params-file", params],
                                   env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        processes.append(process)
        deadline = time.monotonic() + 180.0  # a first start on a fresh machine compiles the numba kernels (~50 s)
        while driver.pose_pub.get_subscription_count() == 0:
            assert process.poll() is None, process.stdout.read()
            assert time.monotonic() < deadline, "simulator did not come up"
            rclpy.spin_once(driver.node, timeout_sec=0.1)
        while not driver.wrenches:  # the first step may wait for numba to load or compile its kernels
            assert process.poll() is None, process.stdout.read()
            assert time.monotonic() < deadline, "simulator published no wrench"
            driver.hold(0.05)
        return process

    driver.start = start
    yield driver
    stop(processes)
    driver.node.destroy_node()
    rclpy.shutdown()


def stop(processes) -> None:
    """Terminate the processes, killing any that does not exit within 10 s."""
    for process in processes:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()


def test_wrench_at_rest_is_the_weight_and_a_tip_load_adds_its_equilibrium(simulator):
    process = simulator.start()
    simulator.hold(2.0)
    force, torque = simulator.mean_wrench()
    # Base frame = world frame here (identity pose). The holder carries the weight W downwards and the moment
    # of the weight about A: (L/2 x) x (-W z) = +W L/2 y (the sag shortens the lever by < 0.1 %).
    assert simulator.wrenches[-1].header.frame_id == "needle_base"
    np.testing.assert_allclose(force, [0.0, 0.0, -WEIGHT], atol=0.01 * WEIGHT)
    np.testing.assert_allclose(torque, [0.0, WEIGHT * LENGTH / 2, 0.0], atol=0.01 * WEIGHT * LENGTH / 2)

    tip_mass = 0.02
    request = ApplyPointLoad.Request(name="tip", arc_length=LENGTH, frame_id="world")
    request.force.z = -tip_mass * G
    assert simulator.call(simulator.apply, request).success
    simulator.hold(2.0)
    force, torque = simulator.mean_wrench()
    shape = simulator.shapes[-1]
    points = np.array([[p.x, p.y, p.z] for p in shape.points]) - [0.4, 0.0, 0.3]
    # Equilibrium of the deflected needle: lever arms are the horizontal distances of the tip and of the
    # centre of mass (uniform mass per arc length: mean of equally spaced samples, trapezoid-weighted).
    weights = np.full(len(points), 1.0)
    weights[[0, -1]] = 0.5
    x_cg = np.sum(weights * points[:, 0]) / weights.sum()
    expected_torque_y = WEIGHT * x_cg + tip_mass * G * points[-1, 0]
    np.testing.assert_allclose(force, [0.0, 0.0, -WEIGHT - tip_mass * G], atol=0.01 * WEIGHT)
    np.testing.assert_allclose(torque[1], expected_torque_y, rtol=0.01)

    bad = ApplyPointLoad.Request(name="bad", arc_length=2 * LENGTH)
    assert not simulator.call(simulator.apply, bad).success
    cleared = simulator.call(simulator.clear, ClearPointLoads.Request())
    assert cleared.removed == 1
    assert process.poll() is None


def test_shape_follows_a_base_rotation(simulator):
    simulator.start(**{"needle.gravity": [0.0, 0.0, 0.0]})
    simulator.hold(0.5)
    steps = 100
    for k in range(steps + 1):  # 90 deg about z in 1 s
        quaternion = Rotation.from_euler("z", 90.0 * k / steps, degrees=True).as_quat()
        simulator.hold(0.01, quaternion=quaternion)
    simulator.hold(2.0, quaternion=Rotation.from_euler("z", 90.0, degrees=True).as_quat())
    tips = [[s.tip_pose.position.x, s.tip_pose.position.y, s.tip_pose.position.z] for s in simulator.shapes[-10:]]
    # The needle now points along world +y from the base at (0.4, 0, 0.3): tip at (0.4, L, 0.3) within 1 mm
    # (a residual vibration of the heavily damped needle after 2 s is far below that).
    np.testing.assert_allclose(np.mean(tips, axis=0), [0.4, LENGTH, 0.3], atol=1e-3)


class StateTaken(Exception):
    """Raised by a stub node's ``take_state``: an output is being computed."""


@pytest.mark.parametrize("subscribed", ["", "shape", "state", "tf", "path", "pose_array", "marker"])
def test_periodic_outputs_are_computed_only_for_subscribers(subscribed):
    """With no subscriber on the shape outputs (shape, state, TF) nor on the visualization (path, pose array,
    marker) the output thread computes nothing; one subscriber on any of them makes it take the state."""
    node = object.__new__(NeedleSimulatorNode)  # the node's methods on a stub state, without a ROS context
    node.p = {"rates.shape_hz": 100.0, "rates.visualization_hz": 10.0}
    node.use_sim_time, node._lock = False, threading.Lock()
    node._next_output = {"shape": 0.0, "visualization": 0.0}
    node.sim = SimpleNamespace(started=True)
    for name in ("shape", "state", "path", "pose_array", "marker"):
        setattr(node, f"{name}_pub", SimpleNamespace(get_subscription_count=lambda name=name: int(name == subscribed)))
    node.tf = SimpleNamespace(has_subscribers=lambda: subscribed == "tf")

    def take_state():
        raise StateTaken

    node.take_state = take_state
    if subscribed:
        with pytest.raises(StateTaken):
            node.publish_periodic_outputs(1.0)
    else:
        node.publish_periodic_outputs(1.0)


def test_a_late_subscriber_gets_the_visualization(simulator):
    simulator.start(**{"rates.visualization_hz": 20.0})
    simulator.hold(0.3)
    paths = []
    simulator.node.create_subscription(PathMsg, "needle/path", paths.append, 10)
    simulator.hold(1.0)
    assert len(paths) >= 10 and len(paths[-1].poses) > 2


def test_bad_inputs_are_survived_and_never_produce_nan(simulator):
    process = simulator.start()
    simulator.hold(0.5)
    now = simulator.node.get_clock().now()
    bad_poses = [
        dict(position=(math.nan, 0.0, 0.3)),
        dict(position=(0.4, math.inf, 0.3)),
        dict(quaternion=(0.0, 0.0, 0.0, 0.0)),
        dict(quaternion=(0.0, 0.0, 0.0, 5.0)),  # non-normalized: accepted after normalizing
        dict(frame="camera"),
        dict(stamp=(now - rclpy.duration.Duration(seconds=0.2)).to_msg()),  # out of order
        dict(stamp=rclpy.time.Time(seconds=5.0).to_msg()),  # stale: replaced by receive time
        dict(position=(1.4, 0.0, 0.3)),  # 1 m jump
        dict(quaternion=(0.0, 1.0, 0.0, 0.0)),  # 180 deg flip
    ]
    for _ in range(3):
        for pose in bad_poses:
            simulator.pose(**pose)
            simulator.hold(0.02)
    simulator.hold(0.5)
    assert process.poll() is None, "simulator died"
    force, torque = simulator.mean_wrench(last=len(simulator.wrenches))
    values = np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x, m.wrench.torque.y,
                        m.wrench.torque.z] for m in simulator.wrenches])
    assert np.all(np.isfinite(values))
    assert all(np.all(np.isfinite([[p.x, p.y, p.z] for p in s.points])) for s in simulator.shapes)
    tip = simulator.shapes[-1].tip_pose.position
    assert abs(tip.x - (0.4 + LENGTH)) < 2e-3  # still at the valid pose


@pytest.mark.parametrize("override, name", [
    ({"needle.length": -0.1}, "needle.length"),
    ({"integrator.method": "rk4"}, "integrator.method"),
    ({"flange_offset.orientation": [0.0, 0.0, 0.0, 2.0]}, "flange_offset.orientation"),
    ({"needle.gravity": [0.0, -9.81]}, "needle.gravity"),
])
def test_bad_parameter_file_ends_the_node_with_a_message_naming_the_parameter(ros_env, tmp_path, override, name):
    params = str(write_params(tmp_path, **override))
    result = subprocess.run(simulator_command() + ["--ros-args", "--params-file", params],
                            env=ros_env, capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert f"'{name}'" in result.stdout + result.stderr
