"""Base-pose input of the simulator: validation, buffering, interpolation and smooth derivatives.

Poses of the needle holder arrive at 100-1000 Hz with jitter and noise. The integrator needs the base pose and
its first two time derivatives at every step time (they prescribe q_c, q̇_c, q̈_c of seed 000, eqs. 18-20).
Raw finite differences of noisy poses would put the noise, amplified by 1/dt², into q̈_c and hence into the
reaction wrench. Instead a quadratic is fitted by least squares to the samples of a short window (position, and
the rotation vector relative to the newest orientation), and pose, velocity and acceleration are evaluated from
it at the step time. A quadratic reproduces constant-acceleration motion exactly, so the fit adds no lag for
such motion.

ROS-free: the node converts messages into :class:`PoseSample` and asks :meth:`BaseTrajectory.motion_at`.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum

import numpy as np
from numba import njit

from needle_sim_ros import quaternion


class PoseVerdict(Enum):
    """Outcome of offering a pose sample to the trajectory (documented behaviour of each)."""

    ACCEPTED = "accepted"
    NORMALIZED = "accepted after normalizing a non-unit quaternion"
    NOT_FINITE = "rejected: NaN or infinite field"
    ZERO_QUATERNION = "rejected: zero-length quaternion"
    OUT_OF_ORDER = "rejected: stamp not newer than the previous pose"
    JUMP = "rejected: jump beyond the configured limit"
    REANCHORED = "accepted: trajectory re-anchored after consistent jumped poses"


@dataclass(frozen=True)
class PoseSample:
    """One measured base pose: time [s], position [m] and unit quaternion (x, y, z, w), world frame."""

    t: float
    position: np.ndarray
    orientation: np.ndarray


@dataclass(frozen=True)
class BaseKinematics:
    """Pose, velocity and acceleration of the base at one instant (world frame, SI)."""

    position: np.ndarray
    orientation: np.ndarray  # quaternion (x, y, z, w)
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    linear_acceleration: np.ndarray
    angular_acceleration: np.ndarray
    extrapolated: bool  # True when t lies beyond the newest sample


@dataclass(frozen=True)
class TrajectoryLimits:
    """Parameters of the pose input (names match the node parameters under ``pose_input.``)."""

    window: float = 0.02  # [s] length of the least-squares window
    max_extrapolation: float = 0.01  # [s] beyond the newest sample the pose is held
    max_position_jump: float = 0.02  # [m] largest accepted deviation from the predicted position
    max_orientation_jump: float = 0.2  # [rad] largest accepted deviation from the predicted orientation
    reanchor_after: int = 10  # consecutive mutually consistent jumped poses that re-anchor the trajectory
    quaternion_tolerance: float = 1e-3  # |1 - |q|| above which a normalization warning is raised


class BaseTrajectory:
    """Buffer of recent base poses with smooth evaluation at any time."""

    def __init__(self, limits: TrajectoryLimits = TrajectoryLimits(), capacity: int = 256) -> None:
        self.limits = limits
        self._samples: deque[PoseSample] = deque(maxlen=capacity)
        self._rejected: list[PoseSample] = []
        self._fit: np.ndarray | None = None  # quadratic coefficients, recomputed only when a sample arrives

    @property
    def latest(self) -> PoseSample | None:
        return self._samples[-1] if self._samples else None

    def clear(self) -> None:
        self._samples.clear()
        self._rejected.clear()
        self._fit = None

    def offer(self, t: float, position, orientation) -> PoseVerdict:
        """Validate a pose sample and add it to the buffer; the verdict says what happened and why."""
        position = np.asarray(position, dtype=float)
        orientation = np.asarray(orientation, dtype=float)
        if not (np.isfinite(t) and np.all(np.isfinite(position)) and np.all(np.isfinite(orientation))):
            return PoseVerdict.NOT_FINITE
        norm = float(np.linalg.norm(orientation))
        if norm < 1e-9:
            return PoseVerdict.ZERO_QUATERNION
        verdict = PoseVerdict.ACCEPTED if abs(norm - 1.0) <= self.limits.quaternion_tolerance else PoseVerdict.NORMALIZED
        sample = PoseSample(float(t), position, orientation / norm)
        latest = self.latest
        if latest is not None and sample.t <= latest.t:
            return PoseVerdict.OUT_OF_ORDER
        if latest is not None and self._is_jump(sample):
            return self._handle_jump(sample)
        self._rejected.clear()
        self._samples.append(sample)
        self._fit = None
        return verdict

    def _deviation(self, reference: BaseKinematics | PoseSample, sample: PoseSample) -> tuple[float, float]:
        dp = float(np.linalg.norm(sample.position - reference.position))
        relative = quaternion.multiply(quaternion.conjugate(reference.orientation), sample.orientation)
        return dp, float(np.linalg.norm(quaternion.to_rotation_vector(relative)))

    def _within_limits(self, deviation: tuple[float, float]) -> bool:
        return deviation[0] <= self.limits.max_position_jump and deviation[1] <= self.limits.max_orientation_jump

    def _is_jump(self, sample: PoseSample) -> bool:
        # Compare with the last sample rather than an extrapolation: a long gap must not turn into a jump.
        return not self._within_limits(self._deviation(self.latest, sample))

    def _handle_jump(self, sample: PoseSample) -> PoseVerdict:
        if self._rejected and not self._within_limits(self._deviation(self._rejected[-1], sample)):
            self._rejected.clear()
        self._rejected.append(sample)
        if len(self._rejected) < self.limits.reanchor_after:
            return PoseVerdict.JUMP
        self._samples.clear()
        self._samples.extend(self._rejected)
        self._rejected.clear()
        self._fit = None
        return PoseVerdict.REANCHORED

    def motion_at(self, t: float) -> BaseKinematics | None:
        """Smoothed pose, velocity and acceleration at time t; None before the first sample.

        Within the window the quadratic least-squares fit is evaluated (interpolation). Beyond the newest sample
        the fit is extrapolated for at most ``max_extrapolation``; after that the pose is held with zero velocity
        and acceleration.
        """
        if not self._samples:
            return None
        newest = self._samples[-1]
        extrapolated = t > newest.t
        held = t > newest.t + self.limits.max_extrapolation
        t_eval = min(t, newest.t + self.limits.max_extrapolation)
        if self._fit is None:
            self._fit = self._fit_window(newest)
        coeffs = self._fit
        if coeffs.shape[0] < 3:
            # Too few samples for derivatives: the newest pose, at rest.
            zero = np.zeros(3)
            return BaseKinematics(newest.position.copy(), newest.orientation.copy(), zero, zero, zero, zero, extrapolated)
        tau = t_eval - newest.t
        value = coeffs[0] + coeffs[1] * tau + coeffs[2] * tau**2
        rate = coeffs[1] + 2.0 * coeffs[2] * tau
        accel = 2.0 * coeffs[2]
        orientation = quaternion.multiply(newest.orientation, quaternion.from_rotation_vector(value[3:]))
        if held:
            zero = np.zeros(3)
            return BaseKinematics(value[:3], orientation, zero, zero, zero, zero, True)
        # Within a 20 ms window the relative rotation is small, so the world angular velocity is R_ref * d(phi)/dt
        # up to O(|phi|) terms (the exact map is the right Jacobian of SO(3), identity at phi = 0).
        r = quaternion.to_matrix(newest.orientation)
        return BaseKinematics(value[:3], orientation, rate[:3], r @ rate[3:], accel[:3], r @ accel[3:], extrapolated)

    def _fit_window(self, newest: PoseSample) -> np.ndarray:
        """Quadratic least-squares coefficients (3, 6) of [position, rotation vector] in tau = t - t_newest."""
        window = [s for s in self._samples if s.t >= newest.t - self.limits.window]
        if len(window) < 3:
            return np.zeros((0, 6))
        times = np.array([s.t for s in window]) - newest.t
        relative = quaternion.multiply(quaternion.conjugate(newest.orientation), np.array([s.orientation for s in window]))
        values = np.hstack([np.array([s.position for s in window]), quaternion.to_rotation_vector(relative)])
        return _quadratic_fit(times, values, max(self.limits.window, 1e-9))


@njit(cache=True)
def _quadratic_fit(times: np.ndarray, values: np.ndarray, scale: float) -> np.ndarray:
    """Coefficients c (3, m) of the least-squares quadratic values ~ c0 + c1 tau + c2 tau^2.

    Normal equations in tau / scale (scale = window length), so the 3 x 3 system is well conditioned.
    """
    x = times / scale
    design = np.empty((x.size, 3))
    design[:, 0] = 1.0
    design[:, 1] = x
    design[:, 2] = x * x
    coeffs = np.linalg.solve(design.T @ design, design.T @ values)
    coeffs[1] /= scale
    coeffs[2] /= scale * scale
    return coeffs
