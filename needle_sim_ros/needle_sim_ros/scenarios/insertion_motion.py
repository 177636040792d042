"""Base motion of a needle insertion (ROS-free): axial travel through tip-depth waypoints at a constant speed, and
the roll of the base about its axis, which turns the bevel (the cable has no torsion, so the tip rolls with it).

Roll = ``roll`` + duty-cycled spinning + ``roll_changes``. Duty-cycled spinning (Minhas et al. 2007): each period
spins the base one turn at ``spin_rate`` during its last fraction ``duty_cycle`` d and holds it otherwise, so the
path curvature falls roughly as (1 - d). A roll change (t_start, duration, angle) turns the base with a cubic profile.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needle_sim_ros.model import BaseMotion


@dataclass(frozen=True)
class InsertionMotion:
    """Insertion along world +x from the base at the origin; the tip starts ``gap`` [m] before the entry surface.
    waypoints: tip depths [m] in turn (e.g. (0.06, 0.03, 0.09): retract and re-insert); speed [m/s]; roll [rad] at
    the start; spin_rate [rad/s], duty_cycle [0, 1]; roll_changes: ((t_start [s], duration [s], angle [rad]), ...)."""

    waypoints: tuple[float, ...]
    speed: float
    gap: float = 2e-3
    roll: float = 0.0
    spin_rate: float = 0.0
    duty_cycle: float = 0.0
    roll_changes: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        if not (np.isfinite(self.speed) and self.speed > 0.0):
            raise ValueError(f"insertion speed must be > 0 [m/s], got {self.speed!r}")
        if not self.waypoints or not all(np.isfinite(w) and w >= 0.0 for w in self.waypoints):
            raise ValueError(f"insertion depths must be >= 0 [m], got {self.waypoints!r}")
        if not (np.isfinite(self.gap) and self.gap >= 0.0):
            raise ValueError(f"insertion gap must be >= 0 [m], got {self.gap!r}")
        if not np.isfinite(self.roll):
            raise ValueError(f"roll must be finite [rad], got {float(self.roll)!r}")
        if not (np.isfinite(self.spin_rate) and self.spin_rate >= 0.0):
            raise ValueError(f"spin rate must be >= 0 [rad/s], got {self.spin_rate!r}")
        if not 0.0 <= self.duty_cycle <= 1.0:
            raise ValueError(f"duty cycle must be in [0, 1], got {self.duty_cycle!r}")
        if self.duty_cycle > 0.0 and not self.spin_rate > 0.0:
            raise ValueError(f"a duty cycle > 0 needs a spin rate > 0 [rad/s], got {self.spin_rate!r}")
        for change in self.roll_changes:
            if len(change) != 3 or not np.all(np.isfinite(change)) or change[1] <= 0.0:
                raise ValueError(f"roll change must be (t_start, duration > 0, angle), got {change!r}")
        travel = np.abs(np.diff(np.r_[-self.gap, self.waypoints]))
        object.__setattr__(self, "_times", np.r_[0.0, np.cumsum(travel) / self.speed])
        object.__setattr__(self, "_positions", np.r_[0.0, np.asarray(self.waypoints) + self.gap])

    @property
    def duration(self) -> float:
        """Time [s] to pass every waypoint."""
        return float(self._times[-1])

    def travel(self, t):
        """Base position along x [m] and its velocity [m/s] at time(s) t (piecewise linear through the waypoints)."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        i = np.minimum(np.searchsorted(self._times, t, side="right") - 1, len(self.waypoints) - 1)
        span = self._times[i + 1] - self._times[i]
        direction = np.sign(self._positions[i + 1] - self._positions[i])
        velocity = np.where((t < self.duration) & (span > 0.0), direction * self.speed, 0.0)
        return self._positions[i] + direction * self.speed * (t - self._times[i]), velocity

    def roll_at(self, t):
        """Roll angle [rad] of the base and its rate [rad/s] at time(s) t."""
        t = np.asarray(t, dtype=float)
        angle, rate = np.full(t.shape, self.roll), np.zeros(t.shape)
        if self.duty_cycle > 0.0:
            turn = 2.0 * np.pi / self.spin_rate                     # one full turn per period
            period = turn / self.duty_cycle
            cycles, phase = np.divmod(t, period)
            spinning = np.maximum(phase - (period - turn), 0.0)
            angle = angle + 2.0 * np.pi * cycles + self.spin_rate * spinning
            rate = rate + np.where(spinning > 0.0, self.spin_rate, 0.0)
        for start, duration, change in self.roll_changes:
            u = np.clip((t - start) / duration, 0.0, 1.0)
            angle = angle + change * u * u * (3.0 - 2.0 * u)
            rate = rate + change * 6.0 * u * (1.0 - u) / duration
        return angle, rate

    def motions_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The base (clamp point A, needle along its x axis) at each time (k,): travel along x, roll about x, packed
        (k, 19) as ``BaseMotion.from_packed`` takes it, and the rotations (k, 3, 3) (finite and unit quaternions by
        construction; the simulator's time loop takes a run of steps at once)."""
        x, v = self.travel(times)
        roll, rate = self.roll_at(times)
        packed = np.zeros((np.size(times), 19))  # [position, orientation (x, y, z, w), v, w, a, alpha]
        packed[:, 0], packed[:, 3], packed[:, 6], packed[:, 7], packed[:, 10] = (x, np.sin(0.5 * roll),
                                                                               np.cos(0.5 * roll), v, rate)
        c, s = np.cos(roll), np.sin(roll)
        rotations = np.zeros((np.size(times), 3, 3))
        rotations[:, 0, 0], rotations[:, 1, 1], rotations[:, 1, 2], rotations[:, 2, 1], rotations[:, 2, 2] = (
            1.0, c, -s, s, c)
        return packed, rotations

    def base_at(self, t: float) -> BaseMotion:
        """The base at time t (``motions_at``)."""
        packed, rotations = self.motions_at(np.array([t], dtype=float))
        return BaseMotion.from_packed(packed[0], rotations[0])
