"""Main job (smoke stage): start an installed node in its own process and show its messages arriving here."""
import os
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from needle_interfaces.msg import NeedleShape

REPO = Path(__file__).resolve().parent.parent
EXECUTABLE = REPO / "install/needle_sim_ros/lib/needle_sim_ros/needle_talker_demo"  # where `ros2 run` looks


def main() -> int:
    env = dict(os.environ, ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", str(1 + os.getpid() % 100)))
    os.environ.update(ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"])
    print(f"[main] starting {EXECUTABLE.relative_to(REPO)} (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']})")
    talker = subprocess.Popen([str(EXECUTABLE)], env=env)
    rclpy.init()
    node = rclpy.create_node("main_job_listener")
    received = []
    node.create_subscription(NeedleShape, "needle/shape", received.append, 10)
    deadline = time.monotonic() + 20.0
    try:
        while len(received) < 10 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
            if received and len(received) != getattr(main, "_shown", 0):
                m = received[-1]
                print(f"[main] NeedleShape #{len(received)} from pid {talker.pid}: {len(m.points)} samples, "
                      f"tip x = {m.tip_pose.position.x:.3f} m, frame {m.header.frame_id}")
                main._shown = len(received)
    finally:
        talker.terminate()
        talker.wait()
        node.destroy_node()
        rclpy.shutdown()
    ok = len(received) >= 10
    print("[main] messages crossed the process boundary" if ok else "[main] no messages received", file=sys.stdout if ok else sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
