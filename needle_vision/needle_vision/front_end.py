"""The stereo measurement built from validated parameter values (rig, pipeline, base poses)."""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from needle_common.cdr import PoseStamped
from needle_common.parameters import ParameterError
from needle_common.transforms import RigidTransform
from needle_vision.calibration.rig import CalibrationError, CameraInfoRig, StereoRig, load_camera_calibration
from needle_vision.parameters import stereo_config
from needle_vision.pipeline import StereoNeedlePipeline
from needle_vision.streams.base_pose import BasePoseStore, store_base_pose


class StereoFrontEnd:
    """The measurement as validated parameter ``values`` set it up, one builder for ``needle_stereo``, the offline
    command and the offline pipeline: the rig of the calibration files, else of both cameras' ``camera_info``; the
    base poses (output frame) kept across rebuilds. ``pipeline`` is None while no calibration is known."""

    def __init__(self, values: dict[str, Any]) -> None:
        self.values = values
        # pose of the raw left optical frame in the output frame (the identity without an output_frame)
        self.output_from_left = RigidTransform.from_xyz_quaternion(values["output_transform"]) \
            if values["output_frame"] else RigidTransform()
        self.base_poses = BasePoseStore(values["base_pose.max_age"], values["base_pose.offset"])
        self.camera_infos = CameraInfoRig()
        self.image_frame = ""  # frame_id of the left images (the raw left optical frame)
        self.pipeline: StereoNeedlePipeline | None = None
        if values["left_calibration_file"]:
            try:
                self.use_rig(StereoRig.from_camera_calibrations(*map(load_camera_calibration, (
                    values["left_calibration_file"], values["right_calibration_file"]))))
            except CalibrationError as error:
                raise ParameterError(f"parameter 'left_calibration_file'/'right_calibration_file': {error}") from error

    def use_rig(self, rig: StereoRig) -> None:
        """A new pipeline for ``rig``; CalibrationError (and no pipeline) when it cannot be rectified."""
        self.pipeline = None
        try:
            self.pipeline = StereoNeedlePipeline(rig, stereo_config(self.values), self.output_from_left,
                                                 self.base_poses)
        except (cv2.error, np.linalg.LinAlgError) as error:
            raise CalibrationError(f"the stereo rig cannot be rectified: {error}") from error

    def on_camera_info(self, side: str, info: Any) -> StereoRig | None:
        """Take ``side``'s camera_info (ignored with calibration files): the new rig when both cameras are known and
        one changed, else None; CalibrationError (and no pipeline) when they make no usable rig."""
        if self.values["left_calibration_file"]:
            return None
        try:
            rig = self.camera_infos.offer(side, info)
        except CalibrationError:
            self.pipeline = None
            raise
        if rig is not None:
            self.use_rig(rig)
        return rig

    def add_base_pose(self, pose: PoseStamped) -> None:
        """Store a base pose in the output frame; ValueError says why an unusable one is not stored."""
        store_base_pose(self.base_poses, pose, self.values["output_frame"],
                        (self.values["left_optical_frame"], self.image_frame), self.output_from_left)
