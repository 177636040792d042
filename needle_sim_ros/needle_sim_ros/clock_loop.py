"""The simulator's clock loop: which steps to take at a clock time, on which grid (ROS-free).

A :class:`ClockLoop` decides the time the model should reach and hands the end times of the steps up to it to its
:class:`~needle_sim_ros.stepper.Stepper`. It is the one time loop that integrates the needle: the node feeds poses
and advances it from its real-time loop, the offline pipeline does the same over a bag, and the scenarios, the
ground truth of the sample bags and the benchmarks advance a prescribed base to their sample times.

Timing rules (:meth:`ClockLoop.target_time`):
* live: integrate up to now, extrapolating the newest pose for at most ``max_extrapolation``;
* live, ahead to the pose: also integrate the step that ends at or after the newest pose's stamp (at most one step
  past the clock; its base motion is the fit extrapolated by less than dt), so a pose's wrench is out as soon as
  the pose is in, without waiting for the step's end time. The step grid then follows the phase of the pose
  stream (:meth:`ClockLoop.lock_phase`): once the poses arrive at a consistent phase (a robot at a fixed
  rate), the grid is shifted so that the steps end half a step after them, and each pose is in a step of its own
  even with jitter up to half a step (on a grid through the poses, half of them would fall just after a step end
  and find their step already integrated by the clock, or push the next one a step ahead);
* deterministic (simulated time, offline): integrate up to min(now, newest pose stamp), so poses are always
  interpolated and the result depends on the recorded data only — unless the input timed out, then up to now
  holding the last pose.
A lag of more than ``max_catch_up`` is not integrated (:meth:`ClockLoop.advance_to`).
"""
from __future__ import annotations

import cmath
import math
from dataclasses import replace

import numpy as np

from needle_sim_ros.stepper import Stepper, StepRecord

# Phase lock of the step grid to the pose stream (live, ahead to the pose): the running mean of the poses' phase
# phasor weighs each new pose by PHASE_SMOOTHING (~1/0.01 = 100 poses); the grid is shifted once the mean's length
# (1 for poses at one phase; 0.23 for a uniform jitter of +-0.4 steps; ~0.07 for poses at random phases) is at
# least PHASE_COHERENCE and its phase more than PHASE_TOLERANCE steps from mid-step.
PHASE_SMOOTHING = 0.01
PHASE_COHERENCE = 0.15
PHASE_TOLERANCE = 0.15
# How long [steps] past its end time the live loop's clock waits for a late pose before it integrates a step that no
# pose reached (half a step made more deadline misses on the benchmark's VM).
LATE_POSE_WAIT = 0.25


class ClockLoop:
    """Target time, step grid (in the stepper's data: origin, index, the poses' phase), phase lock and catch-up of
    one stepper; ``pose_timeout`` [s]: how long the newest pose holds the deterministic loop back."""

    def __init__(self, stepper: Stepper, max_catch_up: float = 0.05, pose_timeout: float = 0.1) -> None:
        self.stepper = stepper
        self.data, self.dt = stepper.data, stepper.dt  # the stepper's (never replaced)
        self.max_catch_up = max_catch_up
        self.pose_timeout = pose_timeout

    def restart(self, t: float) -> None:
        """A new step grid from t (the needle (re)started then)."""
        data = self.data
        data.grid_origin, data.step_index, data.pose_phase = float(t), 0, 0j

    def pose_arrived(self, t: float) -> None:
        """Count a pose stamped ``t`` that its step was integrated before, and add it to the poses' phase."""
        data = self.data
        if t <= data.time:
            self.stepper.statistics.late_poses += 1
        x = (float(t) - data.grid_origin) / self.dt
        data.pose_phase += PHASE_SMOOTHING * (cmath.exp(2j * math.pi * (x - math.floor(x))) - data.pose_phase)

    def target_time(self, now: float, deterministic: bool, ahead_to_pose: bool, latest: float | None) -> float:
        """Time the model should reach at clock time ``now`` with the newest pose stamped ``latest`` (None: no
        pose; module docstring)."""
        if deterministic and latest is not None and now - latest <= self.pose_timeout:
            return min(now, latest)
        if ahead_to_pose and latest is not None and latest > now - self.dt:
            # grid indices (a pose within 1 us after a step's end time counts as at it: epoch-time resolution)
            data, dt = self.data, self.dt
            to_pose = math.ceil((latest - data.grid_origin) / dt - 1e-3)
            after_now = math.floor((now - data.grid_origin) / dt + 1e-3) + 1
            return max(now, self.grid_time(min(to_pose, after_now)))
        return now

    def lock_phase(self) -> None:
        """Shift the step grid so that its steps end half a step after the poses' mean phase (``pose_phase``), if
        the poses come at a consistent phase (:data:`PHASE_COHERENCE`) more than :data:`PHASE_TOLERANCE` steps from
        mid-step. The next step then lasts (1 + shift) dt, shift in [-0.5, 0.5); the later ones dt."""
        data = self.data
        if abs(data.pose_phase) < PHASE_COHERENCE:
            return
        mean = cmath.phase(data.pose_phase) / (2.0 * math.pi)  # the poses' mean phase after the step ends
        shift = (mean - 0.5) - math.floor(mean)  # mean - 0.5 wrapped to [-0.5, 0.5)
        if abs(shift) > PHASE_TOLERANCE:
            data.grid_origin += shift * self.dt
            data.pose_phase *= cmath.exp(-2j * math.pi * shift)

    def advance_to(self, t_target: float, source) -> list[StepRecord]:
        """Integrate with fixed steps of dt until the next step would pass t_target, the base from ``source``.

        If the simulation lags more than ``max_catch_up`` behind, the skipped interval is not integrated: the
        state jumps forward in time (shape and velocities kept) and the skipped time is counted.
        """
        data, dt = self.data, self.dt
        if not data.started:
            return []
        lag = t_target - data.time
        if lag > self.max_catch_up:
            skip = math.floor((lag - self.max_catch_up) / dt)
            data.step_index += skip
            data.state = replace(data.state, t=self.grid_time(data.step_index))
            self.stepper.statistics.skipped_time += skip * dt
        # steps whose end time reaches t_target up to the float resolution of the times (0.24 us at epoch times)
        slack = 4.0 * math.ulp(abs(t_target)) + 1e-9 * dt
        count = math.floor((t_target + slack - data.grid_origin) / dt) - data.step_index
        if count <= 0:
            return []
        times, origin, first = np.empty(count), data.grid_origin, data.step_index + 1
        for j in range(count):  # grid_time: cheaper than an array of a list (the live loop's count is 1)
            times[j] = origin + dt * (first + j)
        return self.stepper.run(times, source, t_target)

    @property
    def next_step_end(self) -> float:
        """End time [s] of the next step on the grid (a shifted grid's next step is shorter or longer than dt)."""
        return self.grid_time(self.data.step_index + 1)

    def grid_time(self, index):
        """End time of step ``index`` since the (re)start: origin + index dt, rounded once (no accumulation: at
        epoch times a sum of 1 ms steps would drift by 70 ns per step)."""
        return self.data.grid_origin + self.dt * index
