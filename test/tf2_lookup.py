"""Looks transforms up the way a stock ROS 2 user does: a tf2_ros.Buffer filled by a tf2_ros.TransformListener.

    python tf2_lookup.py SECONDS PARENT CHILD [CHILD ...]

Prints one JSON line {child: {"translation": [...], "rotation": [...]}, ...} of the first successful lookup of each
PARENT -> CHILD (latest available) within SECONDS, and exits 0 if every one succeeded, 1 otherwise.
"""
import json
import sys
import time

import rclpy
from rclpy.time import Time
from tf2_ros import Buffer, TransformException, TransformListener


def main() -> int:
    seconds, parent, children = float(sys.argv[1]), sys.argv[2], sys.argv[3:]
    rclpy.init()
    node = rclpy.create_node("tf2_lookup")
    buffer = Buffer()
    TransformListener(buffer, node)
    found, errors = {}, {}
    end = time.monotonic() + seconds
    while len(found) < len(children) and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
        for child in set(children) - set(found):
            try:
                t = buffer.lookup_transform(parent, child, Time()).transform
            except TransformException as error:
                errors[child] = str(error)
                continue
            found[child] = {"translation": [t.translation.x, t.translation.y, t.translation.z],
                            "rotation": [t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]}
    print(json.dumps({"found": found, "errors": {c: e for c, e in errors.items() if c not in found}}), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0 if len(found) == len(children) else 1


if __name__ == "__main__":
    sys.exit(main())
