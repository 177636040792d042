"""The simulator's base input: what the user sent, as packed base motions at given times (ROS-free).

A :class:`BaseInput` turns the received flange poses (the fit of :class:`BaseTrajectory`), the flange-to-base
offset and the optional twist feed-forward into the motion of the clamp point A at any time -- or, for the
scenarios, the ground truth and the benchmarks, a prescribed ``base_at(t)`` / ``motions_at(times)`` instead.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from needle_sim_ros.base_trajectory import BaseTrajectory, PoseVerdict
from needle_sim_ros.compiled_advance import apply_twist
from needle_sim_ros.model import BaseMotion
from needle_sim_ros.model.kinematics import clamp_motions, clamp_offset
from needle_sim_ros.stepper import magnitude

PACKED_SIZE = 20  # BaseInput.packed
MotionsAt = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class InputLimits:
    """Documented limits of the base input (node parameters ``pose_input.*``): twist magnitudes, and the distance
    [m] from the held pose beyond which a pose arriving after a gap (older than ``pose_timeout``) restarts the
    needle straight there instead of dragging it across in one step."""

    max_linear_speed: float = 5.0  # [m/s]
    max_angular_speed: float = 20.0  # [rad/s]
    resume_tolerance: float = 1e-3  # [m]


class BaseInput:
    """The base motion from the received poses (``trajectory``, ``flange_offset`` (position, quaternion xyzw) of
    the clamp point in the flange frame, the twist while fresher than ``twist_timeout`` [s]) or, when given, from
    ``base_at(t)`` / ``motions_at(times)`` (:meth:`motions`)."""

    def __init__(self, trajectory: BaseTrajectory | None = None,
                 flange_offset: tuple = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), twist_timeout: float = 0.05,
                 limits: InputLimits = InputLimits(), base_at: Callable[[float], BaseMotion] | None = None,
                 motions_at: MotionsAt | None = None) -> None:
        # never replaced: a compiled plan (the stepper's AdvancePlan) holds its buffers
        self._trajectory = BaseTrajectory() if trajectory is None else trajectory
        # [twist timeout, twist [t, v, w] (NaN t: none), offset position, offset rotation (row-major)]: what the
        # compiled advance reads, in one array (one argument)
        self.packed = np.full(PACKED_SIZE, np.nan)
        self.packed[0] = twist_timeout
        self.packed[8:11], offset_rotation = clamp_offset(*flange_offset, prefix="flange_offset.")
        self.packed[11:20] = offset_rotation.ravel()
        self._parts = (self.packed[1:8], self.packed[8:11], self.packed[11:20].reshape(3, 3))  # views, made once
        self.limits = limits
        self.base_at = base_at
        self.motions_at = motions_at

    @property
    def trajectory(self) -> BaseTrajectory:
        return self._trajectory

    @property
    def twist_timeout(self) -> float:
        return float(self.packed[0])

    @property
    def twist(self) -> np.ndarray | None:
        """The twist feed-forward [t, linear velocity, angular velocity] (:meth:`set_twist`), None before one."""
        return None if np.isnan(self.packed[1]) else self.packed[1:8].copy()

    @twist.setter
    def twist(self, value: np.ndarray | None) -> None:
        self.packed[1:8] = np.nan if value is None else value

    @property
    def from_poses(self) -> bool:
        """Whether the base follows the received poses (not a prescribed motion)."""
        return self.base_at is None and self.motions_at is None

    def offer_pose(self, t: float, position, orientation, gap: float) -> PoseVerdict:
        """Offer a flange pose to the trajectory; a pose more than ``gap`` [s] after the previous one and farther
        than ``limits.resume_tolerance`` from it starts the trajectory anew there (RESTARTED)."""
        return self._trajectory.offer(t, position, orientation, gap, self.limits.resume_tolerance)

    def set_twist(self, t: float, linear_velocity: np.ndarray, angular_velocity: np.ndarray) -> None:
        """Velocity feed-forward of the flange (world frame); used instead of the estimate while fresh.
        ValueError beyond :class:`InputLimits` (the twist is then not used)."""
        speed, rate = magnitude(linear_velocity), magnitude(angular_velocity)
        limits = self.limits
        if not (speed <= limits.max_linear_speed and rate <= limits.max_angular_speed):
            raise ValueError(f"twist |v| = {speed:.3g} m/s, |w| = {rate:.3g} rad/s beyond pose_input.max_linear_speed "
                             f"{limits.max_linear_speed:g} m/s / max_angular_speed {limits.max_angular_speed:g} rad/s")
        self.twist = np.concatenate(([t], np.asarray(linear_velocity, dtype=float).reshape(3),
                                     np.asarray(angular_velocity, dtype=float).reshape(3)))

    def motion_at(self, t: float) -> BaseMotion:
        """Motion of the clamp point A at time t (:meth:`motions`)."""
        values, rotations = self.motions(np.array([t], dtype=float))
        return BaseMotion.from_packed(values[0], rotations[0])

    def motions(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Motions of the clamp point A at the given times (k,), packed (k, 19) as :meth:`BaseMotion.from_packed`
        takes them, and their rotations (k, 3, 3)."""
        if self.motions_at is not None:
            return self.motions_at(times)
        motions = self.prescribed_motions(times)
        if motions is not None:
            return (np.array([m.packed for m in motions]).reshape(len(times), 19),
                    np.array([m.rotation for m in motions]).reshape(len(times), 3, 3))
        flange = self.trajectory.motions_at(times)
        twist, offset, offset_rotation = self._parts
        apply_twist(flange, times, twist, self.twist_timeout)
        return clamp_motions(flange, offset, offset_rotation)

    def prescribed_motions(self, times: np.ndarray) -> list[BaseMotion] | None:
        """A prescribed base's own motions at ``times`` (``base_at``), for steps that take them one at a time;
        None where the motions come packed (``motions_at``, the received poses: :meth:`motions`)."""
        if self.motions_at is not None or self.base_at is None:
            return None
        return [self.base_at(float(t)) for t in times]

    def pose_age(self, now: float) -> float:
        latest = self._trajectory.latest_time
        return now - latest if latest is not None else float("inf")
