"""A node's input connections on ``/diagnostics``: how many publishers each input subscription has matched.

DDS discovery is two-sided: a publisher can see a subscription (``get_subscription_count``) before the
subscription has matched the publisher, and what it publishes in between never arrives. Only the subscribing node
knows its side, so each node reports it, twice a second of steady time (also while a simulated clock stands still):
a ``DiagnosticStatus`` named ``<node>: inputs`` whose values are the resolved input topics with their matched
publisher counts, WARN while one has none. The header stamp is the node's clock (with ``use_sim_time``: zero until
its first ``/clock``), so a player can also tell that the node follows its clock (``scripts/main_job.py``).
"""
from __future__ import annotations

from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.subscription import Subscription
from std_msgs.msg import Header

INPUT_STATUS_PERIOD = 0.5  # [s] of steady time between reports
OK, WARN = 0, 1  # diagnostic_msgs/DiagnosticStatus levels


def input_status_name(node_name: str) -> str:
    """The status name a node's input report has."""
    return f"{node_name}: inputs"


class InputStatus:
    """Reports the matched publishers of the subscriptions given to :meth:`track`, and in the same array the
    node's ``more_statuses()`` (e.g. the stereo node's pair counts)."""

    def __init__(self, node: Node, more_statuses: Callable[[], list[DiagnosticStatus]] = list) -> None:
        self._node = node
        self._more_statuses = more_statuses
        self._subscriptions: list[Subscription] = []
        self._publisher = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        node.create_timer(INPUT_STATUS_PERIOD, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def track(self, *subscriptions: Subscription) -> None:
        self._subscriptions.extend(subscriptions)

    def counts(self) -> dict[str, int]:
        """Matched publishers per input topic (resolved name)."""
        return {s.topic_name: s.get_publisher_count() for s in self._subscriptions}

    def publish(self) -> None:
        counts = self.counts()
        unconnected = [topic for topic, count in counts.items() if count == 0]
        status = DiagnosticStatus(level=bytes([WARN if unconnected else OK]), hardware_id="needle_sim",
                                  name=input_status_name(self._node.get_name()),
                                  message=f"no publisher on {', '.join(unconnected)}" if unconnected else
                                  "every input has a publisher",
                                  values=[KeyValue(key=topic, value=str(count)) for topic, count in counts.items()])
        self._publisher.publish(DiagnosticArray(header=Header(stamp=self._node.get_clock().now().to_msg()),
                                                status=[status, *self._more_statuses()]))
