"""InputReports: what a player still waits for, from the subscribers' own input reports (no ROS graph: a stand-in
node with the graph query and the readiness subscription)."""
from types import SimpleNamespace

import pytest

pytest.importorskip("rclpy", reason="the input reports are ROS messages (diagnostic_msgs)")
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402

from needle_common.ros.input_status import READINESS_TOPIC, REPORT_GRACE, InputReports  # noqa: E402

START_NS = 1_700_000_000_000_000_000


class GraphStandIn:
    """What InputReports asks of its node: the subscribers and publisher count of a topic, and the readiness
    callback."""

    def __init__(self, subscribers: dict[str, list[str]], publishers: dict[str, int] | None = None) -> None:
        self.subscribers = subscribers
        self.publishers = publishers or {}
        self.deliver = None

    def count_publishers(self, topic: str) -> int:
        return self.publishers.get(topic, 0)

    def create_subscription(self, _type, topic, callback, _qos):
        assert topic == READINESS_TOPIC
        self.deliver = callback
        return object()

    def get_subscriptions_info_by_topic(self, topic: str) -> list:
        return [SimpleNamespace(node_namespace=name.rsplit("/", 1)[0] or "/", node_name=name.rsplit("/", 1)[1])
                for name in self.subscribers.get(topic, [])]


def report(node: str, clock_ns: int, counts: dict[str, int]) -> DiagnosticArray:
    msg = DiagnosticArray(status=[DiagnosticStatus(name=f"{node}: inputs", values=[
        KeyValue(key=topic, value=str(count)) for topic, count in counts.items()])])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(clock_ns, 1_000_000_000)
    return msg


def test_a_player_waits_for_each_reporting_subscriber_to_match_and_follow_the_clock():
    graph = GraphStandIn({"/base_pose": ["/needle_simulator", "/rviz"], "/tip_load": ["/needle_simulator"]})
    reports = InputReports(graph)
    topics = ["/base_pose", "/tip_load", "/images"]
    waiting = reports.waiting(topics, now=0.0, clock_ns=START_NS)
    assert "/images: no subscriber" in waiting
    assert "/base_pose: no input report from /needle_simulator yet" in waiting
    assert "/base_pose: no input report from /rviz yet" in waiting
    # a node of the same name in another namespace (another robot) is another subscriber, with its own report
    graph.subscribers["/images"] = ["/needle_stereo", "/robot2/needle_stereo"]
    graph.deliver(report("/needle_simulator", 0, {"/base_pose": 0, "/tip_load": 1}))
    graph.deliver(report("/needle_stereo", START_NS, {"/images": 1}))
    graph.deliver(report("/robot2/needle_stereo", START_NS, {"/images": 0}))
    assert "/images: /robot2/needle_stereo has not matched a publisher" in reports.waiting(topics, 0.1, START_NS)
    graph.deliver(report("/robot2/needle_stereo", START_NS, {"/images": 1}))
    waiting = reports.waiting(topics, now=REPORT_GRACE + 0.1, clock_ns=START_NS)
    # rviz sends no report: after the grace its subscription (seen by the publisher) is taken as matched
    assert waiting == ["/base_pose: /needle_simulator has not matched a publisher",
                       "/tip_load: /needle_simulator has not received /clock"]
    graph.deliver(report("/needle_simulator", START_NS, {"/base_pose": 1, "/tip_load": 1}))
    assert reports.waiting(topics, now=REPORT_GRACE + 0.2, clock_ns=START_NS) == []
    # without a played /clock the stamps do not matter
    graph.deliver(report("/needle_simulator", 0, {"/base_pose": 1, "/tip_load": 1}))
    assert reports.waiting(topics, now=REPORT_GRACE + 0.3) == []


def test_a_player_waiting_for_named_nodes_waits_for_their_inputs_only():
    """--wait-for-nodes: each named node's report, a match of each played topic it reads, its clock; a topic no named
    node reads (a bag's ground truth) holds nothing, whoever else subscribes to it (or nobody)."""
    graph = GraphStandIn({"/base_pose": ["/needle_simulator"], "/ground_truth/shape": ["/rviz"]})
    reports = InputReports(graph)
    topics = ["/base_pose", "/ground_truth/shape", "/ground_truth/wrench"]
    nodes = ["/needle_simulator", "/robot2/needle_compare"]
    assert reports.waiting_for(nodes, topics, START_NS) == ["no input report from /needle_simulator yet",
                                                           "no input report from /robot2/needle_compare yet"]
    graph.deliver(report("/needle_simulator", START_NS, {"/base_pose": 0, "/tip_load": 0}))
    graph.deliver(report("/robot2/needle_compare", 0, {"/base_pose": 1, "/robot2/needle/shape": 0}))
    assert reports.waiting_for(nodes, topics, START_NS) == ["/base_pose: /needle_simulator has not matched a publisher",
                                                           "/robot2/needle_compare has not received /clock"]
    graph.deliver(report("/needle_simulator", START_NS, {"/base_pose": 1, "/tip_load": 0}))
    graph.deliver(report("/robot2/needle_compare", START_NS, {"/base_pose": 1, "/robot2/needle/shape": 0}))
    assert reports.waiting_for(nodes, topics, START_NS) == []  # the unplayed /tip_load and needle/shape hold nothing
    assert reports.waiting_for(nodes, topics) == []


def test_a_named_node_is_waited_for_until_it_matched_every_input_someone_publishes():
    """--wait-for-nodes: an input of a named node that is not played but published by another node (the comparison's
    /wrench and /needle/shape from the simulator) holds the player until the node has matched it from its side: what
    the simulator publishes before that is missing from the comparison's log."""
    graph = GraphStandIn({"/base_pose": ["/needle_compare"]}, publishers={"/wrench": 1, "/needle/shape": 1})
    reports = InputReports(graph)
    graph.deliver(report("/needle_compare", START_NS, {"/needle/shape": 0, "/base_pose": 1, "/wrench": 0,
                                                       "/needle/measured_shape": 0}))
    assert reports.waiting_for(["/needle_compare"], ["/base_pose"], START_NS) == [
        "/needle/shape: /needle_compare has not matched a publisher",
        "/wrench: /needle_compare has not matched a publisher"]  # not /needle/measured_shape: nobody publishes it
    graph.deliver(report("/needle_compare", START_NS, {"/needle/shape": 1, "/base_pose": 1, "/wrench": 1,
                                                       "/needle/measured_shape": 0}))
    assert reports.waiting_for(["/needle_compare"], ["/base_pose"], START_NS) == []


def test_a_node_not_taking_input_holds_the_player():
    """A report with accepting = false (the simulator before its lifecycle state is active: it drops its input)
    holds both kinds of wait, however matched its inputs are."""
    graph = GraphStandIn({"/base_pose": ["/needle_simulator"]})
    reports = InputReports(graph)
    graph.deliver(report("/needle_simulator", START_NS, {"/base_pose": 1, "accepting": "false"}))
    assert reports.waiting(["/base_pose"], 0.0, START_NS) == ["/base_pose: /needle_simulator is not taking input yet"]
    assert reports.waiting_for(["/needle_simulator"], ["/base_pose"], START_NS) == [
        "/needle_simulator is not taking input yet"]
    graph.deliver(report("/needle_simulator", START_NS, {"/base_pose": 1, "accepting": "true"}))
    assert reports.waiting(["/base_pose"], 0.0, START_NS) == []
    assert reports.waiting_for(["/needle_simulator"], ["/base_pose"], START_NS) == []
