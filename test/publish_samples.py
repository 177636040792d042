"""Child process of test_middleware.py: publishes the sample messages, or a 1 kHz wrench stream."""
import argparse
import time

import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from message_samples import SAMPLES


def wait_for_subscribers(node, publishers, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while any(p.get_subscription_count() == 0 for p in publishers):
        if time.monotonic() > deadline:
            raise SystemExit("no subscriber matched")
        rclpy.spin_once(node, timeout_sec=0.05)


def publish_samples(node) -> None:
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {name: node.create_publisher(type(make()), f"sample/{name}", reliable) for name, make in SAMPLES.items()}
    wait_for_subscribers(node, pubs.values())
    for _ in range(50):  # repeat until the test process has seen every type (it stops us)
        for name, make in SAMPLES.items():
            pubs[name].publish(make())
        time.sleep(0.1)


def publish_wrench_stream(node, count: int, rate_hz: float) -> None:
    qos = QoSProfile(depth=count, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(WrenchStamped, "wrench_stream", qos)
    wait_for_subscribers(node, [pub])
    time.sleep(0.5)  # let discovery settle on both sides
    period = 1.0 / rate_hz
    start = time.perf_counter()
    for seq in range(count):
        while time.perf_counter() < start + seq * period:
            pass
        msg = WrenchStamped()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.wrench.force.x = float(seq)
        pub.publish(msg)
    elapsed = time.perf_counter() - start
    pub.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    print(f"published {count} in {elapsed:.3f} s", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("mode", choices=["samples", "wrench"])
    parser.add_argument("--count", type=int, default=3000)
    parser.add_argument("--rate", type=float, default=1000.0)
    args = parser.parse_args()
    rclpy.init()
    node = rclpy.create_node("sample_publisher")
    try:
        if args.mode == "samples":
            publish_samples(node)
        else:
            publish_wrench_stream(node, args.count, args.rate)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
