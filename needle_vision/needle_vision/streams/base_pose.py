"""Stamped poses of the needle base, for telling the base of a measured centerline from its tip (issue 16).

The simulator's ``base_pose`` input (``geometry_msgs/PoseStamped`` of the needle holder) or the TF frame of the
needle base give, at each pair's stamp, where the base is; this ordering does not depend on the previous frame
(temporal continuity) nor on a fixed ``base_point``, which flip when the needle moves or starts near them.
:class:`BasePoseStore` keeps the recent poses (decoded by :func:`needle_common.cdr.pose_stamped`). No ROS here.
"""
from __future__ import annotations

import bisect
import math
from typing import Sequence

import numpy as np

from needle_common.cdr import PoseStamped
from needle_common.transforms import RigidTransform, rotate


class BasePoseStore:
    """Recent base poses, as the base point in the output frame, for ordering the measured centerline.

    ``offset``: the point used as the base in the pose's own frame [m] (e.g. the clamp point A in the flange
    frame of the simulator's ``base_pose``, plus a stretch of needle hidden in the holder along x);
    ``max_age`` [s]: a pose farther in time from a pair's stamp is not used (both as the parameters
    ``base_pose.offset`` and ``base_pose.max_age`` validate them). Keeps the newest ``capacity`` poses.
    """

    def __init__(self, max_age: float, offset: Sequence[float] = (0.0, 0.0, 0.0), capacity: int = 4096):
        self.max_age = float(max_age)
        self.offset = tuple(float(v) for v in offset)
        self.capacity = capacity
        self._stamps: list[float] = []
        self._poses: list[tuple] = []  # (position, unit quaternion, output_from_pose): the point made when asked

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp: float, position: Sequence[float], orientation: Sequence[float],
            output_from_pose: RigidTransform | None = None) -> None:
        """Store the base point of a pose given in a frame whose pose in the output frame is ``output_from_pose`` (None:
        the output frame itself). ValueError for non-finite values or a zero quaternion (nothing stored). The point is
        computed when :meth:`base_at` asks for it (poses come at 1 kHz, pairs at tens of Hz)."""
        position, orientation = _floats(position), _floats(orientation)
        values = (stamp, *position, *orientation)
        if len(values) != 8 or not all(map(math.isfinite, values)):
            raise ValueError("non-finite stamp, position or orientation")
        norm = math.hypot(*orientation)
        if norm < 1e-9:
            raise ValueError("zero quaternion")
        index = bisect.bisect_right(self._stamps, stamp)
        self._stamps.insert(index, float(stamp))
        self._poses.insert(index, (position, [q / norm for q in orientation], output_from_pose))
        if len(self._stamps) > self.capacity:
            del self._stamps[0], self._poses[0]

    def base_at(self, stamp: float) -> np.ndarray | None:
        """The base point [m, output frame] of the pose nearest in time to ``stamp``, or None when none is
        within ``max_age``."""
        index = bisect.bisect_left(self._stamps, stamp)
        nearest = min((k for k in (index - 1, index) if 0 <= k < len(self._stamps)),
                      key=lambda k: abs(self._stamps[k] - stamp), default=None)
        if nearest is None or abs(self._stamps[nearest] - stamp) > self.max_age:
            return None
        position, unit_quaternion, output_from_pose = self._poses[nearest]
        shift = rotate(unit_quaternion, self.offset) if any(self.offset) else (0.0, 0.0, 0.0)
        point = np.array([p + s for p, s in zip(position, shift)])
        return point if output_from_pose is None else output_from_pose.apply(point)


def _floats(values: Sequence[float]) -> list[float]:
    """Python floats (a pose's arrays: numpy scalars cost more in the arithmetic here)."""
    return values.tolist() if isinstance(values, np.ndarray) else [float(v) for v in values]


IDENTITY = RigidTransform()  # built once: its checks cost ~0.2 ms, and the poses come at 1 kHz


def output_from_pose_frame(frame_id: str, output_frame: str, left_frames: Sequence[str],
                           output_from_left: RigidTransform) -> RigidTransform | None:
    """Pose of a base pose's frame in the output frame: the identity for the output frame (``output_frame``,
    or the left optical frame when it is empty) and for an empty frame_id, ``output_from_left`` for the left
    optical frame (``left_frames``: its names), None for any other frame (the pose cannot be used)."""
    if not frame_id or frame_id == output_frame:
        return IDENTITY
    if frame_id in left_frames:
        return output_from_left
    return None


def store_base_pose(store: BasePoseStore, pose: PoseStamped, output_frame: str, left_frames: Sequence[str],
                    output_from_left: RigidTransform) -> None:
    """Add ``pose`` to ``store`` in the output frame (:func:`output_from_pose_frame`); ValueError saying why a pose
    cannot be used (another frame, non-finite values, a zero quaternion)."""
    to_output = output_from_pose_frame(pose.frame_id, output_frame, left_frames, output_from_left)
    if to_output is None:
        raise ValueError(f"frame '{pose.frame_id}' is neither the output frame "
                         f"'{output_frame or left_frames[-1]}' nor the left optical frame")
    store.add(pose.stamp, pose.position, pose.orientation, to_output)
