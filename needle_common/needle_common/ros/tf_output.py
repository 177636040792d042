"""Transforms on ``/tf`` and ``/tf_static`` for a node, with tf2_ros where it is installed.

On a ROS 2 install the broadcasters of ``tf2_ros`` publish. Without them (``tf2_ros`` has no PyPI wheel) the node
publishes ``tf2_msgs/msg/TFMessage`` itself with tf2's QoS: ``/tf`` reliable, volatile, depth 100; ``/tf_static``
reliable, transient local, depth 1, one message holding every static transform of the node. Without
``tf2_msgs`` either, the node logs one warning and runs without TF.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


def transform_stamped(stamp, parent: str, child: str, translation: Sequence[float],
                      quaternion: Sequence[float]) -> TransformStamped:
    """Pose of ``child`` in ``parent`` (translation [m], quaternion x, y, z, w) at ``stamp`` (builtin Time)."""
    msg = TransformStamped()
    msg.header.stamp, msg.header.frame_id, msg.child_frame_id = stamp, parent, child
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = (float(v) for v in translation)
    r.x, r.y, r.z, r.w = (float(v) for v in np.asarray(quaternion, dtype=float) / np.linalg.norm(quaternion))
    return msg


class TfOutput:
    """``send`` publishes dynamic transforms, ``send_static`` adds static ones (latched, replacing a previous
    transform of the same child frame). ``backend`` is ``'tf2_ros'``, ``'tf2_msgs'`` or ``None`` (no TF)."""

    def __init__(self, node: Node) -> None:
        self._static: dict[str, TransformStamped] = {}
        self.backend: str | None = None
        try:
            from tf2_ros import StaticTransformBroadcaster, TransformBroadcaster
            self._dynamic, self._static_broadcaster = TransformBroadcaster(node), StaticTransformBroadcaster(node)
            self.backend = "tf2_ros"
            return
        except ImportError:
            pass
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            node.get_logger().warning("neither tf2_ros nor tf2_msgs is installed: running without TF "
                                      "(install ros-jazzy-tf2-ros to get /tf and /tf_static)")
            return
        self._message = TFMessage
        self._tf_pub = node.create_publisher(TFMessage, TF_TOPIC, TF_QOS)
        self._tf_static_pub = node.create_publisher(TFMessage, TF_STATIC_TOPIC, TF_STATIC_QOS)
        self.backend = "tf2_msgs"

    def has_subscribers(self) -> bool:
        """Whether anything subscribes to ``/tf`` (tf2_ros's broadcaster: through its publisher ``pub_tf``; true if
        a version without it cannot tell)."""
        if self.backend == "tf2_ros":
            publisher = getattr(self._dynamic, "pub_tf", None)
            return publisher is None or publisher.get_subscription_count() > 0
        return self.backend == "tf2_msgs" and self._tf_pub.get_subscription_count() > 0

    def send(self, transforms: list[TransformStamped]) -> None:
        if self.backend == "tf2_ros":
            self._dynamic.sendTransform(transforms)
        elif self.backend == "tf2_msgs":
            self._tf_pub.publish(self._message(transforms=transforms))

    def send_static(self, transforms: list[TransformStamped]) -> None:
        if self.backend == "tf2_ros":
            self._static_broadcaster.sendTransform(transforms)
        elif self.backend == "tf2_msgs":
            self._static.update({t.child_frame_id: t for t in transforms})
            self._tf_static_pub.publish(self._message(transforms=list(self._static.values())))
