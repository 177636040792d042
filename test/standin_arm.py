"""A stand-in for a CRTK arm driver: publishes its measured pose (``measured_cp``) at 1 kHz and reads the force to
render (``servo_cf``) reliably, as a driver's servo_cf subscription does.

    python standin_arm.py NAMESPACE FRAME OUTPUT_JSON

SIGUSR1 toggles the pose stream (the arm goes silent / resumes); SIGTERM or SIGINT writes OUTPUT_JSON
({"wrenches": [[monotonic time, |force|, |torque|], ...], "events": [[monotonic time, "silent" | "resume"], ...]})
and exits. CLOCK_MONOTONIC is the same clock in every process of the machine: the test compares its own times.
"""
import json
import math
import signal
import sys
import threading
import time

import rclpy
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

RATE = 1000.0  # [Hz] a CRTK driver's measured_cp


def main() -> int:
    namespace, frame, output = sys.argv[1:4]
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("standin_arm", namespace=namespace)
    wrenches, events = [], []
    silent = threading.Event()
    done = threading.Event()

    def received(msg: WrenchStamped) -> None:
        f, t = msg.wrench.force, msg.wrench.torque
        wrenches.append([time.monotonic(), math.sqrt(f.x**2 + f.y**2 + f.z**2), math.sqrt(t.x**2 + t.y**2 + t.z**2)])

    node.create_subscription(WrenchStamped, "servo_cf", received,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    publisher = node.create_publisher(PoseStamped, "measured_cp", QoSProfile(depth=10))

    def toggle(*_) -> None:
        silent.clear() if silent.is_set() else silent.set()
        events.append([time.monotonic(), "silent" if silent.is_set() else "resume"])

    signal.signal(signal.SIGUSR1, toggle)
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())

    def stream() -> None:
        """The needle holder 0.3 m above the base, needle along x, swaying 5 mm at 0.5 Hz."""
        start = time.monotonic()
        k = 0
        while not done.is_set():
            k += 1
            time.sleep(max(0.0, start + k / RATE - time.monotonic()))
            if silent.is_set():
                continue
            msg = PoseStamped()
            msg.header.frame_id = frame
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.pose.position.x, msg.pose.position.z = 0.4, 0.3
            msg.pose.position.y = 0.005 * math.sin(math.pi * (time.monotonic() - start))
            msg.pose.orientation.w = 1.0
            publisher.publish(msg)

    thread = threading.Thread(target=stream, daemon=True)
    thread.start()
    try:
        while not done.is_set():
            rclpy.spin_once(node, timeout_sec=0.01)
    except ExternalShutdownException:
        pass
    thread.join(timeout=1.0)
    with open(output, "w") as stream_out:
        json.dump({"wrenches": wrenches, "events": events}, stream_out)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
