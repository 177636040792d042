"""ROS side of the MCAP recording core: type names, QoS conversion, and a node's topic recorder.

rosbag2 records for each topic the QoS profiles offered by its publishers (queried from the graph, as here) and
plays back with a profile adapted from them (:func:`playback_qos`).
"""
from __future__ import annotations

import importlib
from typing import Any, Sequence

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.serialization import serialize_message

from needle_common.qos import OfferedQos
from needle_sim_ros.recording import McapBagWriter, RecordingError, WriterOptions

_DEFAULT_DEPTH = 10


def type_name_of(message_class: type) -> str:
    """``geometry_msgs.msg.PoseStamped`` -> ``'geometry_msgs/msg/PoseStamped'``."""
    package, namespace = message_class.__module__.split(".")[:2]
    return f"{package}/{namespace}/{message_class.__name__}"


def message_class(type_name: str) -> type:
    """Python class of a ``pkg/msg/Type`` name; raises ImportError/AttributeError if not installed."""
    package, namespace, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{namespace}"), name)


def offered_qos(profile: QoSProfile) -> OfferedQos:
    def policy(value: Any) -> str:
        return value.name.lower()

    return OfferedQos(history=policy(profile.history), depth=int(profile.depth),
                      reliability=policy(profile.reliability), durability=policy(profile.durability),
                      deadline_ns=profile.deadline.nanoseconds, lifespan_ns=profile.lifespan.nanoseconds,
                      liveliness=policy(profile.liveliness),
                      liveliness_lease_duration_ns=profile.liveliness_lease_duration.nanoseconds,
                      avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


def playback_qos(recorded: Sequence[OfferedQos]) -> QoSProfile:
    """Publisher QoS for playback: the recorded offer if all publishers agreed on the policies that decide
    compatibility (reliability, durability, deadline, liveliness), else the default (reliable, volatile)."""
    def enum(kind: type, name: str):
        return kind.__members__.get(name.upper(), kind.SYSTEM_DEFAULT)

    def compatibility(q: OfferedQos) -> tuple:
        return q.reliability, q.durability, q.deadline_ns, q.liveliness, q.liveliness_lease_duration_ns

    if not recorded or len({compatibility(q) for q in recorded}) != 1:
        return QoSProfile(depth=_DEFAULT_DEPTH)
    first = recorded[0]
    depth = first.depth if first.history == "keep_last" and first.depth > 0 else _DEFAULT_DEPTH
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(depth, _DEFAULT_DEPTH),
                      reliability=enum(ReliabilityPolicy, first.reliability),
                      durability=enum(DurabilityPolicy, first.durability),
                      deadline=Duration(nanoseconds=first.deadline_ns),
                      lifespan=Duration(nanoseconds=first.lifespan_ns),
                      liveliness=enum(LivelinessPolicy, first.liveliness),
                      liveliness_lease_duration=Duration(nanoseconds=first.liveliness_lease_duration_ns))


class TopicRecorder:
    """Records a node's messages into an MCAP file/bag; each topic is registered at its first message with the
    QoS its publishers offer. A write failure is logged once and stops the recording, never the node."""

    def __init__(self, node: Node, path: str, options: WriterOptions, custom_data: dict[str, str]) -> None:
        self._node = node
        self._writer: McapBagWriter | None = McapBagWriter(path, options, custom_data)  # RecordingError: caller
        self._registered: set[str] = set()
        self.failure: str | None = None  # why the recording stopped early (then close() cannot finalize it)
        self._stopped_files: list = []
        node.create_timer(max(options.chunk_interval, 0.1) if options.chunk_interval > 0 else 1.0,
                          lambda: self._guard(lambda w: w.flush_due(self._now())))

    def add_parameters(self, node_name: str, values: dict[str, Any], parameter_file: str) -> None:
        """Parameters in force: a metadata record (Foxglove) and a ROS 2 parameter file attachment."""
        self._guard(lambda w: w.add_metadata(f"{node_name}/parameters", {k: str(v) for k, v in values.items()}))
        self._guard(lambda w: w.add_attachment(f"{node_name}_parameters.yaml", "application/yaml",
                                               parameter_file.encode(), self._now()))

    def record(self, topic: str, message: Any, message_type: type, own_qos: QoSProfile | None = None) -> None:
        """Record a message (object or serialized bytes) of ``message_type`` on the resolved ``topic``."""
        if self._writer is None:
            return
        data = message if isinstance(message, bytes) else serialize_message(message)
        if topic not in self._registered:
            offers = [offered_qos(own_qos)] if own_qos is not None else [
                offered_qos(info.qos_profile) for info in self._node.get_publishers_info_by_topic(topic)]
            self._guard(lambda w: w.add_topic(topic, type_name_of(message_type), offers or [OfferedQos()]))
            self._registered.add(topic)
        self._guard(lambda w: w.write(topic, data, self._now()))

    def close(self) -> list:
        """Finalize; returns the files. ``failure`` says whether they are incomplete (stopped by an error)."""
        if self._writer is None:
            return self._stopped_files
        writer, self._writer = self._writer, None
        try:
            return writer.close()
        except RecordingError as error:
            self.failure = str(error)
            self._node.get_logger().error(f"recording not finalized: {error}; run needle_mcap_recover on it")
            return writer.files

    def _now(self) -> int:
        return self._node.get_clock().now().nanoseconds

    def _guard(self, action) -> None:
        if self._writer is None:
            return
        try:
            action(self._writer)
        except RecordingError as error:
            self._node.get_logger().error(f"recording stopped: {error}; the file keeps every complete chunk "
                                          "(needle_mcap_recover rebuilds its index)")
            writer, self._writer = self._writer, None
            self.failure = str(error)
            self._stopped_files = writer.close()
            self._node.get_logger().error(f"recording files: {', '.join(map(str, self._stopped_files))}")
