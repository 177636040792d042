"""Cross-process latency and deadline misses of `needle_simulator` at 1 kHz (issue 4 benchmark).

Starts the simulator in its own process (10 elements, dt = 1 ms, wall-clock time), publishes base poses at
1 kHz from this process (a slow sinusoidal pitch, like a robot driver would), and measures

* latency: from publishing a pose (its stamp) to receiving the first wrench whose step time is at or after that
  stamp, i.e. the first wrench integrated up to the pose's instant (pose transport + wait for the next tick +
  step + wrench transport);
* deadline misses: the node's own counter from /diagnostics (periods in which the loop had to integrate more
  than one step to catch up), relative to the steps taken.

Usage: python bench/bench_simulator_latency.py [--duration 60] [--elements 10]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.qos import qos_profile_sensor_data
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=60.0, help="measurement time [s]")
    parser.add_argument("--elements", type=int, default=10)
    parser.add_argument("--rate", type=float, default=1000.0, help="pose rate [Hz]")
    args = parser.parse_args()

    env = dict(os.environ, ROS_DOMAIN_ID=str(1 + os.getpid() % 100), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"], ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    params = Path(tempfile.mkdtemp()) / "bench.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"needle.elements": args.elements, "integrator.dt": 0.001}}}))
    executable = REPO / "install/needle_sim_ros/lib/needle_sim_ros/needle_simulator"
    simulator = subprocess.Popen([str(executable), "--ros-args", "--params-file", str(params)], env=env)

    rclpy.init()
    node = rclpy.create_node("latency_bench")
    pub = node.create_publisher(PoseStamped, "base_pose", 10)
    wrenches: list[tuple[float, float]] = []  # (receive time, stamp)
    diagnostics: list[dict] = []
    node.create_subscription(WrenchStamped, "wrench", lambda m: wrenches.append(
        (time.time(), m.header.stamp.sec + m.header.stamp.nanosec * 1e-9)), qos_profile_sensor_data)
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diagnostics.append(
        {kv.key: kv.value for kv in m.status[0].values}) if m.status else None, 10)
    while pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.1)

    pose_stamps = []
    period = 1.0 / args.rate
    start = time.perf_counter()
    warmup = 3.0
    k = 0
    while time.perf_counter() - start < warmup + args.duration:
        target = start + k * period
        while time.perf_counter() < target:
            rclpy.spin_once(node, timeout_sec=0.0)
        now = node.get_clock().now()
        t = now.nanoseconds * 1e-9
        msg = PoseStamped()
        msg.header.stamp = now.to_msg()
        msg.header.frame_id = "world"
        msg.pose.position.x, msg.pose.position.z = 0.4, 0.3
        o = Rotation.from_euler("y", 5.0 * np.sin(2 * np.pi * 0.2 * t), degrees=True).as_quat()
        msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z, msg.pose.orientation.w = o
        pub.publish(msg)
        if time.perf_counter() - start > warmup:
            pose_stamps.append(t)
        k += 1
    end = time.time() + 0.5
    while time.time() < end:
        rclpy.spin_once(node, timeout_sec=0.01)
    simulator.terminate()
    simulator.wait()

    received = np.array(wrenches)
    order = np.argsort(received[:, 1])
    stamps, arrivals = received[order, 1], received[order, 0]
    index = np.searchsorted(stamps, pose_stamps)
    valid = index < len(stamps)
    first_arrival = np.minimum.accumulate(arrivals[::-1])[::-1]  # earliest arrival among stamps >= pose stamp
    latency = (first_arrival[index[valid]] - np.array(pose_stamps)[valid]) * 1e3
    steps = [int(d["steps"]) for d in diagnostics if "steps" in d]
    misses = [int(d["deadline_misses"]) for d in diagnostics if "deadline_misses" in d]
    step_mean = [float(d["step_time_mean_ms"]) for d in diagnostics if "step_time_mean_ms" in d]
    miss_rate = (misses[-1] - misses[0]) / max(steps[-1] - steps[0], 1) if len(steps) > 1 else float("nan")

    print(f"\nneedle_simulator, {args.elements} elements, dt = 1 ms, poses at {args.rate:g} Hz, {args.duration:g} s")
    print("| metric | value | target |")
    print("|---|---|---|")
    print(f"| latency p50 | {np.percentile(latency, 50):.3f} ms | |")
    print(f"| latency p99 | {np.percentile(latency, 99):.3f} ms | < 2 ms |")
    print(f"| latency max | {latency.max():.3f} ms | |")
    print(f"| wrench messages received | {len(wrenches)} | |")
    print(f"| deadline misses | {100 * miss_rate:.3f} % | < 1 % |")
    print(f"| mean step time (node) | {np.mean(step_mean[1:]) if len(step_mean) > 1 else float('nan'):.3f} ms | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
