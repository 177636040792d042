"""The haptic output's shaping, without ROS: frame, pose watchdog with a resume ramp, and saturation.

The rendered wrench is the needle's wrench on its holder about A (the sign of the ``wrench`` output), in the arm's
base frame (``frame == "base"``: ``frames.world``) or the holder frame (``"tool"``: ``frames.base``). Watchdog: a
last pose *arrival* (monotonic wall clock, also under simulated time: it guards the link to the arm) older than
``pose_timeout`` makes the gain zero; when poses return it ramps from 0 to 1 over ``resume_ramp`` (also after the
first pose). Saturation: a force (torque) beyond ``max_force`` (``max_torque``) is scaled to it, direction kept,
and counted.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

ZERO = (0.0, 0.0, 0.0)


def _clip(vector: Sequence[float], limit: float) -> tuple[tuple[float, ...], bool]:
    """The vector scaled down to length ``limit`` if longer (direction kept), and whether it was."""
    norm = math.hypot(*vector)
    if norm <= limit:
        return tuple(vector), False
    scale = limit / norm if norm > 0.0 else 0.0
    return tuple(v * scale for v in vector), True


@dataclass
class HapticShaper:
    """State of the haptic output: limits, watchdog and counters (one instance per activation)."""

    max_force: float
    max_torque: float
    pose_timeout: float
    resume_ramp: float
    world_frame: bool = True  # "base": the arm's base frame (frames.world); False: the holder frame
    last_pose: float = -math.inf    # monotonic arrival time [s] of the newest base pose
    resumed_at: float = -math.inf   # when poses (re)started after a silence
    clipped_forces: int = 0
    clipped_torques: int = 0
    watchdog_trips: int = 0
    poses_seen: bool = False
    _silent: bool = True

    def pose_arrived(self, now: float) -> None:
        """A base pose arrived at monotonic time ``now`` [s]."""
        if now - self.last_pose > self.pose_timeout:
            self.resumed_at = now
        self.last_pose, self.poses_seen = now, True

    def silent(self, now: float) -> bool:
        """Whether the watchdog holds the output at zero (no pose for longer than ``pose_timeout``)."""
        silent = now - self.last_pose > self.pose_timeout
        if silent and not self._silent:
            self.watchdog_trips += 1
        self._silent = silent
        return silent

    def gain(self, now: float) -> float:
        """0 while silent, then rising linearly to 1 over ``resume_ramp`` after the poses came back."""
        if self.silent(now):
            return 0.0
        if self.resume_ramp <= 0.0:
            return 1.0
        return min(max((now - self.resumed_at) / self.resume_ramp, 0.0), 1.0)

    def shape(self, wrenches: Iterable[tuple[float, Sequence[float], Sequence[float]]], now: float):
        """(time, force, torque) to publish for each (time, force, torque) of a step, scaled by the gain at ``now``
        and saturated (a non-finite wrench becomes zero: never NaN towards an arm)."""
        gain = self.gain(now)
        for t, force, torque in wrenches:
            if gain == 0.0 or not all(map(math.isfinite, (*force, *torque))):
                yield t, ZERO, ZERO
                continue
            force, clipped_force = _clip([gain * f for f in force], self.max_force)
            torque, clipped_torque = _clip([gain * m for m in torque], self.max_torque)
            self.clipped_forces += clipped_force
            self.clipped_torques += clipped_torque
            yield t, force, torque

    def frame_wrenches(self, records) -> list[tuple[float, Sequence[float], Sequence[float]]]:
        """(step end time, force, torque) of each step record (``simulation.StepRecord``) in the output frame."""
        if self.world_frame:
            return [(r.t, r.wrench.force_world.tolist(), r.wrench.torque_world.tolist()) for r in records]
        return [(r.t, r.wrench.force_base.tolist(), r.wrench.torque_base.tolist()) for r in records]
