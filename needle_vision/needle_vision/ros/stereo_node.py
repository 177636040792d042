"""``needle_stereo``: stereo measurement of the needle centerline (seed 000, Sec. III-A) as a ROS 2 node.

Subscribes ``left/image_raw``, ``right/image_raw`` (``sensor_msgs/Image``; with ``image_transport: compressed``
``sensor_msgs/CompressedImage`` on image_transport's ``left/image_raw/compressed``, ``right/image_raw/compressed``,
decoded with OpenCV), and ``left/camera_info``, ``right/camera_info`` when no calibration files are given
(stereo_image_proc naming; remap as needed); pairs frames by approximate time (``sync_tolerance``, a bounded queue of
``sync_queue_size`` frames per camera); publishes ``needle/measured_points`` (sensor_msgs/PointCloud2: the centerline
samples, x y z float32, plus vx..vz, ax..az when tracking), ``needle/measured_shape`` (needle_interfaces/NeedleShape
with per-sample uncertainty), ``needle/debug_image`` (bgr8, centerlines drawn) and, twice a second, its input report and
what became of the pairs on ``/diagnostics`` (:mod:`needle_common.ros.input_status`,
:mod:`needle_vision.ros.measurement_status`). Base and tip are told apart by the needle's base pose: ``base_pose``
(geometry_msgs/PoseStamped, read raw) and, where tf2_ros is installed, the TF frame ``base_pose.frame``. Everything else
happens in the ROS-free :class:`needle_vision.pipeline.StereoNeedlePipeline`, whose numba kernels load on a worker
thread at start (~1 min where numba's cache has none): until then the input report says ``accepting: false`` and the
pairs are counted as ``skipped_loading_kernels``.
"""
from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import rclpy
import rclpy.executors
import rclpy.time
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from needle_interfaces.msg import NeedleShape
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2, PointField
from std_msgs.msg import Header

from needle_common.cdr import needle_shape, pose_stamped
from needle_common.ros.input_status import InputStatus
from needle_common.ros.ros_parameters import declare_all, qos_profile
from needle_common.ros.runner import run_node
from needle_common.ros.tf_output import TfOutput, transform_stamped
from needle_vision.calibration.rig import CalibrationError, StereoRig
from needle_vision.streams.image_codec import ImageFormatError, SerializedImage, deserialize_image, image_fields
from needle_vision.streams.outputs import debug_image, pointcloud2_fields
from needle_vision.streams.pairing import StampPairer
from needle_vision.front_end import StereoFrontEnd
from needle_vision.parameters import SPECS, validate_all
from needle_vision.pipeline import FrameResult, FrameStatus, compile_kernels
from needle_vision.ros.measurement_status import MeasurementStatus


class NeedleStereoNode(Node):
    def __init__(self) -> None:
        super().__init__("needle_stereo")
        self.values = validate_all(declare_all(self, SPECS))
        self.front = StereoFrontEnd(self.values)
        self.pairer = StampPairer(self.values["sync_tolerance"], self.values["sync_queue_size"])
        self.compressed = self.values["image_transport"] == "compressed"
        # the two images of a pair decoded at once (OpenCV releases the GIL while decoding)
        self._decoder = ThreadPoolExecutor(2, thread_name_prefix="decode") if self.compressed else None
        self.frame_id = self.values["output_frame"]
        self._last_warning: dict[str, float] = {}
        self._reported_drops = 0
        self.tf = TfOutput(self)
        self.measurement_status = MeasurementStatus(self.get_fully_qualified_name())
        self.kernels_ready = threading.Event()
        self.inputs = InputStatus(self, lambda: [self.measurement_status.status(
            self.pairer.dropped, self.front.pipeline.rejections if self.front.pipeline else Counter())],
            accepting=self.kernels_ready.is_set)
        qos = qos_profile(self.values["image_qos"])
        if self.front.pipeline:
            self.send_camera_frames(self.front.pipeline.rig)
        else:
            for side in ("left", "right"):
                self.inputs.track(self.create_subscription(CameraInfo, f"{side}/camera_info",
                                                           lambda msg, side=side: self.on_camera_info(side, msg), qos))
        # after the parameters are checked, on a worker: the node subscribes and reports at once (daemon: a stop
        # while they compile does not wait for them)
        threading.Thread(target=self.load_kernels, name="kernels", daemon=True).start()
        image_type, suffix = (CompressedImage, "/compressed") if self.compressed else (Image, "")
        for side in ("left", "right"):  # read serialized, as the offline tools read a bag's images
            self.inputs.track(self.create_subscription(image_type, f"{side}/image_raw{suffix}",
                                                       lambda data, side=side: self.on_image(side, data), qos,
                                                       raw=True))
        if self.values["base_pose.topic"]:
            self.inputs.track(self.create_subscription(PoseStamped, self.values["base_pose.topic"], self.on_base_pose,
                                                       qos_profile("sensor_data", 100), raw=True))
        self.tf_buffer = self.base_tf_buffer()
        self.cloud_pub = self.create_publisher(PointCloud2, "needle/measured_points", 10)
        self.shape_pub = self.create_publisher(NeedleShape, "needle/measured_shape", 10)
        self.debug_pub = self.create_publisher(Image, "needle/debug_image", 1)
        source = "calibration files" if self.front.pipeline else "left/camera_info and right/camera_info"
        self.get_logger().info(f"needle_stereo ready: {self.values['image_transport']} images, calibration from "
                               f"{source}, background from {self.values['background.frames']} pairs")

    def load_kernels(self) -> None:
        """Compile, or load from numba's cache, the measurement's kernels (:func:`compile_kernels`), then take
        pairs."""
        self.get_logger().info("loading the measurement kernels (compiling them if numba's cache has none: ~1 min); "
                               "pairs are counted as skipped_loading_kernels until then")
        try:
            self.get_logger().info(f"measurement kernels ready in {compile_kernels():.1f} s "
                                   f"({self.measurement_status.pairs['skipped_loading_kernels']} pairs skipped)")
        except Exception as error:  # noqa: BLE001 - numba's or LLVM's: the pairs compile them as they need them
            self.get_logger().error(f"loading the measurement kernels failed, the first pairs compile them: {error}")
        self.kernels_ready.set()

    def base_tf_buffer(self) -> Any:
        """A tf2_ros buffer listening to /tf for the base frame, or None (no frame set, or tf2_ros missing)."""
        if not self.values["base_pose.frame"]:
            return None
        try:
            from tf2_ros import Buffer, TransformListener
        except ImportError:
            self.get_logger().info("tf2_ros is not installed: the base frame is not looked up on TF (base poses "
                                   f"from '{self.values['base_pose.topic']}' only)")
            return None
        buffer = Buffer()
        self._tf_listener = TransformListener(buffer, self)
        return buffer

    def on_base_pose(self, data: bytes) -> None:
        """A serialized base pose, stored in the output frame; unusable ones are warned about (throttled)."""
        try:
            self.front.add_base_pose(pose_stamped(data))
        except ValueError as error:
            self.warn("base_pose", f"base pose on '{self.values['base_pose.topic']}' ignored: {error}")

    def look_up_base(self, header: Header, stamp: float) -> None:
        """The base frame's pose on TF at the image's stamp into the store (nothing when TF has none)."""
        try:
            transform = self.tf_buffer.lookup_transform(self.frame_id or header.frame_id,
                                                        self.values["base_pose.frame"],
                                                        rclpy.time.Time.from_msg(header.stamp))
        except Exception:  # noqa: BLE001 - tf2's lookup, connectivity and extrapolation errors: no pose
            return
        t, r = transform.transform.translation, transform.transform.rotation
        try:
            self.front.base_poses.add(stamp, (t.x, t.y, t.z), (r.x, r.y, r.z, r.w))
        except ValueError as error:
            self.warn("base_pose", f"base frame '{self.values['base_pose.frame']}' on TF ignored: {error}")

    def send_camera_frames(self, rig: StereoRig) -> None:
        """/tf_static: output_frame -> left optical frame (output_transform; only with an output_frame) and
        left -> right optical frame (the stereo calibration's extrinsics)."""
        stamp = self.get_clock().now().to_msg()
        left, right = self.values["left_optical_frame"], self.values["right_optical_frame"]
        transforms = []
        if self.frame_id:
            pose = self.values["output_transform"]
            transforms.append(transform_stamped(stamp, self.frame_id, left, pose[:3], pose[3:]))
        right_in_left = rig.left_from_right.as_xyz_quaternion()
        transforms.append(transform_stamped(stamp, left, right, right_in_left[:3], right_in_left[3:]))
        self.tf.send_static(transforms)

    def warn(self, kind: str, text: str) -> None:
        """A warning, at most one per ``warning_period`` for each kind."""
        now = time.monotonic()
        if now - self._last_warning.get(kind, -np.inf) >= self.values["warning_period"]:
            self._last_warning[kind] = now
            self.get_logger().warning(text)

    def on_camera_info(self, side: str, msg: CameraInfo) -> None:
        try:
            rig = self.front.on_camera_info(side, msg)
        except CalibrationError as error:
            self.warn("calibration", f"camera_info unusable, nothing is measured: {error}")
            return
        if rig is None:
            return
        self.send_camera_frames(rig)
        self.get_logger().info("stereo calibration received from camera_info; background model restarts")

    def on_image(self, side: str, data: bytes) -> None:
        try:
            image = deserialize_image(data, self.compressed)
        except ImageFormatError as error:
            self.measurement_status.count("skipped_decode_error")
            self.warn("decode", f"{side} image skipped: {error}")
            return
        pair = self.pairer.push(side, image.stamp, image)
        if self.pairer.dropped > self._reported_drops:
            self.warn("sync", f"{self.pairer.dropped - self._reported_drops} frame(s) without a partner within "
                              f"{self.values['sync_tolerance']} s were dropped")
            self._reported_drops = self.pairer.dropped
        if pair is None:
            return
        pipeline = self.front.pipeline
        if pipeline is None:
            self.measurement_status.count("skipped_no_calibration")
            self.warn("calibration", "no usable stereo calibration yet (waiting for left/camera_info and "
                                     "right/camera_info): frame skipped")
            return
        if not self.kernels_ready.is_set():
            self.measurement_status.count("skipped_loading_kernels")
            self.warn("kernels", f"pair at {pair.stamp:.6f} s skipped: the measurement kernels are still loading")
            return
        try:
            images = list(self._decoder.map(SerializedImage.gray, (pair.left, pair.right))) if self._decoder \
                else [pair.left.gray(), pair.right.gray()]
        except ImageFormatError as error:
            self.measurement_status.count("skipped_decode_error")
            self.warn("decode", f"pair at {pair.stamp:.6f} s skipped: {error}")
            return
        left = pair.left
        self.front.image_frame = left.frame_id
        header = Header(stamp=Time(sec=left.sec, nanosec=left.nanosec), frame_id=left.frame_id)
        if self.tf_buffer is not None:
            self.look_up_base(header, pair.stamp)
        result = pipeline.process(pair.stamp, *images)
        self.measurement_status.count(result.status.name.lower())
        if result.status is FrameStatus.REJECTED:
            counts = ", ".join(f"{kind} {count}" for kind, count in pipeline.rejections.most_common())
            self.warn("rejected", f"nothing published for the pair at {pair.stamp:.6f} s: {result.reason} "
                                  f"(rejected so far: {counts})")
        if result.status is not FrameStatus.BACKGROUND:
            self.publish_debug(header, images, result)
        if result.status is FrameStatus.MEASURED:
            self.publish(header, result)

    def publish(self, image_header: Header, result: FrameResult) -> None:
        measurement = result.measurement
        header = Header(stamp=image_header.stamp, frame_id=self.frame_id or image_header.frame_id)
        extra = {"v": result.motion.velocity, "a": result.motion.acceleration} if result.motion else None
        fields = pointcloud2_fields(measurement.points, extra)
        fields["fields"] = [PointField(**field) for field in fields["fields"]]
        self.cloud_pub.publish(PointCloud2(header=header, **fields))
        self.shape_pub.publish(needle_shape(
            header.stamp.sec, header.stamp.nanosec, header.frame_id, NeedleShape.SOURCE_STEREO, measurement.points,
            measurement.tangents, measurement.arc_length, uncertainty=measurement.uncertainty))

    def publish_debug(self, image_header: Header, images: list[np.ndarray], result: FrameResult) -> None:
        if not self.values["debug_image.enabled"] or self.debug_pub.get_subscription_count() == 0:
            return
        measurement = result.measurement
        picture = debug_image(images[0], images[1],
                              measurement.left_centerline.points if measurement else None,
                              measurement.right_centerline.points if measurement else None,
                              self.values["debug_image.downsample"])
        self.debug_pub.publish(Image(header=image_header, **image_fields(picture, "bgr8")))

    def destroy_node(self) -> None:
        if self._decoder is not None:
            self._decoder.shutdown(cancel_futures=True)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(NeedleStereoNode, "needle_stereo", args, SPECS)


if __name__ == "__main__":
    sys.exit(main())
