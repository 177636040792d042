"""Base motion of a needle insertion (ROS-free): axial travel through tip-depth waypoints at a constant speed, and
the roll of the base about its axis, which turns the bevel (the cable has no torsion, so the tip rolls with it).

Roll = ``roll`` + duty-cycled spinning + ``roll_changes``.  Duty-cycled spinning (Minhas et al. 2007): each
period spins the base one full turn at ``spin_rate`` during the last fraction ``duty_cycle`` of the period and holds
it during the rest; the bevel then pushes along a fixed direction only (1 - d) of the time, so the path curvature
falls roughly as (1 - d), and d = 1 (constant spinning) goes straight.  A roll change (t_start, duration, angle)
turns the base by ``angle`` with a smooth (cubic) profile.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needle_sim_ros.model import BaseMotion


@dataclass(frozen=True)
class InsertionMotion:
    """Insertion along world +x from the base at the origin; the tip starts ``gap`` [m] before the entry surface.

    waypoints: tip depths [m] to reach in turn (e.g. (0.09,), or (0.06, 0.03, 0.09) to retract and re-insert);
    speed [m/s]; roll [rad] at the start; spin_rate [rad/s] and duty_cycle [0, 1] of duty-cycled spinning;
    roll_changes: ((t_start [s], duration [s], angle [rad]), ...).
    """

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
        if not 0.0 <= self.duty_cycle <= 1.0:
            raise ValueError(f"duty cycle must be in [0, 1], got {self.duty_cycle!r}")
        if self.duty_cycle > 0.0 and not (np.isfinite(self.spin_rate) and self.spin_rate > 0.0):
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

    def travel(self, t: float) -> tuple[float, float]:
        """Base position along x [m] and its velocity [m/s] at time t (piecewise linear through the waypoints)."""
        t = min(max(t, 0.0), self.duration)
        i = min(int(np.searchsorted(self._times, t, side="right")) - 1, len(self.waypoints) - 1)
        span = self._times[i + 1] - self._times[i]
        direction = np.sign(self._positions[i + 1] - self._positions[i])
        velocity = direction * self.speed if t < self.duration and span > 0.0 else 0.0
        return float(self._positions[i] + direction * self.speed * (t - self._times[i])), float(velocity)

    def roll_at(self, t: float) -> tuple[float, float]:
        """Roll angle [rad] of the base and its rate [rad/s] at time t."""
        angle, rate = self.roll, 0.0
        if self.duty_cycle > 0.0:
            turn = 2.0 * np.pi / self.spin_rate                     # one full turn per period
            period = turn / self.duty_cycle
            cycles, phase = divmod(t, period)
            spinning = max(phase - (period - turn), 0.0)
            angle += 2.0 * np.pi * cycles + self.spin_rate * spinning
            rate += self.spin_rate if spinning > 0.0 else 0.0
        for start, duration, change in self.roll_changes:
            u = min(max((t - start) / duration, 0.0), 1.0)
            angle += change * u * u * (3.0 - 2.0 * u)
            rate += change * 6.0 * u * (1.0 - u) / duration
        return angle, rate

    def base_at(self, t: float) -> BaseMotion:
        """The base (clamp point A, needle along its x axis) at time t: travel along x, roll about x (built packed:
        finite and a unit quaternion by construction, so without BaseMotion's checks; once per time step)."""
        x, v = self.travel(t)
        roll, rate = self.roll_at(t)
        packed = np.zeros(19)  # [position, orientation (x, y, z, w), v, w, a, alpha]
        packed[0], packed[3], packed[6], packed[7], packed[10] = x, np.sin(0.5 * roll), np.cos(0.5 * roll), v, rate
        c, s = np.cos(roll), np.sin(roll)
        return BaseMotion.from_packed(packed, np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]))
