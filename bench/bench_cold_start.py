"""Cold start of `needle_simulator` (issue #12): process start to the first wrench, and what the time is made of.

"First message": the bench publishes base poses at 1 kHz (stamped now, world frame) from before the simulator
process is started; the first message is the first ``wrench`` (base wrench) the bench receives. Times are from
the start of the simulator process (``subprocess.Popen``, default configuration: 10 elements, dt = 1 ms, autostart):

* time to active: the node's ``get_state`` service first answers ``active`` (polled every 10 ms);
* time to first wrench: the first ``wrench`` message received;
* kernels: the time the node reports for compiling/loading its numba kernels (its log line);
* imports: a separate process importing, in this order, numpy, numba, scipy, rclpy and the node module
  (``needle_sim_ros.nodes.simulator_node``, i.e. the rest of the package), each timed.

Rows: "first start" is the first start on the kernel cache as the installation left it — run the bench right after
``source scripts/setup_env.sh`` on a fresh clone, before anything else has started the simulator, to measure a
fresh install; "warm" is the median of ``--starts`` later starts; ``--empty-cache`` adds a start with an empty
numba cache (a fresh install without the build-time compilation: minutes).

Usage: python bench/bench_cold_start.py [--starts 3] [--empty-cache] [--timeout 600]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
EXECUTABLE = Path(os.environ.get("NEEDLE_INSTALL", REPO / "install")) / "needle_sim_ros/lib/needle_sim_ros" \
    / "needle_simulator"
IMPORT_PROBE = """
import json, time
times, start = {}, time.perf_counter()
for name in ("numpy", "numba", "scipy.spatial.transform", "rclpy.lifecycle", "needle_sim_ros.nodes.simulator_node"):
    t = time.perf_counter()
    __import__(name)
    times[name] = time.perf_counter() - t
times["total"] = time.perf_counter() - start
print(json.dumps(times))
"""
KERNEL_LOG = re.compile(r"compiled/loaded the numerical kernels in ([0-9.]+) s")


def import_times(env: dict) -> dict:
    """Import times [s] of the heavy modules in a fresh interpreter (median of three)."""
    runs = [json.loads(subprocess.run([sys.executable, "-c", IMPORT_PROBE], env=env, check=True,
                                      capture_output=True, text=True).stdout) for _ in range(3)]
    return {key: float(np.median([run[key] for run in runs])) for key in runs[0]}


class Probe:
    """This process's ROS side: base poses at 1 kHz, the first wrench, the simulator's lifecycle state."""

    def __init__(self) -> None:
        import rclpy
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from lifecycle_msgs.srv import GetState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data
        from rclpy.serialization import serialize_message
        from std_msgs.msg import Header

        rclpy.init()
        self.node = rclpy.create_node("cold_start_bench")
        self.publisher = self.node.create_publisher(PoseStamped, "base_pose", 10)
        self.first_wrench: float | None = None
        self.node.create_subscription(WrenchStamped, "wrench", self._on_wrench, qos_profile_sensor_data, raw=True)
        self.get_state = self.node.create_client(GetState, "/needle_simulator/get_state")
        self.request = GetState.Request()
        self.template = bytearray(serialize_message(PoseStamped(header=Header(frame_id="world"))))
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        threading.Thread(target=self.executor.spin, daemon=True).start()

    def _on_wrench(self, data: bytes) -> None:
        if self.first_wrench is None:
            self.first_wrench = time.perf_counter()

    def publish_pose(self) -> None:
        t = time.time()
        sec = int(t)
        struct.pack_into("<iI", self.template, 4, sec, min(round((t - sec) * 1e9), 999_999_999))
        struct.pack_into("<7d", self.template, len(self.template) - 56, 0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0)
        self.publisher.publish(bytes(self.template))

    def active(self) -> bool:
        if not self.get_state.service_is_ready():
            return False
        future = self.get_state.call_async(self.request)
        deadline = time.perf_counter() + 0.5
        while not future.done() and time.perf_counter() < deadline:
            time.sleep(0.001)
        return future.done() and future.result() is not None and future.result().current_state.label == "active"

    def start(self, env: dict, timeout: float) -> dict:
        """Start the simulator, publish poses until the first wrench; times [s] from the process start."""
        self.first_wrench = None
        log = tempfile.TemporaryFile(mode="w+")
        start = time.perf_counter()
        simulator = subprocess.Popen([str(EXECUTABLE)], env=env, stdout=log, stderr=subprocess.STDOUT)
        active_at = None
        next_poll = start
        try:
            while self.first_wrench is None:
                now = time.perf_counter()
                if now - start > timeout or simulator.poll() is not None:
                    raise RuntimeError(f"no wrench after {now - start:.0f} s (simulator exit code {simulator.poll()})")
                self.publish_pose()
                if active_at is None and now >= next_poll:
                    next_poll = now + 0.01
                    if self.active():
                        active_at = time.perf_counter()
                time.sleep(max(0.0, now + 0.001 - time.perf_counter()))
        finally:
            simulator.terminate()
            simulator.wait()
        log.seek(0)
        kernels = KERNEL_LOG.search(log.read())
        return {"active": (active_at or self.first_wrench) - start, "wrench": self.first_wrench - start,
                "kernels": float(kernels.group(1)) if kernels else float("nan")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--starts", type=int, default=3, help="warm starts (median reported)")
    parser.add_argument("--empty-cache", action="store_true", help="also start once with an empty numba cache")
    parser.add_argument("--timeout", type=float, default=600.0, help="give up on a start after this long [s]")
    args = parser.parse_args()
    if not EXECUTABLE.exists():
        print(f"error: {EXECUTABLE} not found: source scripts/setup_env.sh first", file=sys.stderr)
        return 2
    os.environ.update(ROS_DOMAIN_ID=str(1 + os.getpid() % 100), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env = dict(os.environ)
    probe = Probe()
    time.sleep(2.0)  # this process's DDS participant settles first: not charged to the simulator's first start
    rows = [("first start", probe.start(env, args.timeout))]
    warm = [probe.start(env, args.timeout) for _ in range(args.starts)]
    rows.append((f"warm (median of {args.starts})", {k: float(np.median([w[k] for w in warm])) for k in warm[0]}))
    if args.empty_cache:
        with tempfile.TemporaryDirectory() as cache:
            rows.append(("empty numba cache", probe.start(dict(env, NUMBA_CACHE_DIR=cache), args.timeout)))
    imports = import_times(env)
    print(f"\nneedle_simulator cold start (load average {os.getloadavg()[0]:.2f}; "
          f"NUMBA_CACHE_DIR={env.get('NUMBA_CACHE_DIR', '(unset: __pycache__ next to the sources)')})")
    print("| start | kernels compile/load [s] | time to active [s] | time to first wrench [s] |")
    print("|---|---|---|---|")
    for name, row in rows:
        print(f"| {name} | {row['kernels']:.2f} | {row['active']:.2f} | {row['wrench']:.2f} |")
    print("\n| import (fresh interpreter, median of 3) | time [s] |")
    print("|---|---|")
    for name, seconds in imports.items():
        print(f"| {name} | {seconds:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
