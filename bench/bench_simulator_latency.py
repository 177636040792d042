"""Cross-process latency and deadline misses of `needle_simulator` at 1 kHz (issue 4 benchmark).

Starts the simulator in its own process (10 elements, dt = 1 ms, wall-clock time, its default configuration:
integration thread at SCHED_FIFO priority 50 if permitted), publishes base poses at 1 kHz from this process (a
slow sinusoidal pitch, like a robot driver would; publish times jittered by +-0.4 ms, a harsher driver than most:
with the node's grid locked half a step from the poses, a pose later than +0.25 ms plus its transport meets a step
already integrated), and measures

* latency: from publishing a pose (its stamp) to receiving the first wrench whose step time is at or after that
  stamp and that arrives after the pose was sent, i.e. the first wrench integrated up to the pose's instant that
  could have used the pose (pose transport + wait for the step: its end time, or none with loop.ahead_to_pose +
  step + wrench transport). "Receiving" is the middleware's reception time of the wrench in this process
  (rclpy MessageInfo ``received_timestamp``, taken by the DDS reader), so the delay before this process's own
  receiving thread takes the message is not charged to the node; that delay is shown separately (callback);
* deadline misses: the node's own counter from /diagnostics (periods in which the loop had to integrate more
  than one step to catch up), relative to the steps taken;
* poses late for their step: the node's ``poses_late_for_their_step`` relative to the accepted poses (a pose whose
  step was integrated before it arrived: its latency is about a step longer).

The simulator computes its shape and visualization outputs only while something subscribes to them; this process
subscribes to the wrench and the diagnostics only (a controller's view), or also to the shape and the path with
``--with-outputs`` (RViz running beside it).

With ``--echo`` the simulator is replaced by the transport floor of this machine: a process that answers each pose
with a wrench stamped with the pose's stamp, taken and published as the simulator's loop does (the same polled
subscription, wait set, QoS and ready-made CDR bytes), no simulation. The simulator cannot be faster than it.

With ``--haptics`` the simulator runs twice in the same invocation, with the haptic output off and then on
(``haptics.enable``; this process then also reads ``haptic/wrench`` reliably, as an arm's driver would), and the
table has a column for each: the haptic output's cost is the difference of the pose->wrench latencies; the
pose->haptic wrench latency is shown as well.

Usage: python bench/bench_simulator_latency.py [--duration 60] [--elements 10] [--jitter 0.8] [--realtime-priority 0]
                                             [--param loop.ahead_to_pose=false ...] [--echo] [--haptics]
       python bench/bench_simulator_latency.py --pose-path   (the node's per-pose Python only, in-process)
"""
from __future__ import annotations

import argparse
import math
import os
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from nav_msgs.msg import Path as Path_
from needle_interfaces.msg import NeedleShape
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from needle_sim_ros.nodes.polling import MessageWaiter, PolledCallbackGroup, drain

REPO = Path(__file__).resolve().parents[1]


def counter_rate(diagnostics: list[dict], counter: str, total: str) -> float:
    """Increase of the node's diagnostic ``counter`` over that of ``total`` between the first and the last report
    that carry both (NaN with fewer than two)."""
    pairs = [(int(d[counter]), int(d[total])) for d in diagnostics if counter in d and total in d]
    if len(pairs) < 2:
        return float("nan")
    return (pairs[-1][0] - pairs[0][0]) / max(pairs[-1][1] - pairs[0][1], 1)


def stamp_seconds(data: bytes) -> float:
    sec, nanosec = struct.unpack_from("<iI", data, 4)
    return sec + nanosec * 1e-9


def pose_path_cost(elements: int, poses: int = 3000) -> None:
    """Print the node's per-pose Python, in this process: offering a pose to the simulation (validation, buffer) and
    the base motion at the next step time (the base-pose refit), median and p90 over ``poses`` poses at 1 kHz."""
    from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
    from needle_sim_ros.simulation import compile_kernels, simulation_from_parameters

    p = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS} | {"needle.elements": elements}
    compile_kernels(p)
    sim = simulation_from_parameters(p)
    costs = []
    for k in range(poses + 100):
        t = 1.0 + 1e-3 * k + 4e-4
        half_pitch = 0.5 * math.radians(5.0 * math.sin(2 * math.pi * 0.2 * t))
        position, orientation = np.array([0.4, 0.0, 0.3]), np.array([0.0, math.sin(half_pitch), 0.0,
                                                                       math.cos(half_pitch)])
        start = time.perf_counter()
        sim.offer_pose(t, position, orientation)
        offered = time.perf_counter()
        sim.base_motions(np.array([t + 6e-4]))
        costs.append((offered - start, time.perf_counter() - offered))
    costs = np.array(costs[100:]) * 1e6
    print(f"per-pose Python ({poses} poses, load average {os.getloadavg()[0]:.2f}): offer median "
          f"{np.median(costs[:, 0]):.1f} us (p90 {np.percentile(costs[:, 0], 90):.1f}), base motion with the refit "
          f"median {np.median(costs[:, 1]):.1f} us (p90 {np.percentile(costs[:, 1], 90):.1f})")


def serve_echo() -> None:
    """The ``--echo`` process: each base pose answered at once with a wrench carrying the pose's stamp."""
    from needle_common.ros.ros_parameters import qos_profile
    from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS

    defaults = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
    rclpy.init()
    node = rclpy.create_node("latency_echo")
    wrench_pub = node.create_publisher(WrenchStamped, "wrench", qos_profile(defaults["qos.wrench"], 100))
    template = bytearray(serialize_message(WrenchStamped(header=Header(frame_id="needle_base"))))

    def on_pose(data: bytes) -> None:
        template[4:12] = data[4:12]  # the pose's stamp (sec, nanosec)
        wrench_pub.publish(bytes(template))

    subscription = node.create_subscription(PoseStamped, "base_pose", on_pose,
                                            qos_profile(defaults["qos.base_pose"], 100),
                                            callback_group=PolledCallbackGroup(), raw=True)
    waiter = MessageWaiter([subscription], node.context)
    while rclpy.ok():
        if waiter.wait(0.1):
            drain(subscription)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=60.0, help="measurement time [s]")
    parser.add_argument("--elements", type=int, default=10)
    parser.add_argument("--rate", type=float, default=1000.0, help="pose rate [Hz]")
    parser.add_argument("--jitter", type=float, default=0.8, help="pose timing jitter, peak to peak [periods]")
    parser.add_argument("--realtime-priority", type=int, default=None,
                        help="override the node's loop.realtime_priority (default 50; 0: normal scheduling)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="another needle_simulator parameter (YAML value), e.g. loop.ahead_to_pose=false")
    parser.add_argument("--pose-path", action="store_true",
                        help="only measure the node's per-pose Python in this process (no simulator process)")
    parser.add_argument("--with-outputs", action="store_true",
                        help="also subscribe to needle/shape and needle/path (the node then computes its outputs)")
    parser.add_argument("--echo", action="store_true",
                        help="measure the transport floor: an echo process instead of the simulator")
    parser.add_argument("--haptics", action="store_true",
                        help="run with the haptic output off, then on, and show both in one table")
    parser.add_argument("--serve-echo", action="store_true", help=argparse.SUPPRESS)  # the --echo process itself
    args = parser.parse_args()
    if args.pose_path:
        pose_path_cost(args.elements)
        return 0
    if args.serve_echo:
        serve_echo()
        return 0
    if args.haptics and args.echo:
        parser.error("--haptics measures the simulator: not with --echo")

    env = dict(os.environ, ROS_DOMAIN_ID=str(1 + os.getpid() % 100), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"], ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    overrides = {"needle.elements": args.elements, "integrator.dt": 0.001}
    if args.realtime_priority is not None:
        overrides["loop.realtime_priority"] = args.realtime_priority
    for assignment in args.param:
        name, separator, value = assignment.partition("=")
        if not separator:
            parser.error(f"--param {assignment!r}: expected NAME=VALUE")
        overrides[name] = yaml.safe_load(value)
    runs = {"haptics off": False, "haptics on": True} if args.haptics else {"": None}
    rclpy.init()
    results = {}
    for label, haptics in runs.items():
        run_overrides = overrides if haptics is None else overrides | {"haptics.enable": haptics}
        results[label] = measure(args, env, run_overrides, haptic_topic=bool(haptics))
        if results[label] is None:
            rclpy.shutdown()
            return 2
    rclpy.shutdown()
    subject = "echo (transport floor, no simulation)" if args.echo else "needle_simulator"
    print(f"\n{subject}, {args.elements} elements, dt = 1 ms, poses at {args.rate:g} Hz, {args.duration:g} s, "
          f"loop.realtime_priority {'default (50)' if args.realtime_priority is None else args.realtime_priority}, "
          f"{'shape and path subscribed' if args.with_outputs else 'no output subscribed'}")
    rows = {key: [result[key] for result in results.values()] for key in next(iter(results.values()))}
    targets = {"latency p99": "< 1 ms", "deadline misses": "< 0.1 %"}
    print("| metric | " + " | ".join(label or "value" for label in results) + " | target |")
    print("|---|" + "---|" * len(results) + "---|")
    for key, values in rows.items():
        print(f"| {key} | " + " | ".join(values) + f" | {targets.get(key, '')} |")
    if args.haptics:
        off, on = (float(results[label]["latency p50"].split()[0]) for label in runs)
        print(f"| haptic output's cost at p50 (on - off) | {on - off:+.3f} ms | | <= 0.05 ms |")
    return 0


def measure(args, env: dict, overrides: dict, haptic_topic: bool) -> dict[str, str] | None:
    """One simulator (or echo) process with these parameters, driven and measured for ``args.duration`` s: the
    table's rows (None if the process exited before subscribing). ``haptic_topic``: also read haptic/wrench
    reliably and measure pose->haptic wrench latency."""
    params = Path(tempfile.mkdtemp()) / "bench.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": overrides}}))
    executable = REPO / "install/needle_sim_ros/lib/needle_sim_ros/needle_simulator"
    load_before = os.getloadavg()[0]  # the machine may be shared: latency depends on it
    command = [sys.executable, __file__, "--serve-echo"] if args.echo else [str(executable), "--ros-args",
                                                                              "--params-file", str(params)]
    simulator = subprocess.Popen(command, env=env)

    node = rclpy.create_node("latency_bench")
    pub = node.create_publisher(PoseStamped, "base_pose", 10)
    # (stamp, middleware receive time, callback time) of every wrench
    wrenches: list[tuple[float, float, float]] = []
    diagnostics: list[dict] = []
    # raw: only the stamp is needed (bytes 4-12 of the CDR payload); no Python message objects
    wrench_sub = node.create_subscription(WrenchStamped, "wrench", lambda data, info: wrenches.append(
        (stamp_seconds(data), info["received_timestamp"] * 1e-9, time.time())), qos_profile_sensor_data, raw=True,
        callback_group=PolledCallbackGroup())
    haptics: list[tuple[float, float]] = []  # (stamp, middleware receive time) of every haptic wrench
    subscriptions = [wrench_sub]
    if haptic_topic:
        subscriptions.append(node.create_subscription(
            WrenchStamped, "haptic/wrench", lambda data, info: haptics.append(
                (stamp_seconds(data), info["received_timestamp"] * 1e-9)),
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE), raw=True,
            callback_group=PolledCallbackGroup()))
    if args.with_outputs:  # raw: their bytes are not decoded
        for topic, kind in (("needle/shape", NeedleShape), ("needle/path", Path_)):
            node.create_subscription(kind, topic, lambda data: None, 10, raw=True)
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diagnostics.append(
        {kv.key: kv.value for kv in m.status[0].values}) if m.status else None, 10)
    # Wrenches are taken on their own thread, blocked in a wait set between messages (no executor: ~0.1 ms of
    # Python less per message); diagnostics (1 Hz) through an executor. The publishing loop sleeps between poses
    # and sends ready-made CDR bytes. A robot driver's publisher costs microseconds; this process stands in for
    # it, so it should take as little as possible of the two cores the node runs on as well.
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinning = threading.Thread(target=executor.spin, daemon=True)
    spinning.start()
    receiving = threading.Event()
    receiving.set()

    def receive_wrenches() -> None:
        waiter = MessageWaiter(subscriptions, node.context)
        while receiving.is_set():
            for subscription in waiter.wait(0.05):
                drain(subscription)
        waiter.close()

    receiver = threading.Thread(target=receive_wrenches, daemon=True)
    receiver.start()

    def stop() -> None:
        receiving.clear()
        receiver.join()
        executor.shutdown()
        spinning.join()
        node.destroy_node()
        simulator.terminate()
        simulator.wait()
    while pub.get_subscription_count() == 0:
        if simulator.poll() is not None:  # e.g. a --param the node refused (its own message is above)
            print(f"error: the {'echo' if args.echo else 'simulator'} process exited with status "
                  f"{simulator.returncode} before subscribing", file=sys.stderr)
            stop()
            return None
        time.sleep(0.1)

    template = bytearray(serialize_message(PoseStamped(header=Header(frame_id="world"))))
    pose_offset = len(template) - 56  # the pose's 7 doubles end the message
    pose_stamps, publish_delays = [], []
    period = 1.0 / args.rate
    # publish times jittered by up to +-jitter/2 periods: the poses meet the node's 1 ms step grid at every phase
    phase = np.random.default_rng(0).uniform(-0.5, 0.5, 100_000) * args.jitter
    start = time.perf_counter()
    warmup = 3.0
    k = 0
    while time.perf_counter() - start < warmup + args.duration:
        target = start + (k + phase[k % phase.size]) * period
        remaining = target - time.perf_counter()
        if remaining > 0:
            time.sleep(remaining)
        late = time.perf_counter() - target
        t = time.time()
        half_pitch = 0.5 * math.radians(5.0 * math.sin(2 * math.pi * 0.2 * t))  # about world y
        sec = math.floor(t)
        struct.pack_into("<iI", template, 4, sec, min(round((t - sec) * 1e9), 999_999_999))
        struct.pack_into("<7d", template, pose_offset, 0.4, 0.0, 0.3, 0.0, math.sin(half_pitch), 0.0,
                         math.cos(half_pitch))
        pub.publish(bytes(template))
        if time.perf_counter() - start > warmup:
            pose_stamps.append(t)
            publish_delays.append(late)
        k += 1
    time.sleep(0.5)
    stop()

    received = np.array(wrenches)
    sent = np.array(pose_stamps)  # a pose's stamp is its publication time

    def latency_ms(arrivals: np.ndarray, stamps: np.ndarray) -> np.ndarray:
        """Per pose: the earliest arrival of a wrench with a step time >= the pose's stamp that arrived after the
        pose was sent (both thresholds are the stamp: key = min(step time, arrival) >= stamp)."""
        key = np.minimum(stamps, arrivals)
        order = np.argsort(key)
        earliest = np.minimum.accumulate(arrivals[order][::-1])[::-1]  # earliest arrival among keys >= key
        index = np.searchsorted(key[order], sent)
        valid = index < len(order)
        return (earliest[index[valid]] - sent[valid]) * 1e3

    latency, latency_callback = latency_ms(received[:, 1], received[:, 0]), latency_ms(received[:, 2], received[:, 0])
    step_mean = [float(d["step_time_mean_ms"]) for d in diagnostics if "step_time_mean_ms" in d]
    miss_rate = counter_rate(diagnostics, "deadline_misses", "steps")
    late_rate = counter_rate(diagnostics, "poses_late_for_their_step", "poses_accepted")
    rows = {
        "load average (1 min) before / after": f"{load_before:.2f} / {os.getloadavg()[0]:.2f}",
        "latency p50": f"{np.percentile(latency, 50):.3f} ms",
        "latency p99": f"{np.percentile(latency, 99):.3f} ms",
        "latency p99.9": f"{np.percentile(latency, 99.9):.3f} ms",
        "latency max": f"{latency.max():.3f} ms",
        "latency to the bench's Python callback p50 / p99": f"{np.percentile(latency_callback, 50):.3f} / "
                                                             f"{np.percentile(latency_callback, 99):.3f} ms",
        "wrench messages received": f"{len(wrenches)}",
        "pose publication after its jittered time p50 / p99": f"{1e3 * np.percentile(publish_delays, 50):.3f} / "
                                                              f"{1e3 * np.percentile(publish_delays, 99):.3f} ms",
        "deadline misses": f"{100 * miss_rate:.3f} %",
        "poses late for their step (node diagnostics)": f"{100 * late_rate:.3f} %",
        "mean step time (node)": f"{np.mean(step_mean[1:]) if len(step_mean) > 1 else float('nan'):.3f} ms"}
    if args.haptics:
        if haptics:
            haptic = np.array(haptics)
            haptic_latency = latency_ms(haptic[:, 1], haptic[:, 0])
            rows["pose -> haptic wrench latency p50 / p99"] = (f"{np.percentile(haptic_latency, 50):.3f} / "
                                                               f"{np.percentile(haptic_latency, 99):.3f} ms")
        else:
            rows["pose -> haptic wrench latency p50 / p99"] = "-"
        rows["haptic messages received"] = f"{len(haptics)}"
    return rows


if __name__ == "__main__":
    sys.exit(main())
