"""Main job: the whole needle_sim pipeline on a bundled bag, as real ROS 2 nodes in separate processes.

    python scripts/main_job.py [--bag bags/dynamic_pitch.mcap] [--rate 1] [--duration S] [--output-dir DIR]
                               [--image-transport raw|compressed [--image-codec png|jpeg]]

1. Offline reference: the batch mode (needle_offline) runs the same pipeline over the bag in this process, with
   the bag time as the clock (out/<bag>/offline). It is the deterministic reference for the live run and fills
   numba's on-disk kernel cache, so the nodes do not stall compiling at the first pose.
2. Live: starts the installed executables (install/<pkg>/lib/<pkg>/, where ``ros2 run`` looks) with simulated time:
   ``needle_simulator``, ``needle_stereo`` (bags with images) and ``needle_compare`` (recording MCAP, writing a JSON
   summary), each with its node config file and the bag's experiment file (config/experiments/<bag>.yaml); and
   ``needle_replay`` paused (``--start-paused``, publishing the bag's start time on /clock); waits until every node
   is up and reports on /needle_sim/readiness that each of its inputs the bag plays has matched the replay's
   publisher (and the comparison its inputs from the simulator and the stereo node) and that its clock is at the
   bag's start (discovery is two-sided: what is published before that is lost); then resumes the replay. When the
   bag is done and the last comparison is in, the nodes are stopped with SIGINT (the comparison finalizes its log).
   With ``--image-transport compressed`` the replay plays the bag's images as a camera publishing through
   image_transport's compressed plugin would (CompressedImage on ``<topic>/compressed``, PNG or JPEG) and the
   stereo node takes those (its parameter ``image_transport: compressed``).
3. Prints the RMSE summary, how many measurements were compared, the simulator's and the stereo's last reports on
   /diagnostics (the simulator's comes once a second of bag time: it counts the steps up to then), the model's and the
   measurement's own error against the ground truth (synthetic bags) and where the MCAP log, summary and plots are
   (out/<bag>/live).

Exit status 0 if measurements were compared; 1 otherwise or if a node failed. Child processes are always stopped
(SIGINT, then SIGTERM/SIGKILL after a timeout), also on Ctrl+C or SIGTERM.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SOURCES = (REPO / "needle_sim_ros", REPO / "needle_vision")
EXECUTABLES = {  # name -> (package, module run with ``python -m`` when not installed)
    "needle_simulator": ("needle_sim_ros", "needle_sim_ros.nodes.simulator_node"),
    "needle_stereo": ("needle_vision", "needle_vision.ros.stereo_node"),
    "needle_compare": ("needle_sim_ros", "needle_sim_ros.nodes.compare_node"),
    "needle_replay": ("needle_sim_ros", "needle_sim_ros.nodes.replay_node"),
    "needle_bringup": ("needle_sim_ros", "needle_sim_ros.nodes.bringup"),
}
CLOCK_HZ = 100.0  # /clock rate of the replay: the nodes' simulated time advances in 10 ms ticks
START_TIMEOUT = 180.0  # [s] for the nodes to come up (a first start on a fresh machine compiles numba kernels)
DRAIN_TIMEOUT = 15.0  # [s] after the bag for the last comparisons
STOP_TIMEOUT = 15.0  # [s] for a node to exit after SIGINT


def say(text: str) -> None:
    print(f"\033[1m[main]\033[0m {text}", flush=True)


def isolated_env(from_source: bool) -> dict[str, str]:
    """Children's environment: a ROS domain of this run (id from the pid) on this host only."""
    env = dict(os.environ)
    env.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    if from_source:
        env["PYTHONPATH"] = os.pathsep.join([*map(str, SOURCES), env.get("PYTHONPATH", "")])
    return env


def command(name: str, from_source: bool) -> list[str]:
    """The installed executable, or ``python -m <module>`` from the source tree."""
    package, module = EXECUTABLES[name]
    installed = Path(os.environ.get("NEEDLE_INSTALL", REPO / "install")) / package / "lib" / package / name
    if installed.exists() and not from_source:
        return [str(installed)]
    return [sys.executable, "-m", module]


@dataclass
class Child:
    name: str
    process: subprocess.Popen
    log_path: Path
    stopping: bool = False

    def failed(self) -> bool:
        """Exited by itself with a non-zero status."""
        code = self.process.poll()
        return code is not None and code != 0 and not self.stopping

    def cpu_seconds(self) -> float | None:
        """User + system CPU time of the running process (Linux /proc), None once it exited."""
        try:
            fields = Path(f"/proc/{self.process.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return None
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""


@dataclass
class Children:
    """The started processes, stopped in reverse start order however the job ends."""

    env: dict[str, str]
    log_dir: Path
    started: list[Child] = field(default_factory=list)

    def start(self, name: str, args: list[str], from_source: bool) -> Child:
        log_path = self.log_dir / f"{name}.log"
        stream = open(log_path, "w")
        # Own session: Ctrl+C reaches only this job, which then stops the nodes in order (the comparison last
        # sees its inputs end, then finalizes its log).
        process = subprocess.Popen([*command(name, from_source), *args], env=self.env, cwd=REPO, stdout=stream,
                                   stderr=subprocess.STDOUT, start_new_session=True)
        stream.close()
        child = Child(name, process, log_path)
        self.started.append(child)
        shown = log_path.relative_to(REPO) if log_path.is_relative_to(REPO) else log_path
        say(f"started {name} (pid {process.pid}, log {shown})")
        return child

    def stop(self, child: Child) -> int | None:
        """SIGINT, then SIGTERM, then SIGKILL, each after a timeout; returns the exit status."""
        child.stopping = True
        for sig, timeout in ((signal.SIGINT, STOP_TIMEOUT), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
            if child.process.poll() is not None:
                break
            child.process.send_signal(sig)
            try:
                child.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                say(f"{child.name} did not exit after {sig.name}")
        return child.process.poll()

    def stop_all(self) -> None:
        for child in reversed(self.started):
            self.stop(child)


def slice_bag(source: Path, destination: Path, start_offset: float, duration: float | None,
              background_frames: int) -> Path:
    """A copy of the bag's messages logged in [start + start_offset, + duration], for a shorter run; the first
    ``background_frames`` images (and camera infos) of each camera are kept, since the stereo needs them first."""
    from needle_common.bag_reader import BagReader
    from needle_sim_ros.recording import McapBagWriter, WriterOptions
    reader = BagReader(source)
    begin = reader.start_time_ns + round(start_offset * 1e9)
    end = reader.end_time_ns if duration is None else begin + round(duration * 1e9)
    kept: dict[str, int] = {}
    with McapBagWriter(destination, WriterOptions(overwrite=True)) as writer:
        for topic in reader.topics.values():
            writer.add_topic(topic.name, topic.type_name, topic.offered_qos)
        for message in reader.messages():
            camera = message.topic.endswith(("/image_raw", "/camera_info"))
            background = camera and kept.get(message.topic, 0) < background_frames
            kept[message.topic] = kept.get(message.topic, 0) + 1
            if begin <= message.log_time_ns <= end or background:
                writer.write(message.topic, message.data, message.log_time_ns)
            elif message.log_time_ns > end:
                break
    return destination


def expected_measurements(bag: Path, stereo: bool, background_frames: int) -> int:
    """Measurements the bag should yield: stereo pairs after the background, or recorded measured shapes."""
    from needle_common.bag_reader import BagReader
    topics = BagReader(bag).topics
    if stereo:
        return max(0, topics["/left/image_raw"].message_count - background_frames) if "/left/image_raw" in topics else 0
    return topics["/needle/measured_shape"].message_count if "/needle/measured_shape" in topics else 0


class Monitor:
    """This job's own node: sees the graph, the clock, the comparisons and the simulator's diagnostics."""

    def __init__(self) -> None:
        import rclpy
        from lifecycle_msgs.srv import GetState
        from diagnostic_msgs.msg import DiagnosticArray
        from needle_interfaces.msg import ShapeError
        from rclpy.qos import QoSProfile
        from rosgraph_msgs.msg import Clock
        from std_srvs.srv import Trigger
        from needle_common.ros.input_status import InputReports
        from rclpy.signals import SignalHandlerOptions
        self.rclpy = rclpy
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # Ctrl+C stays a KeyboardInterrupt here
        self.node = rclpy.create_node("needle_main_job")
        self.clock_ns = 0
        self.errors: list[float] = []
        self.node.create_subscription(Clock, "/clock", self._on_clock, QoSProfile(depth=1))
        self.node.create_subscription(ShapeError, "shape_error", lambda m: self.errors.append(m.rmse),
                                      QoSProfile(depth=100))
        self.get_state = self.node.create_client(GetState, "/needle_simulator/get_state")
        self.get_state_request = GetState.Request()
        self.resume = self.node.create_client(Trigger, "/needle_replay/resume")
        self.reports = InputReports(self.node)  # the nodes' latched input reports (needle_replay reads them too)
        self.statuses: dict[str, tuple[int, dict[str, str]]] = {}  # /diagnostics: status name -> (clock ns, values)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _on_diagnostics(self, msg) -> None:
        clock_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for status in msg.status:
            self.statuses[status.name] = (clock_ns, {kv.key: kv.value for kv in status.values})

    def _on_clock(self, msg) -> None:
        self.clock_ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=max(0.0, min(0.05, end - time.monotonic())))

    def connected(self, stereo: bool, fbg: bool, image_topic: str = "/left/image_raw") -> bool:
        """Every node is up and the comparison's inputs are connected."""
        n = self.node
        ready = (n.count_subscribers("/base_pose") >= 1 and n.count_publishers("/needle/shape") >= 1
                 and n.count_subscribers("/needle/shape") >= 1 and n.count_publishers("/shape_error") >= 1)
        if stereo:
            ready = ready and n.count_publishers("/needle/measured_shape") >= 1 \
                and n.count_subscribers(image_topic) >= 1
        if stereo or fbg:
            ready = ready and n.count_subscribers("/needle/measured_shape") >= 1
        return ready

    def simulator_active(self) -> bool:
        """The simulator answers its lifecycle state ``active``: its kernels are compiled and it takes poses (it
        subscribes before compiling; poses sent earlier would wait in its queue and the first one it keeps would not
        be the bag's first)."""
        if not self.get_state.service_is_ready():
            return False
        future = self.get_state.call_async(self.get_state_request)
        end = time.monotonic() + 1.0
        while not future.done() and time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
        return future.done() and future.result() is not None and future.result().current_state.label == "active"

    def call_resume(self) -> bool:
        """needle_replay's ~/resume; False if it did not answer within 5 s."""
        if not self.resume.wait_for_service(timeout_sec=5.0):
            return False
        future = self.resume.call_async(self.resume.srv_type.Request())
        end = time.monotonic() + 5.0
        while not future.done() and time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
        return future.done() and future.result() is not None and future.result().success

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def run(args: argparse.Namespace) -> int:
    sys.path[:0] = [str(s) for s in SOURCES] if args.from_source else []
    from needle_sim_ros.offline.cli import main as offline_main
    from needle_sim_ros.offline.cli import summary_lines
    from needle_sim_ros.parameters.compare import LOGGABLE_TOPICS
    from needle_sim_ros.parameters.experiment import experiment_for_bag, load_experiment, node_values
    from needle_sim_ros.offline.plots import write_plots
    from needle_sim_ros.offline.results import read_pipeline_log, versus_ground_truth

    bag = (REPO / args.bag).resolve() if not args.bag.is_absolute() else args.bag
    experiment = load_experiment(args.experiment) if args.experiment else experiment_for_bag(bag, REPO / "config")
    stereo = experiment.settings.stereo
    name = bag.stem
    root = (args.output_dir or REPO / "out" / name).resolve()
    out = root / "live"
    out.mkdir(parents=True, exist_ok=True)
    say(f"bag {bag.relative_to(REPO) if bag.is_relative_to(REPO) else bag}: {experiment.settings.description}")
    shown = experiment.path.relative_to(REPO) if experiment.path.is_relative_to(REPO) else experiment.path
    say(f"experiment parameters {shown}; outputs in {root}")
    stereo_params = node_values(experiment.files["needle_stereo"], "needle_stereo")
    logged = node_values(experiment.files["needle_compare"], "needle_compare").get("log.topics", LOGGABLE_TOPICS)
    background = int(stereo_params.get("background.frames", 10))
    if args.start_offset or args.duration is not None:
        bag = slice_bag(bag, root / f"{name}_slice.mcap", args.start_offset, args.duration, background)
        say(f"playing a slice: {args.start_offset:g} s + {args.duration if args.duration is not None else 'all'} s")
    expected = expected_measurements(bag, stereo, background)
    offline = None
    if not args.skip_offline:
        # The same pipeline in this process, deterministic: the reference for the live run. It also compiles (first
        # run after a build) or loads the numba kernels into the on-disk cache, so the nodes do not stall on them.
        say("offline reference run (needle_offline: same stages, bag time as the clock, as fast as it goes) ...")
        status = offline_main([str(bag), "--experiment", str(experiment.path), "--output-dir", str(root / "offline")])
        if status != 0:
            say("the offline run failed")
            return 1
        offline = json.loads((root / "offline" / "summary.json").read_text())

    env = isolated_env(args.from_source)
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    say(f"ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, discovery on this host only; "
        f"{'source tree' if args.from_source else 'installed executables (install/<pkg>/lib/<pkg>/)'}")
    children = Children(env, out)
    log_path, summary_path = out / "needle_compare.mcap", out / "summary.json"
    summary_path.unlink(missing_ok=True)
    monitor = None
    try:
        def params(node: str) -> list[str]:
            files = [a for path in experiment.files[node] for a in ("--params-file", str(path))]
            return ["--ros-args", *files, "-p", "use_sim_time:=true"]

        children.start("needle_simulator", params("needle_simulator"), args.from_source)
        compressed = args.image_transport == "compressed"
        if stereo:
            children.start("needle_stereo", [*params("needle_stereo"), "-p",
                                             f"image_transport:={args.image_transport}"], args.from_source)
        compare = children.start("needle_compare", [*params("needle_compare"), "-p", f"log.path:={log_path}",
                                          "-p", "log.overwrite:=true", "-p", f"summary_path:={summary_path}",
                                          "-r", "model/shape:=needle/shape",
                                          "-r", "measured/shape:=needle/measured_shape"], args.from_source)
        from needle_common.bag_reader import BagReader
        reader = BagReader(bag)
        duration = (reader.end_time_ns - reader.start_time_ns) / 1e9
        topics = [t for t in ("/base_pose", "/tip_load", *(("/left/image_raw", "/right/image_raw") if stereo else ()),
                              *(() if stereo else ("/needle/measured_shape",))) if t in reader.topics]
        if stereo and not stereo_params.get("left_calibration_file", ""):
            topics += [t for t in ("/left/camera_info", "/right/camera_info") if t in reader.topics]
        replay = children.start("needle_replay", [str(bag), "--clock", str(CLOCK_HZ), "--rate", str(args.rate),
                                                   "--start-paused", "--wait-for-subscribers", "10", "--topics",
                                                   *topics, *(("--compress-images", args.image_codec) if compressed
                                                              else ())], args.from_source)
        # the names the replay publishes on (image_transport's <image>/compressed for compressed images)
        played = [f"{t}/compressed" if compressed and t.endswith("/image_raw") else t for t in topics]
        # the comparison's inputs from the other nodes, matched from its side too: what the simulator publishes
        # before that is missing from the log
        internal = ["/needle/shape", *(("/needle/measured_shape",) if stereo else ()),
                    *(("/wrench",) if "wrench" in logged else ())]
        monitor = Monitor()
        say("waiting for the nodes to come up and match the replay's and each other's publishers ...")
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            monitor.spin(0.2)
            missing = monitor.reports.waiting([*played, *internal], time.monotonic(), reader.start_time_ns)
            if not missing and monitor.connected(stereo, not stereo, "/left/image_raw/compressed" if compressed
                                                 else "/left/image_raw") and monitor.simulator_active():
                break
            failed = [c for c in children.started if c.failed()]
            if failed or time.monotonic() > deadline:
                for child in failed:
                    say(f"{child.name} exited with status {child.process.returncode}:\n{child.tail()}")
                say(f"the nodes did not come up ({'; '.join(missing) or 'not connected'})" if not failed else
                    "a node failed at start")
                return 1
        if not monitor.call_resume():
            say(f"needle_replay did not resume:\n{replay.tail()}")
            return 1
        images = f", images as CompressedImage ({args.image_codec})" if compressed and stereo else ""
        say(f"nodes connected; playing {duration:.2f} s of bag at {args.rate:g}x with /clock{images} "
            f"({expected} measurements expected)")
        next_report = time.monotonic() + 1.0
        while replay.process.poll() is None:
            monitor.spin(0.1)
            failed = [c for c in children.started if c.failed()]
            if failed:
                for child in failed:
                    say(f"{child.name} exited with status {child.process.returncode}:\n{child.tail()}")
                return 1
            if time.monotonic() >= next_report and monitor.clock_ns:
                next_report += 1.0
                t = (monitor.clock_ns - reader.start_time_ns) / 1e9
                last = f", last RMSE {monitor.errors[-1] * 1e3:.3f} mm" if monitor.errors else ""
                say(f"  bag time {max(t, 0.0):5.2f} / {duration:.2f} s, {len(monitor.errors)} comparisons{last}")
        if replay.process.returncode != 0:
            say(f"needle_replay failed (status {replay.process.returncode}):\n{replay.tail()}")
            return 1
        drain_end = time.monotonic() + DRAIN_TIMEOUT
        while len(monitor.errors) < expected and time.monotonic() < drain_end:
            monitor.spin(0.2)
        monitor.spin(0.5)
        report_clock_ns, diagnostics = monitor.statuses.get("/needle_simulator: integration", (0, {}))
        diagnostics_bag_time = (report_clock_ns - reader.start_time_ns) / 1e9
        stereo_pairs = monitor.statuses.get("/needle_stereo: measurement", (0, {}))[1]
        cpu = {c.name: c.cpu_seconds() for c in children.started if c.process.poll() is None}
        say(f"bag done: {len(monitor.errors)} comparisons seen; stopping the nodes")
        for child in reversed(children.started):
            status = children.stop(child)
            if status not in (0, None, -signal.SIGINT):
                say(f"{child.name} exited with status {status}:\n{child.tail()}")
        if not summary_path.is_file():
            say(f"needle_compare wrote no summary ({summary_path}):\n{compare.tail()}")
            return 1
        summary = {"bag": str(bag), "experiment": str(experiment.path), "rate": args.rate,
                   "image_transport": args.image_transport + (f" ({args.image_codec})" if compressed else ""),
                   "comparison": json.loads(summary_path.read_text())}
        log = read_pipeline_log(log_path, bag)
        summary["versus_ground_truth"] = versus_ground_truth(log)
        summary["expected_measurements"] = expected
        summary["simulator_diagnostics"] = diagnostics
        summary["stereo_diagnostics"] = stereo_pairs
        # bag time [s] of the pose the needle (last) started at: 0 when the simulator got the bag's first pose
        summary["needle_started_at_s"] = float(diagnostics.get("started_at_s", "nan")) - reader.start_time_ns / 1e9
        summary["cpu_seconds"] = cpu
        summary["plots"] = [str(p) for p in write_plots(log, out / "plots", experiment.settings.plot_instants, name)]
        summary_path.write_text(json.dumps(summary, indent=2) + "\n")
        compared = summary["comparison"]["compared"]
        say("RMSE summary (model vs measurement):")
        for line in summary_lines(summary):
            say(f"  {line}")
        dropped = expected - compared
        say(f"  {compared} of {expected} measurements compared" + (f" ({dropped} dropped)" if dropped > 0 else
                                                                     " (none dropped)"))
        if offline is not None and offline["comparison"]["rmse_mean_m"] is not None:
            say(f"  offline reference: RMSE mean {offline['comparison']['rmse_mean_m'] * 1e3:.3f} mm over "
                f"{offline['comparison']['compared']} measurements, {offline['timing']['real_time_factor']:.2f}x "
                f"real time ({root / 'offline'})")
        if diagnostics:
            say(f"  simulator (last report, bag time {diagnostics_bag_time:.2f} s): {diagnostics.get('steps')} steps, "
                f"needle started at bag time {summary['needle_started_at_s']:.3f} s, mean step "
                f"{diagnostics.get('step_time_mean_ms')} ms, skipped {diagnostics.get('skipped_time_s')} s, failed "
                f"steps {diagnostics.get('failed_steps')}")
        if stereo_pairs:
            say("  stereo pairs: " + ", ".join(f"{key[len('pairs_'):].replace('_', ' ')} {value}"
                                               for key, value in stereo_pairs.items() if key.startswith("pairs_"))
                + f"; frames without a partner {stereo_pairs.get('frames_unpaired')}")
        say("  CPU time of the nodes [s]: " + ", ".join(f"{k} {v:.1f}" for k, v in cpu.items() if v is not None))
        say(f"MCAP log: {log_path}")
        say(f"summary:  {summary_path}")
        say(f"plots:    {out / 'plots'} ({', '.join(Path(p).name for p in summary['plots'])})")
        say(f"node logs: {out}/*.log")
        return 0 if compared > 0 else 1
    finally:
        if monitor is not None:
            monitor.close()
        children.stop_all()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bag", type=Path, default=Path("bags/dynamic_pitch.mcap"), help="bag to play "
                        "(default: %(default)s); its parameters: config/experiments/<bag name>.yaml")
    parser.add_argument("--experiment", type=Path, help="experiment params file instead of the bag's")
    parser.add_argument("--rate", type=float, default=1.0, help="playback rate (default 1: real time)")
    parser.add_argument("--start-offset", type=float, default=0.0, help="skip the first S seconds of the bag")
    parser.add_argument("--duration", type=float, help="play only S seconds")
    parser.add_argument("--output-dir", type=Path, help="outputs: <dir>/live (nodes) and <dir>/offline "
                        "(default: out/<bag name>)")
    parser.add_argument("--skip-offline", action="store_true", help="no offline reference run first")
    parser.add_argument("--image-transport", choices=("raw", "compressed"), default="raw", help="how the replay "
                        "publishes the bag's images and the stereo node takes them: raw (sensor_msgs/Image) or "
                        "compressed (sensor_msgs/CompressedImage on <topic>/compressed) (default: %(default)s)")
    parser.add_argument("--image-codec", choices=("png", "jpeg"), default="png", help="with --image-transport "
                        "compressed: PNG (lossless) or JPEG at quality 95 (default: %(default)s)")
    parser.add_argument("--from-source", action="store_true", help="run the nodes from the source tree "
                        "(python -m) instead of the installed executables")
    args = parser.parse_args()
    if not args.rate > 0 or args.start_offset < 0 or (args.duration is not None and args.duration <= 0):
        parser.error("--rate and --duration must be > 0, --start-offset >= 0")
    def interrupted(*_) -> None:
        raise KeyboardInterrupt

    # Ctrl+C and SIGTERM end the job through its clean-up, also when started with SIGINT ignored (a background job
    # of a script), which the nodes would inherit and then not finalize their logs on SIGINT.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, interrupted)
    try:
        return run(args)
    except KeyboardInterrupt:
        say("interrupted: nodes stopped")
        return 130
    except (OSError, ValueError) as error:  # bad bag, experiment file or parameters (the message names them)
        say(f"error: {error}")
        return 2


if __name__ == "__main__":
    sys.exit(main())
