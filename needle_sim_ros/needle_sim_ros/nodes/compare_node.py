"""needle_compare: model vs measured needle shape, published as ShapeError and logged to MCAP.

Pairs ``model/shape`` with ``measured/shape`` (NeedleShape) or ``measured/points`` (PointCloud2, float32 x, y, z) by
stamp, maps the measurement into the model frame and publishes ``shape_error``. With ``log.path`` it records the
shapes, errors, ``base_pose``, ``wrench`` and the parameters in force into an MCAP file, finalized on SIGINT/SIGTERM.
Core: :mod:`needle_sim_ros.comparison`; parameters: :mod:`needle_sim_ros.parameters.compare`.
"""
from __future__ import annotations

import json
import sys
import pathlib
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, WrenchStamped
from needle_interfaces.msg import NeedleShape, ShapeError
from rclpy.node import Node
from nav_msgs.msg import Path
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2, PointField
from visualization_msgs.msg import Marker

from needle_common.parameters import ParameterError, params_file_text

from needle_sim_ros.comparison import ComparedPair, ComparisonSession
from needle_sim_ros.messages.centerline_display import ComparisonDisplay
from needle_sim_ros.messages.shape import shape_arrays, shape_error_cdr, stamp_ns
from needle_common.ros.input_status import InputStatus
from needle_common.ros.ros_parameters import declare_all, qos_profile
from needle_sim_ros.nodes.recording_bridge import TopicRecorder
from needle_common.ros.runner import run_node
from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS, DISPLAY_TOPICS
from needle_sim_ros.recording import RecordingError, WriterOptions

NODE_NAME = "needle_compare"
WARN_PERIOD = 5.0  # [s] between repeated warnings about bad input
LOGGABLE = {"model/shape": NeedleShape, "measured/shape": NeedleShape, "measured/points": PointCloud2,
            "shape_error": ShapeError, "base_pose": PoseStamped, "wrench": WrenchStamped,
            **{topic: Path if topic.endswith("path") else Marker for topic in DISPLAY_TOPICS}}


def cloud_points(cloud: PointCloud2) -> np.ndarray:
    """Finite x, y, z points (n, 3) [m] of a PointCloud2 whose x, y, z fields are float32; raises ValueError."""
    fields = {f.name: f for f in cloud.fields}
    if any(name not in fields or fields[name].datatype != PointField.FLOAT32 for name in "xyz"):
        raise ValueError("PointCloud2 needs float32 fields x, y, z")
    width, height, step = int(cloud.width), int(cloud.height), int(cloud.point_step)
    if step < 12 or cloud.row_step < width * step or len(cloud.data) < height * cloud.row_step:
        raise ValueError("PointCloud2 data is shorter than width * height * point_step")
    dtype = np.dtype({"names": list("xyz"), "formats": [(">f4" if cloud.is_bigendian else "<f4")] * 3,
                      "offsets": [fields[n].offset for n in "xyz"], "itemsize": step})
    raw = np.frombuffer(bytes(cloud.data), dtype=np.uint8)[:height * cloud.row_step].reshape(height, cloud.row_step)
    rows = np.ascontiguousarray(raw[:, :width * step]).view(dtype).reshape(-1)
    points = np.column_stack([rows[n].astype(float) for n in "xyz"])
    return points[np.all(np.isfinite(points), axis=1)]


class CompareNode(Node):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.values = declare_all(self, COMPARE_PARAMETERS)
        v = self.values
        self.session = ComparisonSession(v, self.warn_rejected)
        self.error_qos = QoSProfile(depth=10)
        self.error_publisher = self.create_publisher(ShapeError, "shape_error", self.error_qos)
        self.recorder = self._open_recording() if v["log.path"] else None
        self.logged = {self.resolve_topic_name(t): t for t in v["log.topics"]} if self.recorder else {}

        self.display_publishers = {topic: self.create_publisher(LOGGABLE[topic], topic, 10) for topic in DISPLAY_TOPICS}
        self.displayer = ComparisonDisplay(v["display.rate"], v["display.tube_radius"], self.session.model_from_camera)
        if self.recorder is not None and v["log.tf"]:
            self._record_tf()
        inputs = InputStatus(self)
        # The inputs arrive serialized: the log holds the bytes received, not rclpy's re-serialization of them.
        inputs.track(self.create_subscription(NeedleShape, "model/shape", lambda data: self.on_shape(
            "model/shape", data, self.session.add_model), QoSProfile(depth=50), raw=True))
        if v["measured_input"] == "shape":
            inputs.track(self.create_subscription(NeedleShape, "measured/shape", lambda data: self.on_shape(
                "measured/shape", data, self.session.add_measurement), QoSProfile(depth=10), raw=True))
        else:
            inputs.track(self.create_subscription(PointCloud2, "measured/points", self.on_measured_points,
                                                  QoSProfile(depth=10), raw=True))
        input_qos = qos_profile(v["qos.inputs"], 100)
        for topic, message_type in (("base_pose", PoseStamped), ("wrench", WrenchStamped)):
            if self.resolve_topic_name(topic) in self.logged:
                inputs.track(self.create_subscription(message_type, topic,
                                                      lambda data, t=topic, m=message_type: self.log(t, data, m),
                                                      input_qos, raw=True))

    def _open_recording(self) -> TopicRecorder:
        v = self.values
        options = WriterOptions(**{name: v[f"log.{name}"] for name in (  # log.<name>: the writer option <name>
            "compression", "chunk_size", "chunk_interval", "max_file_size", "max_file_duration", "overwrite")})
        flat = {name: str(value) for name, value in v.items()}
        try:
            recorder = TopicRecorder(self, v["log.path"], options, custom_data={f"{NODE_NAME}.{k}": s
                                                                                  for k, s in flat.items()})
        except (RecordingError, ValueError) as error:
            raise ParameterError(f"parameter 'log.path' = '{v['log.path']}': {error}") from error
        recorder.add_parameters(NODE_NAME, flat, params_file_text({NODE_NAME: v}))
        self.get_logger().info(f"recording to {v['log.path']}")
        return recorder

    def _record_tf(self) -> None:
        """Record /tf and /tf_static (static transforms arrive latched: transient local)."""
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.get_logger().warning("log.tf: tf2_msgs is not installed, the recording has no /tf and /tf_static")
            return
        for topic, durability in (("/tf", DurabilityPolicy.VOLATILE), ("/tf_static", DurabilityPolicy.TRANSIENT_LOCAL)):
            self.logged[topic] = topic
            self.create_subscription(TFMessage, topic, lambda data, t=topic: self.log(t, data, TFMessage),
                                     QoSProfile(depth=100, durability=durability), raw=True)

    # --- input ------------------------------------------------------------------------------------------------
    def log(self, topic: str, message: Any, message_type: type, own_qos: QoSProfile | None = None) -> None:
        resolved = self.resolve_topic_name(topic)
        if resolved in self.logged:
            self.recorder.record(resolved, message, message_type, own_qos)

    def warn_rejected(self, what: str, reason: str) -> None:
        self.get_logger().warning(f"ignoring {what}: {reason}", throttle_duration_sec=WARN_PERIOD)

    def on_shape(self, topic: str, data: bytes, add) -> None:
        """A NeedleShape of ``topic``, logged and handed to the session's ``add`` (model or measurement)."""
        self.log(topic, data, NeedleShape)
        msg = deserialize_message(data, NeedleShape)
        points, arc_length, _ = shape_arrays(msg)
        self.publish(add(stamp_ns(msg.header.stamp), msg.header.frame_id, msg.header, points, arc_length))

    def on_measured_points(self, data: bytes) -> None:
        self.log("measured/points", data, PointCloud2)
        msg = deserialize_message(data, PointCloud2)
        try:
            points = cloud_points(msg)
        except ValueError as error:
            self.session.reject("measured points", str(error))
            return
        self.publish(self.session.add_measurement(stamp_ns(msg.header.stamp), msg.header.frame_id, msg.header,
                                                  points, what="measured points"))

    # --- output -----------------------------------------------------------------------------------------------
    def publish(self, compared: list[ComparedPair]) -> None:
        """Each pair's ShapeError, then the compared centerlines as Path and Marker tube (model frame), published
        and recorded."""
        for pair in compared:
            data = shape_error_cdr(pair.result, pair.model_tag, pair.measured_tag)
            self.error_publisher.publish(data)
            self.log("shape_error", data, ShapeError, self.error_qos)
            for topic, data in self.displayer.outputs(pair).items():
                self.display_publishers[topic].publish(data)
                self.log(topic, data, LOGGABLE[topic])

    def finish(self) -> dict:
        """Finalize the recording; return (and write, if configured) the run summary."""
        if self.recorder is not None:
            files = ", ".join(map(str, self.recorder.close())) or "none"
            if self.recorder.failure is None:
                print(f"[{NODE_NAME}] recording finalized: {files}", flush=True)
            else:
                print(f"[{NODE_NAME}] recording NOT finalized ({self.recorder.failure}): {files}; "
                      "needle_mcap_recover rebuilds its index", file=sys.stderr, flush=True)
        report = self.session.finish()
        print(f"[{NODE_NAME}] summary: {json.dumps(report)}", flush=True)
        if self.values["summary_path"]:
            path = pathlib.Path(self.values["summary_path"])
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(json.dumps(report, indent=2) + "\n")
            except OSError as error:
                print(f"[{NODE_NAME}] cannot write summary_path '{path}': {error}", file=sys.stderr, flush=True)
        return report


def main(args=None) -> int:
    return run_node(CompareNode, NODE_NAME, args, COMPARE_PARAMETERS)


if __name__ == "__main__":
    sys.exit(main())
