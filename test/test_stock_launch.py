"""The stock Jazzy path, run as a user runs it: ``ros2 launch``, ``ros2 lifecycle``, ``ros2 param`` and tf2_ros,
built from ../shared/ros2-src into a test-only workspace (workspaces.py; skipped, saying why, where it is absent).

Every command is the real command line in its own process; every wait is bounded.
"""
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS

from test_end_to_end import DYNAMIC, REPO, main_job

pytestmark = [pytest.mark.slow, pytest.mark.ros]
HERE = Path(__file__).parent
START_TIMEOUT = 120.0  # [s] for the nodes to come up (the first start of a fresh install loads the numba kernels)
REPLAY_TIMEOUT = 240.0  # [s] for a replay launch of the 6 s dynamic bag to end by itself
CAMERA_FRAMES = ("stereo_left_optical_frame", "stereo_right_optical_frame")
# The command line without its daemon (nothing outlives the test), discovering for 3 s (the default 0.5 s missed the
# node now and then on this loaded 2-core machine: 'Node not found')
NO_DAEMON = ("--no-daemon", "--spin-time", "3")
PLAYER_DONE = r"\[needle_replay-\d+\]: process has finished cleanly"


class Launch:
    """``ros2 launch needle_sim_ros bringup.launch.py ARGS`` (or another launch file) in its own session, its output
    in a file; stopped with SIGINT, then SIGKILL of its process group, at the end of the test."""

    def __init__(self, env: dict, log: Path, *arguments: str, launch_file: str = "") -> None:
        self.log = log
        target = [launch_file] if launch_file else ["needle_sim_ros", "bringup.launch.py"]
        with open(log, "w") as stream:
            self.process = subprocess.Popen(["ros2", "launch", *target, *arguments], env=env, cwd=REPO,
                                            stdout=stream, stderr=subprocess.STDOUT, start_new_session=True)

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def wait_for(self, pattern: str, timeout: float) -> re.Match:
        """The first match of ``pattern`` in the output; fails if the launch ends or ``timeout`` passes first."""
        deadline = time.monotonic() + timeout
        while not (match := re.search(pattern, self.output())):
            assert self.process.poll() is None, f"the launch ended ({self.process.returncode}):\n{self.output()}"
            assert time.monotonic() < deadline, f"no '{pattern}' within {timeout:g} s:\n{self.output()}"
            time.sleep(0.2)
        return match

    def wait(self, timeout: float) -> int:
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the launch was still running after {timeout:g} s:\n{self.output()[-5000:]}")

    def stop(self) -> int | None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout=10)
        return self.process.returncode


@pytest.fixture
def launches():
    started: list[Launch] = []
    yield started
    for launch in started:
        launch.stop()


def ros2(env: dict, *arguments: str, timeout: float = 30.0, retry_until: float = 20.0) -> str:
    """``ros2 ARGUMENTS``, repeated while it fails for up to ``retry_until`` seconds: each call is a new participant,
    which may miss a node it has not yet discovered ('Node not found')."""
    deadline = time.monotonic() + retry_until
    while True:
        result = subprocess.run(["ros2", *arguments], env=env, capture_output=True, text=True, timeout=timeout)
        if result.returncode == 0 or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert result.returncode == 0, f"ros2 {' '.join(arguments)}: {result.returncode}\n{result.stdout}{result.stderr}"
    return result.stdout


def active(env: dict, node: str) -> None:
    """Wait (bounded) until ``node`` reports the lifecycle state active."""
    deadline = time.monotonic() + START_TIMEOUT
    while "active [3]" not in (state := subprocess.run(
            ["ros2", "lifecycle", "get", node, *NO_DAEMON], env=env, capture_output=True, text=True,
            timeout=30).stdout):
        assert time.monotonic() < deadline, f"{node} not active after {START_TIMEOUT:g} s: {state!r}"
        time.sleep(1.0)


def shape_errors(log: Path) -> int:
    """Comparisons in a comparison log (one /shape_error message each)."""
    with open(log, "rb") as stream:
        return sum(channel.topic == "/shape_error" for _, channel, _ in make_reader(stream).iter_messages())


@pytest.fixture(scope="module")
def replay(stock_env, tmp_path_factory):
    """``mode:=replay`` of the dynamic bag with its experiment, as the issue's user ran it, with a tf2_ros listener
    looking world -> needle_tip and the camera frames up meanwhile."""
    tmp = tmp_path_factory.mktemp("replay")
    launch = Launch(stock_env, tmp / "launch.log", "mode:=replay", f"bag:={DYNAMIC}", "experiment:=dynamic_pitch",
                    f"log:={tmp / 'compare.mcap'}")
    try:
        lookup = subprocess.run([sys.executable, str(HERE / "tf2_lookup.py"), "60", "world", "needle_tip",
                                 *CAMERA_FRAMES], env=stock_env, capture_output=True, text=True, timeout=90)
        code = launch.wait(REPLAY_TIMEOUT)
    finally:
        launch.stop()
    return {"code": code, "output": launch.output(), "log": tmp / "compare.mcap", "lookup": lookup}


def test_replay_compares_every_measurement_and_ends_by_itself(replay):
    """As scripts/main_job.py counts: one comparison per stereo pair after the background pair."""
    assert replay["code"] == 0, replay["output"][-5000:]
    expected = main_job.expected_measurements(DYNAMIC, stereo=True, background_frames=1)
    assert expected == 10
    assert shape_errors(replay["log"]) == expected, replay["output"][-5000:]
    summary = json.loads(re.search(r"\[needle_compare\] summary: (\{.*\})", replay["output"]).group(1))
    assert summary["compared"] == expected and summary["rmse_mean_m"] < 1e-4, summary
    assert re.search(PLAYER_DONE, replay["output"])


def test_replay_with_compressed_image_topics_compares_every_measurement(stock_env, launches, tmp_path):
    """``image_transport:=compressed``: the player plays the bag's images as PNG CompressedImage on
    image_transport's <image>/compressed topics, the stereo node takes those, and every measurement is compared."""
    launch = Launch(stock_env, tmp_path / "launch.log", "mode:=replay", f"bag:={DYNAMIC}", "experiment:=dynamic_pitch",
                    "image_transport:=compressed", f"log:={tmp_path / 'compare.mcap'}")
    launches.append(launch)
    assert launch.wait(REPLAY_TIMEOUT) == 0, launch.output()[-5000:]
    output = launch.output()
    assert shape_errors(tmp_path / "compare.mcap") == 10, output[-5000:]
    summary = json.loads(re.search(r"\[needle_compare\] summary: (\{.*\})", output).group(1))
    assert summary["compared"] == 10 and summary["rmse_mean_m"] < 1e-4, summary
    assert "needle_stereo ready: compressed images" in output


def test_tf2_ros_listener_finds_the_needle_tip_and_the_cameras(replay):
    lookup = replay["lookup"]
    assert lookup.returncode == 0, lookup.stdout + lookup.stderr
    found = json.loads(lookup.stdout.splitlines()[-1])["found"]
    # The left camera where config/needle_stereo.yaml's output_transform puts it; the tip one needle length
    # (0.27 m, less its small sag) from the base, which the bag holds at the world origin.
    stereo = yaml.safe_load((REPO / "config" / "needle_stereo.yaml").read_text())["/**"]["ros__parameters"]
    np.testing.assert_allclose(found[CAMERA_FRAMES[0]]["translation"], stereo["output_transform"][:3], atol=1e-9)
    assert 0.25 < np.linalg.norm(found["needle_tip"]["translation"]) < 0.2701, found["needle_tip"]


def test_namespace_applies_the_experiment_and_the_cli_sees_the_nodes(stock_env, launches, tmp_path):
    """namespace:=/psm1 with an experiment: its needle_simulator section applies (ros2 param get); a runtime
    parameter is described and set; the bag plays in the namespace, the nodes stay up (keep_alive), and a second
    activation does not restart the player (before: 'executed more than once', every node stopped, exit 1)."""
    launch = Launch(stock_env, tmp_path / "launch.log", "mode:=replay", f"bag:={DYNAMIC}",
                    "experiment:=dynamic_pitch", "namespace:=/psm1", "stereo:=false", "compare:=false",
                    "keep_alive:=true")
    launches.append(launch)
    node = "/psm1/needle_simulator"
    active(stock_env, node)
    assert "[0.162, 0.27]" in ros2(stock_env, "param", "get", node, "fixtures.clamp_interval", *NO_DAEMON)
    assert "reliable" in ros2(stock_env, "param", "get", node, "qos.wrench", *NO_DAEMON)
    described = ros2(stock_env, "param", "describe", node, "rates.shape_hz", *NO_DAEMON)
    assert "Type: double" in described and "Min value: 0.1" in described, described
    assert "successful" in ros2(stock_env, "param", "set", node, "rates.shape_hz", "25.0", *NO_DAEMON)
    assert "25.0" in ros2(stock_env, "param", "get", node, "rates.shape_hz", *NO_DAEMON)
    launch.wait_for(PLAYER_DONE, REPLAY_TIMEOUT)
    for transition in ("deactivate", "activate"):
        assert "Transitioning successful" in ros2(stock_env, "lifecycle", "set", node, transition, *NO_DAEMON)
    time.sleep(3.0)
    assert launch.process.poll() is None, launch.output()[-5000:]
    assert "executed more than once" not in launch.output()
    active(stock_env, node)
    assert launch.stop() == 0, launch.output()[-5000:]


def replay_in_a_parent(stock_env: dict, launches: list, tmp_path: Path, group_action: str) -> None:
    """A parent launch file that includes the bringup (mode:=replay of the dynamic bag, no stereo or comparison)
    under ``group_action`` (a launch_ros action's constructor call); it must end by itself with the bag played."""
    parent = tmp_path / "parent.launch.py"
    parent.write_text(f"""
from launch import LaunchDescription
from launch.actions import GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch_ros.actions import PushRosNamespace, SetRemap
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    bringup = PythonLaunchDescriptionSource([FindPackageShare("needle_sim_ros"), "/launch/bringup.launch.py"])
    arguments = {{"mode": "replay", "bag": "{DYNAMIC}", "experiment": "dynamic_pitch", "stereo": "false",
                 "compare": "false"}}
    return LaunchDescription([GroupAction([{group_action},
                                           IncludeLaunchDescription(bringup, launch_arguments=arguments.items())])])
""")
    launch = Launch(stock_env, tmp_path / "launch.log", launch_file=str(parent))
    launches.append(launch)
    assert launch.wait(REPLAY_TIMEOUT) == 0, launch.output()[-5000:]
    assert re.search(PLAYER_DONE, launch.output())


def test_a_parent_namespace_reaches_the_player(stock_env, launches, tmp_path):
    """A parent launch's PushRosNamespace: the player waits for /lab/needle_simulator and plays into /lab (before:
    it waited for /needle_simulator, gave up after 30 s and failed)."""
    replay_in_a_parent(stock_env, launches, tmp_path, 'PushRosNamespace("lab")')


def test_the_bringup_needs_no_transition_event(stock_env, launches, tmp_path):
    """Every transition_event of the simulator lost (remapped where the launch does not listen), as one is lost when
    it is published before the launch's subscription has matched (ros2/rcl#1166): the replay still plays and ends
    by itself (before: the launch waited forever for 'configuring -> inactive'; seen once in CI)."""
    replay_in_a_parent(stock_env, launches, tmp_path,
                       'SetRemap(src="/needle_simulator/transition_event", dst="/lost_transition_events")')


@pytest.mark.parametrize("where", ["at start", "at configure"])
def test_a_failing_simulator_ends_the_launch(stock_env, launches, tmp_path, where):
    """A bad parameter (refused at start) or one the model rejects at configure (the simulator configures itself at
    start): the node exits 2 saying why, and the launch ends non-zero within seconds (before: it waited forever).
    At configure the launch may learn of it first from the failed transition's event, published before the exit:
    either ends it, naming the simulator."""
    bad, reason = {"at start": ("needle.elements: -3", "needle.elements"),
                   "at configure": ("needle.element_lengths: [0.1, 0.1]", "element_lengths")}[where]
    experiment = tmp_path / "bad.yaml"
    experiment.write_text(f"needle_simulator:\n  ros__parameters:\n    {bad}\n")
    launch = Launch(stock_env, tmp_path / "launch.log", "mode:=sim", f"experiment:={experiment}")
    launches.append(launch)
    start = time.monotonic()
    code = launch.wait(START_TIMEOUT)
    assert code != 0, launch.output()
    assert time.monotonic() - start < START_TIMEOUT
    ends = ["needle_simulator exited with status 2"]
    if where == "at configure":
        ends.append("needle_simulator failed a lifecycle transition (its log says why)")
    assert any(end in launch.output() for end in ends), launch.output()
    assert reason in launch.output(), launch.output()


def test_configure_only_leaves_the_simulator_inactive_for_a_manager(stock_env, launches, tmp_path):
    """activate:=false: the launch configures the simulator (its change_state service) and leaves it inactive; a
    manager's ``ros2 lifecycle set activate`` then makes it active."""
    launch = Launch(stock_env, tmp_path / "launch.log", "mode:=sim", "activate:=false")
    launches.append(launch)
    launch.wait_for("compiled/loaded the numerical kernels", START_TIMEOUT)
    deadline = time.monotonic() + START_TIMEOUT
    while not (state := ros2(stock_env, "lifecycle", "get", "/needle_simulator", *NO_DAEMON)).startswith("inactive"):
        assert time.monotonic() < deadline, state
        time.sleep(1.0)
    assert "successful" in ros2(stock_env, "lifecycle", "set", "/needle_simulator", "activate", *NO_DAEMON)
    active(stock_env, "/needle_simulator")
    assert launch.stop() == 0, launch.output()[-5000:]


def test_no_transitions_leaves_the_simulator_unconfigured(stock_env, launches, tmp_path):
    """configure:=false: a lifecycle manager drives the node (before: activate:=false still configured it)."""
    launch = Launch(stock_env, tmp_path / "launch.log", "mode:=sim", "configure:=false")
    launches.append(launch)
    launch.wait_for("needle_simulator ready", START_TIMEOUT)
    time.sleep(2.0)
    state = ros2(stock_env, "lifecycle", "get", "/needle_simulator", *NO_DAEMON)
    assert state.startswith("unconfigured"), state
    assert launch.stop() == 0, launch.output()[-5000:]


HAPTICS = "haptics.enable" in {spec.name for spec in SIMULATOR_PARAMETERS}
MAX_FORCE = 0.01  # [N] below the needle's weight (0.027 N): the output saturates while the arm holds still
POSE_TIMEOUT = 0.02  # [s] haptics.pose_timeout's default


@pytest.mark.skipif(not HAPTICS, reason="the simulator has no haptic output yet (haptics.enable: issue 37's node "
                                        "side)")
def test_hil_with_a_standin_arm(stock_env, launches, tmp_path):
    """mode:=hil with a CRTK mapping (measured_cp in, servo_cf out) and a stand-in arm at 1 kHz: the output
    saturates at haptics.max_force; the arm going silent gives zero within the watchdog time; deactivate gives
    zero and a second activation keeps the launch up; SIGINT on the launch gives zero, then a clean exit."""
    experiment = tmp_path / "arm.yaml"  # the tool on the arm: its flange offset and the limits to render
    experiment.write_text("needle_simulator:\n  ros__parameters:\n    flange_offset.position: [0.01, 0.0, 0.0]\n"
                          f"    haptics.max_force: {MAX_FORCE}\n")
    launch = Launch(stock_env, tmp_path / "launch.log", "mode:=hil", "namespace:=/PSM1", "pose_topic:=measured_cp",
                    "pose_frame:=PSM1_base", "haptic_topic:=servo_cf", f"experiment:={experiment}")
    launches.append(launch)
    arm = subprocess.Popen([sys.executable, str(HERE / "standin_arm.py"), "/PSM1", "PSM1_base",
                            str(tmp_path / "arm.json")], env=stock_env)
    try:
        node = "/PSM1/needle_simulator"
        active(stock_env, node)
        assert "[0.01, 0.0, 0.0]" in ros2(stock_env, "param", "get", node, "flange_offset.position", *NO_DAEMON)
        assert "True" in ros2(stock_env, "param", "get", node, "haptics.enable", *NO_DAEMON)
        time.sleep(3.0)  # rendering
        for _ in range(2):  # silent for 1 s, then streaming again
            arm.send_signal(signal.SIGUSR1)
            time.sleep(1.0)
        time.sleep(2.0)
        ros2(stock_env, "lifecycle", "set", node, "deactivate", *NO_DAEMON)
        deactivated = time.monotonic()
        time.sleep(1.0)
        reactivating = time.monotonic()
        ros2(stock_env, "lifecycle", "set", node, "activate", *NO_DAEMON)
        time.sleep(2.0)
        assert launch.process.poll() is None, launch.output()[-5000:]
        interrupted = time.monotonic()
        assert launch.stop() == 0, launch.output()[-5000:]
    finally:
        arm.send_signal(signal.SIGTERM)
        arm.wait(timeout=30)
    record = json.loads((tmp_path / "arm.json").read_text())
    wrenches, events = np.array(record["wrenches"]), dict((name, t) for t, name in record["events"])
    assert len(wrenches) > 1000, launch.output()[-5000:]
    assert wrenches[:, 1].max() <= MAX_FORCE * (1 + 1e-9) and wrenches[:, 1].max() > 0.99 * MAX_FORCE
    silent = wrenches[(wrenches[:, 0] > events["silent"]) & (wrenches[:, 0] < events["resume"])]
    zeros = silent[silent[:, 1] == 0.0, 0]
    assert len(zeros) and zeros[0] - events["silent"] < POSE_TIMEOUT + 0.05, "no zero within the watchdog time"
    assert (silent[silent[:, 0] >= zeros[0], 1] == 0.0).all(), "non-zero output while the arm is silent"
    inactive = wrenches[(wrenches[:, 0] > deactivated - 1.0) & (wrenches[:, 0] < reactivating)]
    assert len(inactive) and inactive[-1, 1] == 0.0
    after_sigint = wrenches[wrenches[:, 0] > interrupted]
    assert len(after_sigint) and after_sigint[-1, 1] == 0.0 and after_sigint[-1, 2] == 0.0
