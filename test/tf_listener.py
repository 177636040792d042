"""Records /tf and /tf_static for some seconds and prints them as JSON (run with the test-only tf2_msgs).

    python tf_listener.py SECONDS
"""
import json
import sys
import time

import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage


def main() -> None:
    seconds = float(sys.argv[1])
    rclpy.init()
    node = rclpy.create_node("tf_test_listener")
    received = []

    def record(topic: str, msg: TFMessage) -> None:
        for t in msg.transforms:
            r, q = t.transform.translation, t.transform.rotation
            received.append({"topic": topic, "parent": t.header.frame_id, "child": t.child_frame_id,
                             "stamp": t.header.stamp.sec + 1e-9 * t.header.stamp.nanosec,
                             "translation": [r.x, r.y, r.z], "rotation": [q.x, q.y, q.z, q.w]})

    node.create_subscription(TFMessage, "/tf", lambda m: record("/tf", m), QoSProfile(depth=100))
    node.create_subscription(TFMessage, "/tf_static", lambda m: record("/tf_static", m),
                             QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    print("ready", flush=True)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps(received), flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
