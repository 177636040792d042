"""Base-pose input of the simulator: validation, buffering, interpolation and smooth derivatives.

Poses of the needle holder arrive at 100-1000 Hz with jitter and noise. The integrator needs the base pose and
its first two time derivatives at every step time (they prescribe q_c, q̇_c, q̈_c of seed 000, eqs. 18-20).
Raw finite differences of noisy poses would put the noise, amplified by 1/dt², into q̈_c and hence into the
reaction wrench. Instead a quadratic is fitted by least squares to the samples of a short window (position, and
the rotation vector relative to the newest orientation), and pose, velocity and acceleration are evaluated from
it at the step time. A quadratic reproduces constant-acceleration motion exactly, so the fit adds no lag for
such motion.

Each new sample changes the fit, so the fit's value at the last time already served to the integrator moves by up
to the fit residual (~0.5 um for a cosine speed ramp sampled at 200 Hz). A prescribed base that jumps by that much
rings the axially stiff needle (EA/L ~ 1e6 N/m) and the reaction wrench chatters. A new fit therefore comes with
a correction that continues the previously served motion at that time in position, velocity and acceleration (C2)
and fades out with a quintic blend by the new newest sample (at least one mean sample interval, at most
``window``): the served motion stays twice continuously differentiable. It is the current fit plus every
correction still fading out, and a new correction makes up only for the change of the fit (and the hold): it
never restates the earlier ones. (Restating them, one correction that replaced the last, was unstable when samples
came ahead of the served time: each restated correction faded faster than the one before, and with 1 kHz poses
integrated at a 200 Hz clock the served base oscillated with 1e6 rad/s^2 and most steps failed.)

ROS-free: :class:`~needle_sim_ros.base_input.BaseInput` offers it the poses and asks
:meth:`BaseTrajectory.motions_at`.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

import numpy as np
from numba import njit

from needle_common.transforms import conjugate, from_rotation_vector, multiply, quaternion_matrix, to_rotation_vector
from needle_sim_ros.model.kinematics import dot3


class PoseVerdict(Enum):
    """Outcome of offering a pose sample to the trajectory (documented behaviour of each)."""

    ACCEPTED = "accepted"
    NORMALIZED = "accepted after normalizing a non-unit quaternion"
    NOT_FINITE = "rejected: NaN or infinite field"
    ZERO_QUATERNION = "rejected: zero-length quaternion"
    OUT_OF_ORDER = "rejected: stamp not newer than the previous pose"
    JUMP = "rejected: jump beyond the configured limit"
    REANCHORED = "accepted: trajectory re-anchored after consistent jumped poses"
    OUT_OF_RANGE = "rejected: a position coordinate beyond +-pose_input.max_position"
    RESTARTED = "accepted after a gap in the input, away from the held pose: needle restarted at rest there"


class PoseSample(NamedTuple):
    """One measured base pose: time [s], position [m] and unit quaternion (x, y, z, w), world frame (a tuple: one
    is made per pose, at up to 1 kHz)."""

    t: float
    position: np.ndarray
    orientation: np.ndarray


@dataclass(frozen=True)
class TrajectoryLimits:
    """Parameters of the pose input (names match the node parameters under ``pose_input.``)."""

    window: float = 0.02  # [s] length of the least-squares window
    max_extrapolation: float = 0.01  # [s] beyond the newest sample the pose is held
    max_position_jump: float = 0.02  # [m] largest accepted deviation from the predicted position
    max_orientation_jump: float = 0.2  # [rad] largest accepted deviation from the predicted orientation
    reanchor_after: int = 10  # consecutive mutually consistent jumped poses that re-anchor the trajectory
    quaternion_tolerance: float = 1e-3  # |1 - |q|| above which a normalization warning is raised
    max_position: float = 100.0  # [m] largest accepted |x|, |y|, |z| of a pose (working volume)


class BaseTrajectory:
    """Buffer of recent base poses with smooth evaluation at any time."""

    def __init__(self, limits: TrajectoryLimits = TrajectoryLimits(), capacity: int = 256) -> None:
        self.limits = limits
        # The newest samples (at least ``capacity``, at most twice that) as arrays, oldest first, for the fit.
        self._capacity = capacity
        self._times = np.empty(2 * capacity)
        self._positions = np.empty((2 * capacity, 3))
        self._orientations = np.empty((2 * capacity, 4))
        self._count = 0
        self._latest: PoseSample | None = None
        self._rejected: list[PoseSample] = []
        self._fit: np.ndarray | None = None  # quadratic coefficients, recomputed only when a sample arrives
        self._served: float | None = None  # latest time whose motion was served (the integrator's history)
        # The C2 corrections still fading out (module docstring), oldest first: the differences (previous minus
        # current served motion) of [position, velocity, acceleration, rotation vector (world), angular velocity,
        # angular acceleration] at their start times, (k, 6, 3), the start times and blend lengths [s]
        self._corrections = np.zeros((CORRECTION_CAPACITY, 6, 3))
        self._correction_starts = np.zeros(CORRECTION_CAPACITY)
        self._correction_blends = np.ones(CORRECTION_CAPACITY)
        self._correction_count = 0
        self._previous: tuple[PoseSample, np.ndarray] | None = None  # newest sample and fit of the previous fit
        # the first 8 arguments of trajectory_motions: the same arrays (changed in place) and limits for good
        self.buffers = (self._times, self._positions, self._orientations, self._corrections, self._correction_starts,
                        self._correction_blends, float(limits.window), float(limits.max_extrapolation))

    @property
    def latest(self) -> PoseSample | None:
        return self._latest

    def clear(self) -> None:
        self._count = 0
        self._latest = None
        self._rejected.clear()
        self._fit = None
        self._served = None
        self._correction_count = 0
        self._previous = None

    def _append(self, sample: PoseSample) -> None:
        if self._count == self._times.size:  # full: keep the newest half
            keep = slice(self._count - self._capacity, self._count)
            for array in (self._times, self._positions, self._orientations):
                array[:self._capacity] = array[keep]
            self._count = self._capacity
        i = self._count
        self._times[i], self._positions[i], self._orientations[i] = sample.t, sample.position, sample.orientation
        self._count += 1
        self._latest = sample
        self._fit = None

    def offer(self, t: float, position, orientation) -> PoseVerdict:
        """Validate a pose sample and add it to the buffer; the verdict says what happened and why."""
        # Own, writable, contiguous copies: a view of a message buffer (read-only) would make numba compile every
        # kernel that takes a sample a second time, at the node's first pose.
        position = np.array(position, dtype=float)
        orientation = np.array(orientation, dtype=float)
        t = float(t)
        latest, limits = self._latest, self.limits
        reference = latest if latest is not None else _ORIGIN
        norm, rescaled, largest, distance, angle = _checked_pose(
            t, position, orientation, reference.position, reference.orientation, latest is not None)
        if not norm >= 0.0:
            return PoseVerdict.NOT_FINITE
        if norm < 1e-9:
            return PoseVerdict.ZERO_QUATERNION
        if largest > limits.max_position:  # per axis: no overflow for huge finite values
            return PoseVerdict.OUT_OF_RANGE
        verdict = PoseVerdict.ACCEPTED if abs(norm - 1.0) <= limits.quaternion_tolerance and not rescaled \
            else PoseVerdict.NORMALIZED
        sample = PoseSample(t, position, orientation)  # the unit quaternion now
        if latest is not None:
            if t <= latest.t:
                return PoseVerdict.OUT_OF_ORDER
            # Compare with the last sample rather than an extrapolation: a long gap must not turn into a jump.
            if not self._within_limits(distance, angle):
                return self._handle_jump(sample)
        self._rejected.clear()
        self._append(sample)
        return verdict

    def _deviation(self, reference: PoseSample, sample: PoseSample) -> tuple[float, float]:
        return _pose_deviation(reference.position, reference.orientation, sample.position, sample.orientation)

    def _within_limits(self, distance: float, angle: float) -> bool:
        return distance <= self.limits.max_position_jump and angle <= self.limits.max_orientation_jump

    def _handle_jump(self, sample: PoseSample) -> PoseVerdict:
        if self._rejected and not self._within_limits(*self._deviation(self._rejected[-1], sample)):
            self._rejected.clear()
        self._rejected.append(sample)
        if len(self._rejected) < self.limits.reanchor_after:
            return PoseVerdict.JUMP
        rejected = list(self._rejected)
        self.clear()
        for kept in rejected:
            self._append(kept)
        return PoseVerdict.REANCHORED

    def motions_at(self, times: np.ndarray) -> np.ndarray:
        """Smoothed motion at each of the given times (k,), packed (k, 19) as [position, orientation (x, y, z, w),
        linear velocity, angular velocity, linear acceleration, angular acceleration] (world frame, SI).

        Within the window the quadratic least-squares fit is evaluated (interpolation). Beyond the newest sample
        the fit is extrapolated for at most ``max_extrapolation``; after that the pose is held with zero velocity
        and acceleration. With fewer than 3 samples in the window: the newest pose, at rest.
        """
        times = np.asarray(times, dtype=float)
        out = np.empty((len(times), 19))
        fit, corrections = trajectory_motions(*self.buffers, *self.fit_state(), times, out)
        self.take_fit(fit, corrections, float(times.max()) if times.size else None)
        return out

    def fit_state(self) -> tuple:
        """The 13 arguments of :func:`trajectory_motions` between :attr:`buffers` and the times: the newest sample,
        the current fit (or none, to fit the window ending at the newest sample anew: refit once per new sample,
        continuing the previously served motion at the last served time) and the number of corrections.
        ValueError before the first sample."""
        newest = self._latest
        if newest is None:
            raise ValueError("no base pose sample yet")
        refit = self._fit is None
        continued = refit and self._served is not None and self._previous is not None
        previous_sample, previous_fit = self._previous if continued else (newest, _NO_FIT)
        return (self._count, newest.t, newest.position, newest.orientation, _NO_FIT if refit else self._fit, refit,
                continued, self._served if continued else 0.0, previous_sample.t, previous_sample.position,
                previous_sample.orientation, previous_fit, self._correction_count)

    def take_fit(self, fit: np.ndarray, corrections: int, served: float | None) -> None:
        """Keep what :func:`trajectory_motions` returned after serving the motions at times up to ``served`` (None:
        at no time)."""
        if self._fit is None:
            self._previous = (self._latest, fit)
        self._fit, self._correction_count = fit, corrections
        if served is not None and (self._served is None or served > self._served):
            self._served = served


_NO_FIT = np.zeros((0, 6))
CORRECTION_CAPACITY = 128  # corrections kept at once (up to ~window / sample interval); beyond, the oldest is dropped


@njit(cache=True)
def trajectory_motions(sample_times: np.ndarray, positions: np.ndarray, orientations: np.ndarray, deltas: np.ndarray,
                       starts: np.ndarray, blends: np.ndarray, window: float, max_extrapolation: float, count: int,
                       t_newest: float, p_newest: np.ndarray, q_newest: np.ndarray, fit: np.ndarray, refit: bool,
                       continued: bool, served: float, t_previous: float, p_previous: np.ndarray,
                       q_previous: np.ndarray, previous_fit: np.ndarray, corrections: int, times: np.ndarray,
                       out: np.ndarray) -> tuple[np.ndarray, int]:
    """Packed motions at ``times`` into ``out`` (:meth:`BaseTrajectory.motions_at`) from the fit, fitted anew first
    if ``refit`` (:func:`_refit_window`); returns (fit, number of corrections)."""
    if refit:
        fit, corrections = _refit_window(sample_times, positions, orientations, count, t_newest, p_newest, q_newest,
                                         window, max_extrapolation, continued, served, t_previous, p_previous,
                                         q_previous, previous_fit, deltas, starts, blends, corrections)
    _evaluate_motions(fit, t_newest, p_newest, q_newest, max_extrapolation, deltas, starts, blends, corrections,
                      times, out)
    return fit, corrections


@njit(cache=True)
def _evaluate_motions(coeffs: np.ndarray, t_newest: float, p_newest: np.ndarray, q_newest: np.ndarray,
                      max_extrapolation: float, deltas: np.ndarray, starts: np.ndarray, blends: np.ndarray,
                      corrections: int, times: np.ndarray, out: np.ndarray) -> None:
    """Packed motions at ``times`` of the fit ``coeffs`` of the window ending at the newest sample, plus the first
    ``corrections`` C2 corrections (see :func:`_apply_correction`)."""
    _evaluate_fit(coeffs, t_newest, p_newest, q_newest, max_extrapolation, times, out)
    for k in range(corrections):
        _apply_correction(deltas[k], starts[k], blends[k], t_newest + max_extrapolation, times, out)


@njit(cache=True)
def _refit_window(times: np.ndarray, positions: np.ndarray, orientations: np.ndarray, count: int, t_newest: float,
                  p_newest: np.ndarray, q_newest: np.ndarray, window: float, max_extrapolation: float,
                  continued: bool, served: float, t_previous: float, p_previous: np.ndarray, q_previous: np.ndarray,
                  previous_fit: np.ndarray, deltas: np.ndarray, starts: np.ndarray, blends: np.ndarray,
                  corrections: int) -> tuple[np.ndarray, int]:
    """(fit, number of corrections) of the window ending at the newest sample (one call per new sample).

    Fit: quadratic least-squares coefficients (3, 6) of [position, rotation vector] in tau = t - t_newest, (0, 6)
    with fewer than 3 samples in the window. If ``continued``, the corrections (``deltas``, ``starts``, ``blends``,
    changed in place) lose those that have ended by ``served`` and gain the difference at ``served``
    between the previous served motion (previous newest sample and fit, with the corrections) and the new one (the
    new fit, with the same corrections); otherwise there are none."""
    first = np.searchsorted(times[:count], t_newest - window)
    if count - first < 3:
        fit = np.zeros((0, 6))
    else:
        fit = _fit_samples(times[first:count] - t_newest, positions[first:count], orientations[first:count],
                           q_newest, max(window, 1e-9))
    if not continued:
        return fit, 0
    at = np.array([served])
    previous, current = np.empty((1, 19)), np.empty((1, 19))
    _evaluate_motions(previous_fit, t_previous, p_previous, q_previous, max_extrapolation, deltas, starts, blends,
                      corrections, at, previous)
    _evaluate_motions(fit, t_newest, p_newest, q_newest, max_extrapolation, deltas, starts, blends, corrections,
                      at, current)
    kept = 0
    for k in range(corrections):  # the steps still to come end after served; a full list drops its oldest
        if starts[k] + blends[k] > served and not (k == 0 and corrections == deltas.shape[0]):
            deltas[kept], starts[kept], blends[kept] = deltas[k], starts[k], blends[k]
            kept += 1
    interval = (t_newest - times[first]) / max(count - 1 - first, 1)
    deltas[kept] = _motion_difference(previous[0], current[0])
    starts[kept], blends[kept] = served, min(max(t_newest - served, interval), window)
    return fit, kept + 1


@njit(cache=True)
def _quaternion_norm(t: float, position: np.ndarray, orientation: np.ndarray) -> float:
    """|orientation|, or NaN if any of t, position, orientation is not finite."""
    nan_if_not_finite = (t + np.sum(position) + np.sum(orientation)) * 0.0  # inf * 0 and NaN * 0 are NaN
    return np.sqrt(np.sum(orientation ** 2)) + nan_if_not_finite


_ORIGIN = PoseSample(0.0, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))  # reference before the first sample


@njit(cache=True)
def _checked_pose(t: float, position: np.ndarray, orientation: np.ndarray, p_latest: np.ndarray,
                  q_latest: np.ndarray, has_latest: bool) -> tuple[float, bool, float, float, float]:
    """A pose sample checked in one call: (|orientation| after rescaling, NaN if any field is not finite; whether
    the orientation was rescaled because |q|^2 would overflow; largest |position coordinate|; distance and rotation
    angle from the latest sample, 0 without one or for an invalid sample). A valid sample's ``orientation`` (the
    caller's own copy) becomes the unit quaternion in place: no array is made, none returned."""
    scale = np.max(np.abs(orientation))
    rescaled = 1e100 < scale < np.inf  # |q|^2 would overflow: a non-unit quaternion like any other
    if rescaled:
        orientation[:] = orientation / scale
    norm = _quaternion_norm(t, position, orientation)
    largest = np.max(np.abs(position))
    if not norm >= 1e-9:
        return norm, rescaled, largest, 0.0, 0.0
    orientation[:] = orientation / norm
    distance, angle = _pose_deviation(p_latest, q_latest, position, orientation) if has_latest else (0.0, 0.0)
    return norm, rescaled, largest, distance, angle


@njit(cache=True)
def _pose_deviation(p_ref: np.ndarray, q_ref: np.ndarray, p: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """(distance [m], rotation angle [rad]) between two poses."""
    rotation = to_rotation_vector(multiply(conjugate(q_ref), q))
    dx, dy, dz = p[0] - p_ref[0], p[1] - p_ref[1], p[2] - p_ref[2]
    return np.sqrt(dx * dx + dy * dy + dz * dz), np.sqrt(dot3(rotation, rotation))


@njit(cache=True)
def _fit_samples(tau: np.ndarray, positions: np.ndarray, orientations: np.ndarray, reference: np.ndarray,
                 scale: float) -> np.ndarray:
    """Fit of [position, rotation vector relative to ``reference``] at times tau (see :func:`_quadratic_fit`)."""
    values = np.empty((tau.size, 6))
    inverse = conjugate(reference)
    for k in range(tau.size):
        values[k, :3] = positions[k]
        values[k, 3:] = to_rotation_vector(multiply(inverse, orientations[k]))
    return _quadratic_fit(tau, values, scale)


@njit(cache=True)
def _evaluate_fit(coeffs: np.ndarray, t_newest: float, p_newest: np.ndarray, q_newest: np.ndarray,
                  max_extrapolation: float, times: np.ndarray, out: np.ndarray) -> None:
    """Packed motions (BaseTrajectory.motions_at) from the fit coefficients (3, 6) or (0, 6)."""
    out[:, :] = 0.0
    rotation = quaternion_matrix(q_newest)
    value = np.empty(6)
    for i in range(times.size):
        if coeffs.shape[0] < 3:
            out[i, 0:3] = p_newest
            out[i, 3:7] = q_newest
            continue
        tau = min(times[i], t_newest + max_extrapolation) - t_newest
        for j in range(6):
            value[j] = coeffs[0, j] + coeffs[1, j] * tau + coeffs[2, j] * tau * tau
        out[i, 0:3] = value[:3]
        out[i, 3:7] = multiply(q_newest, from_rotation_vector(value[3:]))
        if times[i] > t_newest + max_extrapolation:
            continue  # held: at rest
        # Within a 20 ms window the relative rotation is small, so the world angular velocity is R_ref d(phi)/dt up
        # to O(|phi|) terms (the exact map is the right Jacobian of SO(3), identity at phi = 0).
        for j in range(3):
            out[i, 7 + j] = coeffs[1, j] + 2.0 * coeffs[2, j] * tau
            out[i, 13 + j] = 2.0 * coeffs[2, j]
            for k in range(3):
                out[i, 10 + j] += rotation[j, k] * (coeffs[1, 3 + k] + 2.0 * coeffs[2, 3 + k] * tau)
                out[i, 16 + j] += rotation[j, k] * (2.0 * coeffs[2, 3 + k])


@njit(cache=True)
def _motion_difference(previous: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Packed motion ``previous`` minus ``current`` as the (6, 3) correction rows of :func:`_apply_correction`; the
    rotation as the world-frame rotation vector from the current to the previous orientation."""
    delta = np.empty((6, 3))
    delta[0] = previous[0:3] - current[0:3]
    delta[1] = previous[7:10] - current[7:10]
    delta[2] = previous[13:16] - current[13:16]
    delta[3] = to_rotation_vector(multiply(previous[3:7], conjugate(current[3:7])))
    delta[4] = previous[10:13] - current[10:13]
    delta[5] = previous[16:19] - current[16:19]
    return delta


@njit(cache=True)
def _apply_correction(delta: np.ndarray, start: float, blend: float, hold_time: float, times: np.ndarray,
                      out: np.ndarray) -> None:
    """Add c(tau) = (d0 + d1 tau + d2 tau^2 / 2) g(tau), tau = t - start, to the packed motions ``out`` (position and
    world rotation vector, with their first two derivatives), g = 1 - (10 x^3 - 15 x^4 + 6 x^5), x = tau / blend:
    c, c', c'' equal the differences at tau = 0 and vanish from tau = blend on. Held (at rest) times are left."""
    for i in range(times.size):
        tau = times[i] - start
        if tau < 0.0 or tau >= blend or times[i] > hold_time:
            continue
        c, c1, c2 = np.empty(3), np.empty(3), np.empty(3)  # only here: most corrections have faded at most times
        x = tau / blend
        g = 1.0 - x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
        g1 = -30.0 * x * x * (1.0 - x) * (1.0 - x) / blend
        g2 = -60.0 * x * (1.0 - x) * (1.0 - 2.0 * x) / (blend * blend)
        for block in range(2):
            for j in range(3):  # scalar: no temporary arrays per time
                d0, d1, d2 = delta[3 * block, j], delta[3 * block + 1, j], delta[3 * block + 2, j]
                value = d0 + d1 * tau + 0.5 * d2 * tau * tau
                rate = d1 + d2 * tau
                c[j], c1[j], c2[j] = value * g, rate * g + value * g1, d2 * g + 2.0 * rate * g1 + value * g2
            if block == 0:
                out[i, 0:3] += c
                out[i, 7:10] += c1
                out[i, 13:16] += c2
            else:
                out[i, 3:7] = multiply(from_rotation_vector(c), out[i, 3:7])
                out[i, 10:13] += c1
                out[i, 16:19] += c2


@njit(cache=True)
def _quadratic_fit(times: np.ndarray, values: np.ndarray, scale: float) -> np.ndarray:
    """Coefficients c (3, m) of the least-squares quadratic values ~ c0 + c1 tau + c2 tau^2.

    Normal equations in tau / scale (scale = window length), so the 3 x 3 system is well conditioned.
    """
    # normal matrix [[s0, s1, s2], [s1, s2, s3], [s2, s3, s4]] (s_k = sum x^k) and right-hand sides
    x = times / scale
    s = np.zeros(5)
    rhs = np.zeros((3, values.shape[1]))
    for k in range(x.size):
        power = 1.0
        for p in range(5):
            s[p] += power
            if p < 3:
                for column in range(values.shape[1]):  # no temporary array per sample and power
                    rhs[p, column] += power * values[k, column]
            power *= x[k]
    # symmetric 3 x 3 inverse by cofactors (the normal matrix of >= 3 distinct times is positive definite)
    a, b, c, d, e = s[0], s[1], s[2], s[3], s[4]
    inverse = np.array([[c * e - d * d, c * d - b * e, b * d - c * c],
                        [c * d - b * e, a * e - c * c, b * c - a * d],
                        [b * d - c * c, b * c - a * d, a * c - b * b]])
    determinant = a * inverse[0, 0] + b * inverse[1, 0] + c * inverse[2, 0]
    coeffs = np.empty((3, values.shape[1]))
    for row in range(3):  # scalar: a 3 x m product through BLAS costs more than the whole fit
        unscale = 1.0 / (determinant * scale ** row)
        for column in range(values.shape[1]):
            coeffs[row, column] = unscale * (inverse[row, 0] * rhs[0, column] + inverse[row, 1] * rhs[1, column]
                                             + inverse[row, 2] * rhs[2, column])
    return coeffs
