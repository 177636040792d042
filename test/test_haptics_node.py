"""needle_simulator's haptic output, parameters, lifecycle and readiness in a real process, against a stand-in arm
(issue 37): poses at 1 kHz from a thread of this process, ``haptic/wrench`` read with a reliable subscription as a
CRTK driver's ``servo_cf`` reads it."""
import signal
import subprocess
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock

from needle_common.ros.runner import spin_until_shutdown
from needle_sim_ros.nodes.simulator_node import NeedleSimulatorNode
from test_simulator_node import WEIGHT, simulator_command, stop, write_params

TIMEOUT = 0.02  # haptics.pose_timeout [s]
RAMP = 0.2      # haptics.resume_ramp [s]
HAPTICS = {"haptics.enable": True, "haptics.pose_timeout": TIMEOUT, "haptics.resume_ramp": RAMP,
           "rates.diagnostics_hz": 10.0}


class Arm:
    """Stand-in arm: base poses at 1 kHz from its own thread while ``streaming`` is set; records every haptic wrench
    (monotonic receive time, force, torque, frame, stamp [s]), the simulator's wrench and the diagnostics."""

    wall_stamps = True  # the poses, and so the node's steps, are stamped with the wall clock

    def __init__(self) -> None:
        self.node = rclpy.create_node("stand_in_arm")
        self.pose_pub = self.node.create_publisher(PoseStamped, "base_pose", 10)
        self.haptic: list[tuple[float, np.ndarray, np.ndarray, str, float]] = []
        self.wrenches: list[np.ndarray] = []
        self.statuses: list = []
        self.node.create_subscription(WrenchStamped, "haptic/wrench", self.on_haptic,
                                      QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(WrenchStamped, "wrench", lambda m: self.wrenches.append(
            np.array([m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x, m.wrench.torque.y,
                      m.wrench.torque.z])), qos_profile_sensor_data)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: self.statuses.extend(m.status), 10)
        self.streaming = threading.Event()
        self.orientation = (0.0, 0.0, 0.0, 1.0)  # of the base poses (x, y, z, w)
        self.last_sent = 0.0  # monotonic time of the newest pose
        self.last_stamp = 0.0  # its header stamp [s] (the node's clock: wall, or /clock under use_sim_time)
        self._closed = threading.Event()
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._threads = [threading.Thread(target=self.executor.spin, daemon=True),
                         threading.Thread(target=self._stream, daemon=True)]
        for thread in self._threads:
            thread.start()

    def on_haptic(self, msg: WrenchStamped) -> None:
        f, m = msg.wrench.force, msg.wrench.torque
        self.haptic.append((time.monotonic(), np.array([f.x, f.y, f.z]), np.array([m.x, m.y, m.z]),
                            msg.header.frame_id, msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec))

    def _stream(self) -> None:
        msg = PoseStamped()
        msg.header.frame_id = "world"
        msg.pose.position.x, msg.pose.position.z = 0.4, 0.3
        q = msg.pose.orientation
        next_time = time.monotonic()
        while not self._closed.is_set():
            next_time += 1e-3
            time.sleep(max(next_time - time.monotonic(), 0.0))
            if self.streaming.is_set():
                now = time.time()
                msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int((now % 1.0) * 1e9)
                q.x, q.y, q.z, q.w = self.orientation
                self.pose_pub.publish(msg)
                self.last_sent, self.last_stamp = time.monotonic(), now
            else:
                next_time = time.monotonic()

    def close(self) -> None:
        self._closed.set()
        self.executor.shutdown()
        for thread in self._threads:
            thread.join(timeout=5.0)
        self.node.destroy_node()

    def since(self, t: float) -> list:
        return [h for h in list(self.haptic) if h[0] > t]

    def status(self, suffix: str) -> list:
        return [s for s in list(self.statuses) if s.name == f"/needle_simulator: {suffix}"]

    def call(self, service_type, name: str, request, timeout: float = 30.0):
        client = self.node.create_client(service_type, name)
        assert client.wait_for_service(timeout_sec=timeout), name
        future = client.call_async(request)
        deadline = time.monotonic() + timeout
        while not future.done():
            assert time.monotonic() < deadline, f"{name}: no answer"
            time.sleep(0.01)
        return future.result()

    def transition(self, transition_id: int) -> bool:
        return self.call(ChangeState, "needle_simulator/change_state",
                         ChangeState.Request(transition=Transition(id=transition_id))).success


def running(kind: type[Arm]):
    """A stand-in arm of the given kind in a fresh rclpy context; stops the processes started for it, then itself."""
    rclpy.init()
    stand_in = kind()
    stand_in.processes = []
    yield stand_in
    stop(stand_in.processes)
    stand_in.close()
    rclpy.shutdown()


@pytest.fixture
def arm(ros_env):
    yield from running(Arm)


def start(arm: Arm, env, tmp_path, arguments=(), **overrides) -> subprocess.Popen:
    process = subprocess.Popen(simulator_command() + ["--ros-args", "--params-file",
                                                      str(write_params(tmp_path, **overrides)), *arguments],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    arm.processes.append(process)
    return process


def wait_until(condition, process, timeout: float = 180.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert process.poll() is None, process.stdout.read()
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def norms(entries, index: int = 1) -> np.ndarray:
    return np.array([np.linalg.norm(entry[index]) for entry in entries])


def rendering(arm: Arm, process, fraction: float = 0.95) -> None:
    """Wait until the haptic force is the needle's weight (settled and ramped up)."""
    wait_until(lambda: arm.haptic and abs(np.linalg.norm(arm.haptic[-1][1]) - WEIGHT) < (1 - fraction) * WEIGHT,
               process, what="the haptic force to reach the needle's weight")


def at_weight(arm: Arm, seconds: float = 1.0) -> tuple[list, set]:
    """The haptic outputs at the needle's weight (within 5 %) over the next ``seconds``, and the frames of all of
    them. A starved host delays the stand-in arm's poses past the watchdog time now and then (a zero, then the ramp
    back: 9 zeros in 1 s at a load of 1.3 here), which the median of the last 100 outputs took in (20 % of the
    weight, once in CI)."""
    start = time.monotonic()
    time.sleep(seconds)
    entries = arm.since(start)
    steady = [entry for entry in entries if abs(np.linalg.norm(entry[1]) - WEIGHT) < 0.05 * WEIGHT]
    assert len(steady) >= 20, (len(steady), len(entries))
    return steady, {entry[3] for entry in entries}


def settled(arm: Arm, quiet: float = 0.2, timeout: float = 10.0) -> int:
    """The number of haptic outputs received once none came for ``quiet`` seconds."""
    deadline = time.monotonic() + timeout
    count = -1
    while count != len(arm.haptic):
        assert time.monotonic() < deadline, "the haptic output did not stop"
        count = len(arm.haptic)
        time.sleep(quiet)
    return count


def nonzero_runs(entries: list) -> list[list]:
    """The runs of non-zero haptic outputs among ``entries``, each ended by a zero (a watchdog trip)."""
    runs: list[list] = [[]]
    for entry in entries:
        if entry[1].any():
            runs[-1].append(entry)
        elif runs[-1]:
            runs.append([])
    return [run for run in runs if run]


def zero_within_the_watchdog_time(arm: Arm) -> tuple[float, list]:
    """After the poses stop: zeros from within the (wall-clock) watchdog time on, and nothing else; returns (the last
    pose's send time, those zeros). The middleware may deliver the last poses late on a starved host (a trip, then
    the ramp again, before the final zeros). With wall-clock stamps the time to the zero is read on the node's own
    (the step's end time against the last pose's), as this process may receive late (0.19 s once at a load of ~2);
    its receive times are then held to 1 s only. Simulated stamps tell nothing of the wall clock (the starved /clock
    publisher bunches them; a paused /clock leaves the zero with the pose's stamp): the receive times, with slack."""
    silent_from = -1.0
    while silent_from != arm.last_sent:  # the stand-in arm's thread, starved, may still be sending its last pose
        silent_from, last_stamp = arm.last_sent, arm.last_stamp
        time.sleep(0.01)
    time.sleep(0.5)

    def final_zeros() -> list:  # the outputs after the last non-zero one
        after = arm.since(silent_from)
        final = max((index + 1 for index, entry in enumerate(after) if entry[1].any() or entry[2].any()), default=0)
        return after[final:]
    deadline = time.monotonic() + 5.0  # this process, starved, may take seconds to read what came
    while len(final_zeros()) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    zeros = final_zeros()
    assert len(zeros) > 1, len(zeros)
    stamped, received = zeros[0][4] - last_stamp, zeros[0][0] - silent_from
    if arm.wall_stamps:
        assert stamped < TIMEOUT + 0.03 and received < 1.0, (stamped, received)
    else:  # simulated stamps, which a starved /clock publisher bunches: this process's receive times
        assert received < TIMEOUT + 0.1, (stamped, received)
    return silent_from, zeros


def test_the_watchdog_zeroes_a_silent_arm_ramps_back_and_deactivate_sends_zero(arm, ros_env, tmp_path):
    process = start(arm, ros_env, tmp_path, **HAPTICS)
    arm.streaming.set()
    rendering(arm, process)
    # At rest under gravity, base frame = world frame (the poses' frame): the weight, downwards (what a hand
    # holding the needle feels), with the sign of the wrench output.
    steady, frames = at_weight(arm)
    assert frames == {"world"}
    force = np.median([entry[1] for entry in steady], axis=0)
    np.testing.assert_allclose(force, [0.0, 0.0, -WEIGHT], atol=0.03 * WEIGHT)
    np.testing.assert_allclose(np.mean(arm.wrenches[-100:], axis=0)[:3], force, atol=0.03 * WEIGHT)

    # The arm goes silent: zero within the watchdog time, and zero keeps coming at the step rate.
    arm.streaming.clear()
    _, zeros = zero_within_the_watchdog_time(arm)
    stamps = np.array([entry[4] for entry in zeros])  # ~1 kHz of zeros, on the node's step stamps
    assert np.sum((stamps > stamps[0] + 0.05) & (stamps < stamps[0] + 0.35)) > 0.6 * 0.3 * 1000
    assert any(s.level == b"\x02" and "watchdog" in s.message for s in arm.status("haptics"))

    # Back: a ramp over haptics.resume_ramp, no step. Every start from zero is a ramp: a starved host may delay
    # the stand-in arm's poses past the watchdog time mid-ramp (a zero, then the ramp again; seen once in CI), so
    # each run of output that lasts the ramp is checked, on the node's step stamps (not this process's receive
    # times, which a stall of its executor bunches).
    arm.streaming.set()
    resumed = time.monotonic()

    def whole_runs() -> list[list]:  # the runs that last the ramp (up to 10 s: trips every 20-140 ms at a load of 1.2)
        return [run for run in nonzero_runs(arm.since(resumed)) if run[-1][4] - run[0][4] > RAMP + 0.05]
    wait_until(whole_runs, process, 10.0, "a run of output that lasts the ramp")
    runs = nonzero_runs(arm.since(resumed))
    assert all(norms(run)[0] < 0.15 * WEIGHT for run in runs), [norms(run)[0] for run in runs]
    whole = whole_runs()
    for run in whole:
        magnitude, at = norms(run), np.array([entry[4] - run[0][4] for entry in run])
        middle = magnitude[(at > 0.4 * RAMP) & (at < 0.6 * RAMP)]
        assert middle.size and np.all((middle > 0.3 * WEIGHT) & (middle < 0.7 * WEIGHT)), middle
        assert np.all(np.abs(magnitude[at > RAMP + 0.02] - WEIGHT) < 0.05 * WEIGHT)

    # Deactivate: a zero, then nothing else (reliable, in order: what was published before it arrives before it,
    # though a starved executor here may take it after the service's answer).
    assert arm.transition(Transition.TRANSITION_DEACTIVATE)
    stopped = settled(arm)
    assert not arm.haptic[stopped - 1][1].any() and not arm.haptic[stopped - 1][2].any()
    time.sleep(0.3)
    assert len(arm.haptic) == stopped  # nothing after the zero
    assert arm.transition(Transition.TRANSITION_ACTIVATE)  # and it renders again
    activated = time.monotonic()
    wait_until(lambda: any(entry[1].any() for entry in arm.since(activated)), process, 10.0, "rendering again")
    # Deactivate, then cleanup: another zero (a driver that joined in between gets one too).
    assert arm.transition(Transition.TRANSITION_DEACTIVATE)
    deactivated = settled(arm)
    assert arm.transition(Transition.TRANSITION_CLEANUP)
    wait_until(lambda: len(arm.haptic) > deactivated, process, 5.0, "the zero of cleanup")
    assert len(arm.haptic) == deactivated + 1 and not arm.haptic[-1][1].any()


class SimulatedClockArm(Arm):
    """A stand-in arm replayed with simulated time, as from a bag: ``/clock`` at 1 kHz while ``clock_running`` is set
    (from 1000 s on, at the wall rate) and the base poses stamped with it while ``streaming`` is set."""

    wall_stamps = False

    def __init__(self) -> None:
        self.clock_running = threading.Event()
        self.sim_time = 1000.0
        super().__init__()
        self.clock_pub = self.node.create_publisher(Clock, "/clock", 10)

    def _stream(self) -> None:
        msg, clock = PoseStamped(), Clock()
        msg.header.frame_id = "world"
        msg.pose.position.x, msg.pose.position.z = 0.4, 0.3
        msg.pose.orientation.w = 1.0
        next_time = time.monotonic()
        while not self._closed.is_set():
            next_time += 1e-3
            time.sleep(max(next_time - time.monotonic(), 0.0))
            if not self.clock_running.is_set():
                next_time = time.monotonic()
                continue
            self.sim_time += 1e-3
            clock.clock.sec, clock.clock.nanosec = int(self.sim_time), int(round((self.sim_time % 1.0) * 1e9)) % 10**9
            self.clock_pub.publish(clock)
            if self.streaming.is_set():
                msg.header.stamp = clock.clock
                self.pose_pub.publish(msg)
                self.last_sent, self.last_stamp = time.monotonic(), self.sim_time


@pytest.fixture
def sim_arm(ros_env):
    yield from running(SimulatedClockArm)


def test_under_simulated_time_the_wall_clock_watchdog_zeroes_silent_poses_and_a_paused_clock(sim_arm, ros_env,
                                                                                             tmp_path):
    """use_sim_time (a replayed bag driving a real arm): the watchdog still runs on the wall clock. Poses that
    stop while /clock runs, and a paused bag (/clock and poses both stop, so no step is taken), both take the haptic
    output to zero within haptics.pose_timeout; it ramps back when the bag resumes."""
    process = start(sim_arm, ros_env, tmp_path, **(HAPTICS | {"use_sim_time": True}))
    sim_arm.clock_running.set()
    sim_arm.streaming.set()
    rendering(sim_arm, process)
    assert sim_arm.haptic[-1][0] > 0 and sim_arm.sim_time > 1000.0

    sim_arm.streaming.clear()  # the arm's poses stop, the clock runs on
    zero_within_the_watchdog_time(sim_arm)
    assert any(s.level == b"\x02" and "watchdog" in s.message for s in sim_arm.status("haptics"))

    sim_arm.streaming.set()
    rendering(sim_arm, process)
    sim_arm.clock_running.clear()  # the bag paused: neither clock nor poses
    zero_within_the_watchdog_time(sim_arm)

    sim_arm.clock_running.set()
    resumed = time.monotonic()
    rendering(sim_arm, process)
    back = [entry for entry in sim_arm.since(resumed) if entry[1].any()]
    assert norms(back)[0] < 0.15 * WEIGHT, norms(back)[0]  # a ramp, not a step back to the weight


@pytest.mark.parametrize("stop_signal", [signal.SIGTERM, signal.SIGINT])
def test_saturation_holds_and_a_stop_signal_sends_zero_then_exits_cleanly(arm, ros_env, tmp_path, stop_signal):
    # The weight (26.8 mN) and its moment about A (3.6 mN m) both above the limits.
    process = start(arm, ros_env, tmp_path, **(HAPTICS | {"haptics.max_force": 0.01, "haptics.max_torque": 0.001,
                                                          "haptics.resume_ramp": 0.0}))
    arm.streaming.set()
    wait_until(lambda: len([e for e in arm.haptic if e[1].any()]) > 500, process, what="500 haptic wrenches")
    forces, torques = norms(arm.haptic), norms(arm.haptic, 2)
    assert forces.max() <= 0.01 + 1e-12 and torques.max() <= 0.001 + 1e-12
    # direction kept: down (the last wrench rendered: a stand-in arm starved on a loaded host can trip the watchdog,
    # whose zeros are checked elsewhere)
    np.testing.assert_allclose([e for e in arm.haptic if e[1].any()][-1][1], [0.0, 0.0, -0.01], atol=1e-4)
    assert np.linalg.norm(arm.wrenches[-1][:3]) > 2 * 0.01  # the unlimited output is not clipped
    wait_until(lambda: any(s.level == b"\x01" and "saturated" in s.message for s in arm.status("haptics")), process,
               10.0, "a diagnostics WARN for the saturation")
    clipped = [dict((kv.key, kv.value) for kv in s.values) for s in arm.status("haptics")]
    assert int(clipped[-1]["clipped_forces"]) > 0 and int(clipped[-1]["clipped_torques"]) > 0

    process.send_signal(stop_signal)  # the arm still streaming
    output, _ = process.communicate(timeout=20)
    time.sleep(0.2)
    assert process.returncode == 0, output
    assert "Traceback" not in output, output
    assert not arm.haptic[-1][1].any() and not arm.haptic[-1][2].any(), arm.haptic[-1]


def test_the_tool_frame_output_is_the_holder_wrench_in_the_needle_base_frame(arm, ros_env, tmp_path):
    """haptics.frame: tool (a body-frame servo_cf): the base rolled by 90 deg about the needle axis, the weight
    (world -z) is felt along the needle base frame's -y (R^T g, independent of the model), in frames.base, and equals
    the unlimited ``wrench`` output (the same frame) while nothing saturates."""
    arm.orientation = (np.sin(np.pi / 4), 0.0, 0.0, np.cos(np.pi / 4))  # roll +90 deg: base z along world -y
    process = start(arm, ros_env, tmp_path, **(HAPTICS | {"haptics.frame": "tool"}))
    arm.streaming.set()
    rendering(arm, process)
    steady, frames = at_weight(arm)
    assert frames == {"needle_base"}
    force, torque = (np.median([entry[k] for entry in steady], axis=0) for k in (1, 2))
    np.testing.assert_allclose(force, [0.0, -WEIGHT, 0.0], atol=0.03 * WEIGHT)
    wrench = np.mean(arm.wrenches[-100:], axis=0)
    np.testing.assert_allclose(wrench[:3], force, atol=0.01 * WEIGHT)
    np.testing.assert_allclose(wrench[3:], torque, atol=0.01 * WEIGHT * 0.135)


def set_parameter(arm: Arm, name: str, value: float):
    request = SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
    return arm.call(SetParameters, "needle_simulator/set_parameters", request).results[0]


def test_structural_parameters_set_while_unconfigured_take_effect_at_configure(arm, ros_env, tmp_path):
    process = start(arm, ros_env, tmp_path, autostart=False)
    result = set_parameter(arm, "needle.length", 0.135)
    assert result.successful, result.reason
    enable = arm.call(SetParameters, "needle_simulator/set_parameters", SetParameters.Request(parameters=[Parameter(
        name="haptics.enable", value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True))])).results[0]
    assert not enable.successful  # fixed at construction (its publisher exists or not)
    assert arm.transition(Transition.TRANSITION_CONFIGURE) and arm.transition(Transition.TRANSITION_ACTIVATE)
    arm.streaming.set()
    wait_until(lambda: len(arm.wrenches) > 1500, process, what="1.5 s of wrenches")
    # half the needle, half the weight
    np.testing.assert_allclose(np.mean(arm.wrenches[-100:], axis=0)[:3], [0.0, 0.0, -WEIGHT / 2], atol=0.03 * WEIGHT)
    refused = set_parameter(arm, "needle.length", 0.27)
    assert not refused.successful and "unconfigured" in refused.reason, refused.reason

    # Only poses come: the optional inputs (twist, tip load) without a publisher are fine.
    def accepting_report():
        reports = [s for s in arm.status("inputs") if {kv.key: kv.value for kv in s.values}.get("accepting") == "true"]
        return reports[-1] if reports else None

    wait_until(accepting_report, process, 10.0, "an input report while active")
    inputs = accepting_report()
    assert inputs.level == b"\x00", inputs.message
    assert {kv.key: kv.value for kv in inputs.values}["/base_twist"] == "0"
    # Readiness: the same report, latched: a reader that comes later gets the last one, published before it came.
    # The report is repeated every 0.5 s: on a starved host a new one may be sent before the reader has matched, and
    # then comes first (the history keeps one). A late reader is tried again then; without latching none passes.
    for _ in range(5):
        latched = []
        subscribed_at = time.time()
        reader = arm.node.create_subscription(DiagnosticArray, "/needle_sim/readiness", latched.append,
                                              QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                                         durability=DurabilityPolicy.TRANSIENT_LOCAL))
        wait_until(lambda: latched, process, 10.0, "the latched readiness report")
        arm.node.destroy_subscription(reader)
        first = latched[0]
        if first.header.stamp.sec + 1e-9 * first.header.stamp.nanosec < subscribed_at:
            break
    else:
        pytest.fail("no reader got the report published before it subscribed: not latched")
    assert first.status[0].name == "/needle_simulator: inputs"
    assert {kv.key: kv.value for kv in first.status[0].values}["accepting"] == "true"


def test_an_unknown_name_is_a_warning_and_a_misspelling_is_fatal(arm, ros_env, tmp_path):
    """A parent launch's global parameter (``-p`` or a ``/**`` section) that resembles none of the node's is ignored
    with a warning; a misspelling of one of its names stays fatal with the suggestion."""
    process = start(arm, ros_env, tmp_path, ["-p", "robot_name:=psm1"], lab_station="b12")
    wait_until(lambda: arm.pose_pub.get_subscription_count() > 0, process, what="the simulator to subscribe")
    time.sleep(0.5)
    assert process.poll() is None
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=20)
    assert "'robot_name'" in output and "'lab_station'" in output, output
    result = subprocess.run(simulator_command() + ["--ros-args", "-p", "haptics.max_forse:=1.0"], env=ros_env,
                            capture_output=True, text=True, timeout=120)
    output = result.stdout + result.stderr
    assert result.returncode == 2 and "Traceback" not in output, output
    assert "did you mean 'haptics.max_force'" in output, output


def test_an_exception_escaping_the_executor_still_runs_the_finish_hooks_and_propagates():
    """The simulator's finish() sends the haptic zero: it must run on a crash too, and the crash must not look like
    success (the exception goes on: exit status 1)."""
    class FailingExecutor:
        def spin_once(self, timeout_sec: float) -> None:
            raise RuntimeError("a callback failed")

        def shutdown(self) -> None:
            pass

    class Node:
        finished = destroyed = False

        def finish(self) -> None:
            Node.finished = True

        def destroy_node(self) -> None:
            Node.destroyed = True

    rclpy.init()
    with pytest.raises(RuntimeError, match="a callback failed"):
        spin_until_shutdown(FailingExecutor(), [Node()], SimpleNamespace(received=None))
    assert Node.finished and Node.destroyed and not rclpy.ok()


def test_an_integration_loop_that_dies_zeroes_the_haptic_output():
    node = object.__new__(NeedleSimulatorNode)  # the node's methods on a stub state, without a ROS context
    node._stop, zeroed, errors = threading.Event(), [], []
    node.get_logger = lambda: SimpleNamespace(error=errors.append)
    node.zero_haptics = lambda: zeroed.append(True)

    def run_loop():
        raise MemoryError("out of memory")

    node.run_loop = run_loop
    rclpy.init()
    try:
        with pytest.raises(MemoryError):
            node.run_loop_or_zero()
    finally:
        rclpy.shutdown()
    assert zeroed == [True] and "integration loop ended" in errors[0]
