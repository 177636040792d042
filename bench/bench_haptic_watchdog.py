"""Time to zero of `needle_simulator`'s haptic watchdog (issue 37 benchmark).

Starts the simulator in its own process (10 elements, dt = 1 ms, wall-clock time, ``haptics.enable``), and from this
process plays a stand-in arm: base poses at 1 kHz for ``--on`` seconds, then silence for ``--off`` seconds, over and
over, while reading ``haptic/wrench`` reliably (as a CRTK driver's ``servo_cf`` subscription does). Per dropout:

* time to zero: from sending the last pose to the middleware's reception (``received_timestamp``) in this process of
  the first zero haptic wrench after it (the node's watchdog: ``haptics.pose_timeout``, 20 ms by default, plus the
  tick that notices it and the transport);
* non-zero wrenches received later than ``pose_timeout`` + ``--grace`` after the last pose (should be none).

Usage: python bench/bench_haptic_watchdog.py [--dropouts 150] [--on 0.3] [--off 0.1] [--param NAME=VALUE ...]
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
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from needle_sim_ros.nodes.polling import MessageWaiter, PolledCallbackGroup, drain

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dropouts", type=int, default=150, help="number of silences measured (>= 100 for a p99)")
    parser.add_argument("--on", type=float, default=0.3, help="streaming time before each silence [s]")
    parser.add_argument("--off", type=float, default=0.1, help="silence [s]")
    parser.add_argument("--grace", type=float, default=0.002,
                        help="non-zero wrenches received later than pose_timeout + this after the last pose count as "
                             "violations [s]")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="another needle_simulator parameter (YAML value), e.g. haptics.pose_timeout=0.01")
    args = parser.parse_args()

    env = dict(os.environ, ROS_DOMAIN_ID=str(1 + os.getpid() % 100), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"], ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    overrides = {"needle.elements": 10, "integrator.dt": 0.001, "haptics.enable": True, "haptics.resume_ramp": 0.05}
    for assignment in args.param:
        name, separator, value = assignment.partition("=")
        if not separator:
            parser.error(f"--param {assignment!r}: expected NAME=VALUE")
        overrides[name] = yaml.safe_load(value)
    timeout = overrides.get("haptics.pose_timeout", 0.02)
    params = Path(tempfile.mkdtemp()) / "watchdog.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": overrides}}))
    executable = REPO / "install/needle_sim_ros/lib/needle_sim_ros/needle_simulator"
    load_before = os.getloadavg()[0]
    simulator = subprocess.Popen([str(executable), "--ros-args", "--params-file", str(params)], env=env)

    rclpy.init()
    node = rclpy.create_node("watchdog_bench")
    pub = node.create_publisher(PoseStamped, "base_pose", 10)
    received: list[tuple[float, bool]] = []  # (middleware receive time [s], non-zero) of every haptic wrench

    def on_haptic(data: bytes, info) -> None:
        received.append((info["received_timestamp"] * 1e-9, any(struct.unpack_from("<6d", data, len(data) - 48))))

    haptic = node.create_subscription(WrenchStamped, "haptic/wrench", on_haptic,
                                      QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE), raw=True,
                                      callback_group=PolledCallbackGroup())
    receiving = threading.Event()
    receiving.set()

    def receive() -> None:
        waiter = MessageWaiter([haptic], node.context)
        while receiving.is_set():
            if waiter.wait(0.05):
                drain(haptic)
        waiter.close()

    receiver = threading.Thread(target=receive, daemon=True)
    receiver.start()

    def stop() -> None:
        receiving.clear()
        receiver.join()
        node.destroy_node()
        rclpy.shutdown()
        simulator.terminate()
        simulator.wait()

    while pub.get_subscription_count() == 0 or haptic.get_publisher_count() == 0:
        if simulator.poll() is not None:
            print(f"error: the simulator exited with status {simulator.returncode} before subscribing",
                  file=sys.stderr)
            stop()
            return 2
        time.sleep(0.1)

    template = bytearray(serialize_message(PoseStamped(header=Header(frame_id="world"))))
    pose_offset = len(template) - 56

    def stream(seconds: float) -> float:
        """Poses at 1 kHz for ``seconds``; the send time (= stamp, time.time()) of the last one."""
        start = time.perf_counter()
        k, sent = 0, 0.0
        while time.perf_counter() - start < seconds:
            remaining = start + k * 1e-3 - time.perf_counter()
            if remaining > 0:
                time.sleep(remaining)
            sent = time.time()
            sec = math.floor(sent)
            struct.pack_into("<iI", template, 4, sec, min(round((sent - sec) * 1e9), 999_999_999))
            struct.pack_into("<7d", template, pose_offset, 0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0)
            pub.publish(bytes(template))
            k += 1
        return sent

    stream(3.0)  # first pose, kernels warm, ramp done
    last_poses = []
    for _ in range(args.dropouts):
        last_poses.append(stream(args.on))
        time.sleep(args.off)
    time.sleep(0.2)
    stop()

    arrivals = np.array(received)
    times_to_zero, violations, skipped = [], 0, 0
    for last in last_poses:
        window = arrivals[(arrivals[:, 0] > last) & (arrivals[:, 0] < last + args.off)]
        before = arrivals[(arrivals[:, 0] > last - 0.05) & (arrivals[:, 0] <= last)]
        if not before[:, 1].any():  # nothing rendered before this silence: no transition to time
            skipped += 1
            continue
        zeros = window[window[:, 1] == 0.0]
        if not zeros.size:
            violations += 1
            continue
        times_to_zero.append(zeros[0, 0] - last)
        violations += int(np.count_nonzero(window[(window[:, 0] > last + timeout + args.grace), 1]))
    ttz = np.array(times_to_zero) * 1e3
    print(f"\nneedle_simulator haptic watchdog, haptics.pose_timeout {timeout * 1e3:g} ms, {args.dropouts} dropouts "
          f"({args.on:g} s of poses at 1 kHz, {args.off:g} s of silence); load average (1 min) {load_before:.2f} "
          f"before, {os.getloadavg()[0]:.2f} after")
    print("| metric | value |")
    print("|---|---|")
    print(f"| dropouts timed | {ttz.size} (skipped, nothing rendered before: {skipped}) |")
    print(f"| time to zero p50 | {np.percentile(ttz, 50):.2f} ms |")
    print(f"| time to zero p99 | {np.percentile(ttz, 99):.2f} ms |")
    print(f"| time to zero max | {ttz.max():.2f} ms |")
    print(f"| time to zero beyond pose_timeout p99 | {np.percentile(ttz, 99) - timeout * 1e3:.2f} ms |")
    print(f"| non-zero wrenches later than pose_timeout + {args.grace * 1e3:g} ms | {violations} |")
    print(f"| haptic messages received | {len(received)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
