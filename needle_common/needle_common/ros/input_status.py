"""A node's input connections: how many publishers each input subscription has matched, on ``/diagnostics`` and on
the latched readiness topic (:data:`READINESS_TOPIC`), the start handshake that :class:`InputReports` reads
(``needle_replay --wait-for-subscribers``, ``--wait-for-nodes``, the main job). What a report holds and why (DDS
discovery is two-sided: only the subscriber knows that it has matched a publisher): README, "Input reports".
"""
from __future__ import annotations

from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from std_msgs.msg import Header

INPUT_STATUS_PERIOD = 0.5  # [s] of steady time between reports
OK, WARN = 0, 1  # diagnostic_msgs/DiagnosticStatus levels
ACCEPTING = "accepting"  # the report's key saying whether the node takes its input now
READINESS_TOPIC = "/needle_sim/readiness"  # diagnostic_msgs/DiagnosticArray, latched: the nodes' input reports
# Latched: each publisher keeps its last report for late readers; a reader keeps the reports of up to 100 nodes.
READINESS_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
READINESS_READER_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.TRANSIENT_LOCAL)


def fully_qualified_name(namespace: str, node_name: str) -> str:
    """A node's fully qualified name (``/robot1/needle_simulator``; ``/needle_simulator`` in the root namespace)."""
    return f"{namespace.rstrip('/')}/{node_name}"


def input_status_name(namespace: str, node_name: str) -> str:
    """The status name a node's input report has: its fully qualified name (nodes of one name in two namespaces,
    e.g. two robots, report apart)."""
    return f"{fully_qualified_name(namespace, node_name)}: inputs"


class InputStatus:
    """Reports the matched publishers of the subscriptions given to :meth:`track`, whether the node takes its
    input (``accepting()``, if given), and in the same array the node's ``more_statuses()`` (e.g. the stereo
    node's pair counts)."""

    def __init__(self, node: Node, more_statuses: Callable[[], list[DiagnosticStatus]] = list,
                 accepting: Callable[[], bool] | None = None) -> None:
        self._node = node
        self._more_statuses = more_statuses
        self._accepting = accepting
        self._subscriptions: list[Subscription] = []
        self._optional: set[str] = set()  # topics of the optional inputs
        self._publisher = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._readiness = node.create_publisher(DiagnosticArray, READINESS_TOPIC, READINESS_QOS)
        node.create_timer(INPUT_STATUS_PERIOD, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def track(self, *subscriptions: Subscription, optional: bool = False) -> None:
        """Report these subscriptions; ``optional``: one without a publisher is fine (OK, not WARN)."""
        self._subscriptions.extend(subscriptions)
        if optional:
            self._optional.update(s.topic_name for s in subscriptions)

    def counts(self) -> dict[str, int]:
        """Matched publishers per input topic (resolved name)."""
        return {s.topic_name: s.get_publisher_count() for s in self._subscriptions}

    def publish(self) -> None:
        counts = self.counts()
        unconnected = [topic for topic, count in counts.items() if count == 0 and topic not in self._optional]
        accepting = self._accepting is None or self._accepting()
        message = f"no publisher on {', '.join(unconnected)}" if unconnected else "every input has a publisher"
        values = [KeyValue(key=topic, value=str(count)) for topic, count in counts.items()]
        if self._accepting is not None:
            values.append(KeyValue(key=ACCEPTING, value=str(accepting).lower()))
        status = DiagnosticStatus(level=bytes([WARN if unconnected else OK]), hardware_id="needle_sim",
                                  name=input_status_name(self._node.get_namespace(), self._node.get_name()),
                                  message=message if accepting else f"not taking input yet; {message}",
                                  values=values)
        header = Header(stamp=self._node.get_clock().now().to_msg())
        self._readiness.publish(DiagnosticArray(header=header, status=[status]))
        self._publisher.publish(DiagnosticArray(header=header, status=[status, *self._more_statuses()]))


REPORT_GRACE = 1.5  # [s] a subscriber without an input report this long after it appeared is taken to send none


class InputReports:
    """The reading side, for a player (``needle_replay --wait-for-subscribers``): which subscribers of the topics it
    is about to publish have not matched them yet by their own reports (on :data:`READINESS_TOPIC`). A subscriber
    that sends no report (not one
    of these nodes) counts as matched once the publisher sees it and :data:`REPORT_GRACE` has passed."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self._reports: dict[str, tuple[int, dict[str, str]]] = {}  # status name -> (node's clock [ns], values)
        self._first_seen: dict[str, float] = {}  # subscriber node -> steady time [s] it was first seen
        self._subscription = node.create_subscription(DiagnosticArray, READINESS_TOPIC, self._on_diagnostics,
                                                      READINESS_READER_QOS)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        clock_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for status in msg.status:
            self._reports[status.name] = (clock_ns, {kv.key: kv.value for kv in status.values})

    def waiting(self, topics: list[str], now: float, clock_ns: int | None = None) -> list[str]:
        """What a publisher of the (resolved) ``topics`` still waits for at steady time ``now`` [s]: a subscriber at
        all, a subscriber's report, its match, its taking input, and (``clock_ns``: the player's /clock) its clock at
        ``clock_ns``."""
        waiting = []
        for topic in topics:
            subscribers = self._node.get_subscriptions_info_by_topic(topic)
            if not subscribers:
                waiting.append(f"{topic}: no subscriber")
            for info in subscribers:
                name = fully_qualified_name(info.node_namespace, info.node_name)
                status_name = input_status_name(info.node_namespace, info.node_name)
                seen = self._first_seen.setdefault(name, now)
                report = self._reports.get(status_name)
                if report is None:
                    if now - seen < REPORT_GRACE:
                        waiting.append(f"{topic}: no input report from {name} yet")
                elif report[1].get(topic) == "0":
                    waiting.append(f"{topic}: {name} has not matched a publisher")
                elif report[1].get(ACCEPTING) == "false":
                    waiting.append(f"{topic}: {name} is not taking input yet")
                elif clock_ns is not None and report[0] < clock_ns:
                    waiting.append(f"{topic}: {name} has not received /clock")
        return waiting

    def waiting_for(self, nodes: list[str], topics: list[str], clock_ns: int | None = None) -> list[str]:
        """What a publisher of the (resolved) ``topics`` still waits for from the named nodes (fully qualified names,
        e.g. ``/needle_simulator``): each one's input report, a match of each of its inputs among ``topics`` and of
        its other inputs that have a publisher in the graph (the comparison's ``/wrench`` from the simulator: what
        comes before the match is missing from its log), its taking input, and (``clock_ns``: the player's /clock)
        its clock at ``clock_ns``. A topic none of them subscribes to (a bag's ground truth) holds nothing, whoever
        else subscribes to it; nor does an input nobody publishes."""
        waiting = []
        for name in nodes:
            report = self._reports.get(f"{name}: inputs")
            if report is None:
                waiting.append(f"no input report from {name} yet")
                continue
            node_clock_ns, counts = report
            waiting.extend(f"{topic}: {name} has not matched a publisher" for topic, count in counts.items()
                           if count == "0" and (topic in topics or self._node.count_publishers(topic) > 0))
            if counts.get(ACCEPTING) == "false":
                waiting.append(f"{name} is not taking input yet")
            if clock_ns is not None and node_clock_ns < clock_ns:
                waiting.append(f"{name} has not received /clock")
        return waiting

    def close(self) -> None:
        self._node.destroy_subscription(self._subscription)
