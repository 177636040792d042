"""Smoke-test talker: publishes a straight 0.27 m needle as NeedleShape at 10 Hz on `needle/shape`."""
import rclpy
from geometry_msgs.msg import Point, Vector3
from needle_interfaces.msg import NeedleShape
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


class SmokeTalker(Node):
    def __init__(self) -> None:
        super().__init__("needle_talker_demo")
        self.publisher = self.create_publisher(NeedleShape, "needle/shape", 10)
        self.create_timer(0.1, self.publish)

    def publish(self) -> None:
        msg = NeedleShape(source=NeedleShape.SOURCE_MODEL, length=0.27)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "needle_base"
        msg.points = [Point(x=0.027 * i) for i in range(11)]
        msg.tangents = [Vector3(x=1.0) for _ in range(11)]
        msg.arc_length = [0.027 * i for i in range(11)]
        msg.tip_pose.position.x = 0.27
        self.publisher.publish(msg)


def main() -> None:
    rclpy.init()
    node = SmokeTalker()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
