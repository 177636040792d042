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
happens in the ROS-free :class:`needle_vision.pipeline.StereoNeedlePipeline`.
"""
from __future__ import annotations

import sys
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np
import rclpy
import rclpy.executors
import rclpy.time
from geometry_msgs.msg import PoseStamped
from needle_interfaces.msg import NeedleShape
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2, PointField
from std_msgs.msg import Header

from needle_common.cdr import pose_stamped
from needle_common.parameters import ParameterError
from needle_common.ros.input_status import InputStatus
from needle_common.ros.needle_shape import needle_shape_msg
from needle_common.ros.ros_parameters import declare_all
from needle_common.ros.runner import run_node
from needle_common.ros.tf_output import TfOutput, transform_stamped
from needle_common.transforms import quaternions_from_x_axes
from needle_vision.streams.base_pose import store_base_pose
from needle_vision.calibration.rig import CalibrationError, CameraInfoRig, StereoRig, rig_from_calibration_files
from needle_vision.streams.image_codec import (ImageFormatError, compressed_message_to_gray, image_fields,
                                               image_message_to_gray)
from needle_vision.streams.outputs import debug_image, pointcloud2_fields
from needle_vision.streams.pairing import StampPairer
from needle_vision.parameters import SPECS, base_pose_store, output_from_left, stereo_config, validate_all
from needle_vision.pipeline import FrameResult, FrameStatus, StereoNeedlePipeline, compile_kernels
from needle_vision.ros.measurement_status import MeasurementStatus


def _stamp_seconds(header: Header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


class NeedleStereoNode(Node):
    def __init__(self) -> None:
        super().__init__("needle_stereo")
        self.values = validate_all(declare_all(self, SPECS))
        self.config = stereo_config(self.values)
        self.output_from_left = output_from_left(self.values)
        self.base_poses = base_pose_store(self.values)
        self.pairer = StampPairer(self.values["sync_tolerance"], self.values["sync_queue_size"])
        self.pipeline: StereoNeedlePipeline | None = None
        self.camera_infos = CameraInfoRig()
        compressed = self.values["image_transport"] == "compressed"
        # the two images of a pair decoded at once (OpenCV releases the GIL while decoding)
        self._decoder = ThreadPoolExecutor(2, thread_name_prefix="decode") if compressed else None
        self.frame_id = self.values["output_frame"]
        self._last_warning: dict[str, float] = {}
        self._reported_drops = 0
        self._image_frame = ""  # frame_id of the left images (the raw left optical frame)
        self.tf = TfOutput(self)
        self.measurement_status = MeasurementStatus(self.get_fully_qualified_name())
        self.inputs = InputStatus(self, lambda: [self.measurement_status.status(
            self.pairer.dropped, self.pipeline.rejections if self.pipeline else Counter())])
        qos = qos_profile_sensor_data if self.values["image_qos"] == "sensor_data" else \
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        if self.values["left_calibration_file"]:
            try:
                rig = rig_from_calibration_files(self.values["left_calibration_file"],
                                                 self.values["right_calibration_file"])
            except CalibrationError as error:
                raise ParameterError(f"parameter 'left_calibration_file'/'right_calibration_file': {error}") from error
            self.pipeline = StereoNeedlePipeline(rig, self.config, self.output_from_left, self.base_poses)
            self.send_camera_frames(rig)
        else:
            for side in ("left", "right"):
                self.inputs.track(self.create_subscription(CameraInfo, f"{side}/camera_info",
                                                           lambda msg, side=side: self.on_camera_info(side, msg), qos))
        # after the parameters are checked and the static frames sent, before subscribing: a pair arriving while the
        # kernels compile would wait, and the ones after it be dropped
        self.get_logger().info(f"measurement kernels ready in {compile_kernels():.1f} s")
        image_type, suffix = (CompressedImage, "/compressed") if compressed else (Image, "")
        for side in ("left", "right"):
            self.inputs.track(self.create_subscription(image_type, f"{side}/image_raw{suffix}",
                                                       lambda msg, side=side: self.on_image(side, msg), qos))
        if self.values["base_pose.topic"]:
            self.inputs.track(self.create_subscription(PoseStamped, self.values["base_pose.topic"], self.on_base_pose,
                                                       qos_profile_sensor_data, raw=True))
        self.tf_buffer = self.base_tf_buffer()
        self.cloud_pub = self.create_publisher(PointCloud2, "needle/measured_points", 10)
        self.shape_pub = self.create_publisher(NeedleShape, "needle/measured_shape", 10)
        self.debug_pub = self.create_publisher(Image, "needle/debug_image", 1)
        source = "calibration files" if self.pipeline else "left/camera_info and right/camera_info"
        self.get_logger().info(f"needle_stereo ready: {self.values['image_transport']} images, calibration from "
                               f"{source}, background from {self.config.background_frames} pairs")

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
            store_base_pose(self.base_poses, pose_stamped(data), self.frame_id,
                            (self.values["left_optical_frame"], self._image_frame), self.output_from_left)
        except ValueError as error:
            self.warn("base_pose", f"base pose on '{self.values['base_pose.topic']}' ignored: {error}")

    def look_up_base(self, header: Header) -> None:
        """The base frame's pose on TF at the image's stamp into the store (nothing when TF has none)."""
        try:
            transform = self.tf_buffer.lookup_transform(self.frame_id or header.frame_id,
                                                        self.values["base_pose.frame"],
                                                        rclpy.time.Time.from_msg(header.stamp))
        except Exception:  # noqa: BLE001 - tf2's lookup, connectivity and extrapolation errors: no pose
            return
        t, r = transform.transform.translation, transform.transform.rotation
        try:
            self.base_poses.add(_stamp_seconds(header), (t.x, t.y, t.z), (r.x, r.y, r.z, r.w))
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
            rig = self.camera_infos.offer(side, msg)
            if rig is None:
                return
            self.pipeline = StereoNeedlePipeline(rig, self.config, self.output_from_left, self.base_poses)
        except (CalibrationError, cv2.error, np.linalg.LinAlgError) as error:
            self.pipeline = None
            self.warn("calibration", f"camera_info unusable, nothing is measured: {error}")
            return
        self.send_camera_frames(rig)
        self.get_logger().info("stereo calibration received from camera_info; background model restarts")

    def on_image(self, side: str, msg: Image | CompressedImage) -> None:
        pair = self.pairer.push(side, _stamp_seconds(msg.header), msg)
        if self.pairer.dropped > self._reported_drops:
            self.warn("sync", f"{self.pairer.dropped - self._reported_drops} frame(s) without a partner within "
                              f"{self.values['sync_tolerance']} s were dropped")
            self._reported_drops = self.pairer.dropped
        if pair is None:
            return
        if self.pipeline is None:
            self.measurement_status.count("skipped_no_calibration")
            self.warn("calibration", "no usable stereo calibration yet (waiting for left/camera_info and "
                                     "right/camera_info): frame skipped")
            return
        try:
            images = list(self._decoder.map(compressed_message_to_gray, (pair.left, pair.right))) if self._decoder \
                else [image_message_to_gray(pair.left), image_message_to_gray(pair.right)]
        except ImageFormatError as error:
            self.measurement_status.count("skipped_decode_error")
            self.warn("decode", f"pair at {pair.stamp:.6f} s skipped: {error}")
            return
        self._image_frame = pair.left.header.frame_id
        if self.tf_buffer is not None:
            self.look_up_base(pair.left.header)
        result = self.pipeline.process(pair.stamp, *images)
        self.measurement_status.count(result.status.name.lower())
        if result.status is FrameStatus.REJECTED:
            counts = ", ".join(f"{kind} {count}" for kind, count in self.pipeline.rejections.most_common())
            self.warn("rejected", f"nothing published for the pair at {pair.stamp:.6f} s: {result.reason} "
                                  f"(rejected so far: {counts})")
        if result.status is not FrameStatus.BACKGROUND:
            self.publish_debug(pair.left.header, images, result)
        if result.status is FrameStatus.MEASURED:
            self.publish(pair.left.header, result)

    def publish(self, image_header: Header, result: FrameResult) -> None:
        measurement = result.measurement
        header = Header(stamp=image_header.stamp, frame_id=self.frame_id or image_header.frame_id)
        extra = {"v": result.motion.velocity, "a": result.motion.acceleration} if result.motion else None
        fields = pointcloud2_fields(measurement.points, extra)
        fields["fields"] = [PointField(**field) for field in fields["fields"]]
        self.cloud_pub.publish(PointCloud2(header=header, **fields))
        self.shape_pub.publish(needle_shape_msg(
            header, NeedleShape.SOURCE_STEREO, measurement.points, measurement.tangents, measurement.arc_length,
            measurement.points[-1], quaternions_from_x_axes(measurement.tangents[-1]), measurement.uncertainty))

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
