"""The simulator's input rules, one copy for the node and the offline stage (ROS-free).

``needle_simulator`` (live or in simulated time) and the offline pipeline's ``SimulatorStage`` take the same inputs
-- base poses, base twists, tip loads and point loads -- and must accept, convert and refuse them alike:

* a base pose must be in the world frame (or carry no frame); its stamp is used unless it is unset, or, on the wall
  clock, farther than ``max_stamp_offset`` from the receive time (a sender with another clock): then the receive
  time is (simulated time and bags keep every stamp);
* a twist must be finite and in the world frame, within :class:`~needle_sim_ros.base_input.InputLimits`;
* a force (the ``tip_load`` topic, the ``apply_point_load`` service) is given in the world frame (or no frame) or
  in the base frame, which the current base orientation turns into the world frame (REP 103).

A refused input raises :class:`InputRejected`, whose ``kind`` is the counter it goes to and whose message says why.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from needle_sim_ros.base_trajectory import PoseVerdict
from needle_sim_ros.simulation import TIP_LOAD_TOPIC, USED_POSES, NeedleSimulation

__all__ = ["USED_POSES", "InputRejected", "OfferedPose", "SimulatorInputs", "rejected_poses"]


def rejected_poses(counts: dict[PoseVerdict, int]) -> int:
    """How many of the counted poses the simulator did not use (every verdict outside ``USED_POSES``)."""
    return sum(n for verdict, n in counts.items() if verdict not in USED_POSES)


class InputRejected(ValueError):
    """An input the simulator does not use: ``kind`` names its counter (``wrong_frame``, ``twist_rejected``,
    ``tip_load_rejected``, ``point_load_rejected``), the message says why."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


class OfferedPose(NamedTuple):
    """What became of an offered base pose: the trajectory's verdict, the stamp used [s] and whether that is the
    receive time instead of the pose's own stamp."""

    verdict: PoseVerdict
    stamp: float
    stamp_replaced: bool


@dataclass(frozen=True)
class SimulatorInputs:
    """The input rules (module docstring) around one simulation; ``max_stamp_offset`` [s]: inf in simulated time."""

    sim: NeedleSimulation
    world_frame: str
    base_frame: str
    max_stamp_offset: float = math.inf

    def offer_pose(self, frame_id: str, stamp: float, position, orientation, received: float) -> OfferedPose:
        """Offer a base pose stamped ``stamp`` [s] (0: unset) that arrived at ``received`` [s, the clock]."""
        if frame_id not in ("", self.world_frame):
            raise InputRejected("wrong_frame", f"base pose in frame '{frame_id}': expected '{self.world_frame}'")
        replaced = stamp == 0.0 or abs(stamp - received) > self.max_stamp_offset
        used = received if replaced else stamp
        return OfferedPose(self.sim.offer_pose(used, position, orientation), used, replaced)

    def set_twist(self, frame_id: str, linear, angular, received: float) -> None:
        """Use a base twist (world frame) as the velocity feed-forward from ``received`` on."""
        linear, angular = np.asarray(linear, dtype=float), np.asarray(angular, dtype=float)
        if frame_id not in ("", self.world_frame) or not (np.all(np.isfinite(linear)) and np.all(np.isfinite(angular))):
            raise InputRejected("twist_rejected", "base twist not finite or not in the world frame")
        try:
            self.sim.set_twist(received, linear, angular)
        except ValueError as error:
            raise InputRejected("twist_rejected", f"base twist: {error}") from error

    def on_twist(self, msg, received: float) -> None:
        """:meth:`set_twist` of a ``geometry_msgs/TwistStamped`` (the node's message or the offline decoder's)."""
        v, w = msg.twist.linear, msg.twist.angular
        self.set_twist(msg.header.frame_id, (v.x, v.y, v.z), (w.x, w.y, w.z), received)

    def on_tip_load(self, msg) -> None:
        """The ``tip_load`` topic's force (``geometry_msgs/WrenchStamped``) on the tip, replacing the previous one."""
        f = msg.wrench.force
        self.set_point_load(TIP_LOAD_TOPIC, self.sim.model.props.length, msg.header.frame_id, (f.x, f.y, f.z),
                            "tip_load_rejected")

    def world_force(self, frame_id: str, force, kind: str) -> np.ndarray:
        """A force [N] given in ``frame_id`` (world, base or empty: world) in the world frame."""
        force = np.asarray(force, dtype=float)
        frame = frame_id or self.world_frame
        if frame not in (self.world_frame, self.base_frame):
            raise InputRejected(kind, f"frame '{frame}' is neither '{self.world_frame}' nor '{self.base_frame}'")
        if not np.all(np.isfinite(force)):
            raise InputRejected(kind, "force not finite")
        if frame == self.world_frame:
            return force
        if self.sim.base is None:
            raise InputRejected(kind, "no base pose yet to express a base-frame force in the world frame")
        return Rotation.from_quat(self.sim.base.orientation).apply(force)

    def set_point_load(self, name: str, arc_length: float, frame_id: str, force,
                       kind: str = "point_load_rejected") -> None:
        """Set the named point load from a force in ``frame_id`` (``set_point_load``'s limits apply)."""
        world = self.world_force(frame_id, force, kind)
        try:
            self.sim.set_point_load(name, arc_length, world)
        except ValueError as error:
            raise InputRejected(kind, str(error)) from error
