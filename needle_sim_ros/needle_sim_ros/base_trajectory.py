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
from needle_sim_ros.model.records import compiled_entry


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
    """One measured base pose: time [s], position [m] and unit quaternion (x, y, z, w), world frame."""

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

    _offer = None  # _offer_sample compiled for its arguments' types (every trajectory's), made at the first offer

    def __init__(self, limits: TrajectoryLimits = TrajectoryLimits(), capacity: int = 256) -> None:
        self.limits = limits
        self._rejected: list[PoseSample] = []
        self.latest_time: float | None = None  # stamp [s] of the newest sample
        # [samples, corrections, fit rows (3, 0 with fewer than 3 samples in the window, -1: refit due)]
        self._counts = np.array([0, 0, -1], dtype=np.int64)
        self._served = np.array([-np.inf])  # latest time whose motion was served (the integrator's history)
        self._checks = np.array([limits.max_position, limits.quaternion_tolerance, limits.max_position_jump,
                                 limits.max_orientation_jump])
        # The arguments of trajectory_motions before the times, the same arrays (changed in place) for good: the
        # newest samples (at least ``capacity``, at most twice that), oldest first; the C2 corrections still fading
        # out (module docstring), oldest first: previous minus current served [position, velocity, acceleration,
        # rotation vector (world), angular velocity, angular acceleration] (k, 6, 3), start times, blend lengths [s];
        # the fit (refitted once a sample arrived); the counts; the served time, the motion then, a scratch motion.
        self.buffers = (np.empty(2 * capacity), np.empty((2 * capacity, 3)), np.empty((2 * capacity, 4)),
                        np.zeros((CORRECTION_CAPACITY, 6, 3)), np.zeros(CORRECTION_CAPACITY),
                        np.ones(CORRECTION_CAPACITY), np.zeros((3, 6)), self._counts, self._served,
                        np.empty((1, 19)), np.empty((1, 19)), float(limits.window), float(limits.max_extrapolation))
        self._held = (*self.buffers[:3], self._counts, self._served, self._checks)  # _offer_sample's, for good

    @property
    def latest(self) -> PoseSample | None:
        """The newest sample (a copy), None before the first."""
        count = self._counts[SAMPLES]
        if not count:
            return None
        times, positions, orientations = self.buffers[:3]
        return PoseSample(float(times[count - 1]), positions[count - 1].copy(), orientations[count - 1].copy())

    def clear(self) -> None:
        _forget(self._counts, self._served)
        self._rejected.clear()
        self.latest_time = None

    def offer(self, t: float, position, orientation, gap: float = np.inf, resume_tolerance: float = 0.0) -> PoseVerdict:
        """Validate a pose sample and add it to the buffer; the verdict says what happened and why. A pose more
        than ``gap`` [s] after the newest and farther than ``resume_tolerance`` [m] from it starts the trajectory
        anew there (RESTARTED)."""
        # Own, writable, contiguous copies: a view of a message buffer (read-only) would make numba compile every
        # kernel that takes a sample a second time, at the node's first pose.
        position = np.array(position, dtype=float)
        orientation = np.array(orientation, dtype=float)
        t = float(t)
        arguments = (*self._held, t, position, orientation, float(gap), float(resume_tolerance))
        if BaseTrajectory._offer is None:  # the types hold: the arrays made in __init__ and here, floats
            BaseTrajectory._offer = compiled_entry(_offer_sample, *arguments)
        verdict = VERDICTS[BaseTrajectory._offer(*arguments)]
        if verdict is PoseVerdict.JUMP:
            return self._handle_jump(PoseSample(t, position, orientation))  # the unit quaternion now
        if verdict in ADDED:
            self._rejected.clear()
            self.latest_time = t
        return verdict

    def _handle_jump(self, sample: PoseSample) -> PoseVerdict:
        rejected = self._rejected
        if rejected and not _within_jump_limits(*_pose_deviation(rejected[-1].position, rejected[-1].orientation,
                                                                 sample.position, sample.orientation), self._checks):
            rejected.clear()
        rejected.append(sample)
        if len(rejected) < self.limits.reanchor_after:
            return PoseVerdict.JUMP
        kept = list(rejected)
        self.clear()
        for pose in kept:
            _append_sample(*self.buffers[:3], self._counts, pose.t, pose.position, pose.orientation)
        self.latest_time = sample.t
        return PoseVerdict.REANCHORED

    def motions_at(self, times: np.ndarray) -> np.ndarray:
        """Smoothed motion at each of the given times (k,), packed (k, 19) as [position, orientation (x, y, z, w),
        linear velocity, angular velocity, linear acceleration, angular acceleration] (world frame, SI).

        Within the window the quadratic least-squares fit is evaluated (interpolation). Beyond the newest sample
        the fit is extrapolated for at most ``max_extrapolation``; after that the pose is held with zero velocity
        and acceleration. With fewer than 3 samples in the window: the newest pose, at rest. ValueError before the
        first sample.
        """
        times = np.asarray(times, dtype=float)
        out = np.empty((len(times), 19))
        trajectory_motions(*self.buffers, times, out)
        return out


SAMPLES, CORRECTIONS, FIT_ROWS = 0, 1, 2  # BaseTrajectory's counts
CORRECTION_CAPACITY = 128  # corrections kept at once (up to ~window / sample interval); beyond, the oldest is dropped
VERDICTS = tuple(PoseVerdict)  # by the code _offer_sample returns
# the codes of _offer_sample's verdicts: their indices in VERDICTS (numba reads the globals as constants)
_ACCEPTED, _NORMALIZED, _NOT_FINITE, _ZERO_QUATERNION, _OUT_OF_ORDER, _JUMP, _OUT_OF_RANGE, _RESTARTED = (
    VERDICTS.index(PoseVerdict[name]) for name in ("ACCEPTED", "NORMALIZED", "NOT_FINITE", "ZERO_QUATERNION",
                                                   "OUT_OF_ORDER", "JUMP", "OUT_OF_RANGE", "RESTARTED"))
ADDED = (PoseVerdict.ACCEPTED, PoseVerdict.NORMALIZED, PoseVerdict.RESTARTED)  # the verdicts of an added sample


@njit(cache=True)
def _forget(counts: np.ndarray, served: np.ndarray) -> None:
    """No sample, no fit, no correction, nothing served."""
    counts[SAMPLES], counts[CORRECTIONS], counts[FIT_ROWS] = 0, 0, -1
    served[0] = -np.inf


@njit(cache=True)
def _append_sample(sample_times: np.ndarray, positions: np.ndarray, orientations: np.ndarray, counts: np.ndarray,
                   t: float, position: np.ndarray, orientation: np.ndarray) -> None:
    """Add the newest sample (a full buffer keeps its newest half first); its fit is due."""
    count = counts[SAMPLES]
    if count == sample_times.size:
        capacity = count // 2
        sample_times[:capacity] = sample_times[capacity:count]
        positions[:capacity] = positions[capacity:count]
        orientations[:capacity] = orientations[capacity:count]
        count = capacity
    sample_times[count] = t
    positions[count] = position
    orientations[count] = orientation
    counts[SAMPLES], counts[FIT_ROWS] = count + 1, -1


@njit(cache=True)
def _offer_sample(sample_times: np.ndarray, positions: np.ndarray, orientations: np.ndarray, counts: np.ndarray,
                  served: np.ndarray, checks: np.ndarray, t: float, position: np.ndarray, orientation: np.ndarray,
                  gap: float, resume_tolerance: float) -> int:
    """The code (index in :data:`VERDICTS`) of a pose sample offered to the trajectory, added if accepted
    (:meth:`BaseTrajectory.offer`; ``checks``: max_position, quaternion_tolerance, max_position_jump,
    max_orientation_jump); JUMP: beyond the jump limits, for the caller to keep. ``orientation`` (the caller's own
    copy) becomes the unit quaternion in place."""
    count = counts[SAMPLES]
    latest = max(count - 1, 0)  # (row 0 unread without a sample)
    has_latest = count > 0
    norm, rescaled, largest, distance, angle = _checked_pose(t, position, orientation, positions[latest],
                                                             orientations[latest], has_latest)
    if not norm >= 0.0:
        return _NOT_FINITE
    if norm < 1e-9:
        return _ZERO_QUATERNION
    if largest > checks[0]:  # per axis: no overflow for huge finite values
        return _OUT_OF_RANGE
    verdict = _ACCEPTED if abs(norm - 1.0) <= checks[1] and not rescaled else _NORMALIZED
    if has_latest:
        t_latest = sample_times[latest]
        if t <= t_latest:
            return _OUT_OF_ORDER
        # Compare with the last sample rather than an extrapolation: a long gap must not turn into a jump.
        if not _within_jump_limits(distance, angle, checks):
            return _JUMP
        if t - t_latest > gap and distance > resume_tolerance:
            _forget(counts, served)
            verdict = _RESTARTED
    _append_sample(sample_times, positions, orientations, counts, t, position, orientation)
    return verdict


@njit(cache=True)
def _within_jump_limits(distance: float, angle: float, checks: np.ndarray) -> bool:
    return distance <= checks[2] and angle <= checks[3]


@njit(cache=True)
def trajectory_motions(sample_times: np.ndarray, positions: np.ndarray, orientations: np.ndarray, deltas: np.ndarray,
                       starts: np.ndarray, blends: np.ndarray, fit: np.ndarray, counts: np.ndarray,
                       served: np.ndarray, served_motion: np.ndarray, scratch: np.ndarray, window: float,
                       max_extrapolation: float, times: np.ndarray, out: np.ndarray) -> None:
    """Packed motions at ``times`` into ``out`` (:meth:`BaseTrajectory.motions_at`; the arguments before the times:
    :attr:`BaseTrajectory.buffers`) from the fit, fitted anew first if a sample arrived since
    (:func:`_refit_window`); the latest time served and the motion then are kept (``served``, ``served_motion``)."""
    count = counts[SAMPLES]
    if count == 0:
        raise ValueError("no base pose sample yet")
    t_newest, p_newest, q_newest = sample_times[count - 1], positions[count - 1], orientations[count - 1]
    refit = counts[FIT_ROWS] < 0
    if refit:
        _refit_window(sample_times, positions, orientations, count, window, max_extrapolation, deltas, starts,
                      blends, fit, counts, served, served_motion, scratch)
    coeffs = fit[:counts[FIT_ROWS]]
    _evaluate_motions(coeffs, t_newest, p_newest, q_newest, max_extrapolation, deltas, starts, blends,
                      counts[CORRECTIONS], times, out)
    latest = np.argmax(times) if times.size else 0
    if times.size and times[latest] > served[0]:
        served[0] = times[latest]
        served_motion[0] = out[latest]
    elif refit and served[0] > -np.inf:  # the new fit's motion at the time served
        _evaluate_motions(coeffs, t_newest, p_newest, q_newest, max_extrapolation, deltas, starts, blends,
                          counts[CORRECTIONS], served, served_motion)


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
def _refit_window(sample_times: np.ndarray, positions: np.ndarray, orientations: np.ndarray, count: int,
                  window: float, max_extrapolation: float, deltas: np.ndarray, starts: np.ndarray,
                  blends: np.ndarray, fit: np.ndarray, counts: np.ndarray, served: np.ndarray,
                  served_motion: np.ndarray, scratch: np.ndarray) -> None:
    """The fit and corrections of the window ending at the newest sample (one call per new sample), in place.

    Fit: quadratic least-squares coefficients (3, 6) of [position, rotation vector] in tau = t - t_newest, no rows
    with fewer than 3 samples in the window. Once a motion was served, the corrections (``deltas``, ``starts``,
    ``blends``) lose those that have ended by the served time and gain the difference then between the served
    motion and the new one (the new fit, with the same corrections); otherwise there are none."""
    t_newest, p_newest, q_newest = sample_times[count - 1], positions[count - 1], orientations[count - 1]
    first = np.searchsorted(sample_times[:count], t_newest - window)
    rows = 0 if count - first < 3 else 3
    if rows:
        _fit_samples(sample_times[first:count], t_newest, positions[first:count], orientations[first:count],
                     q_newest, max(window, 1e-9), fit)
    counts[FIT_ROWS] = rows
    at = served[0]
    if at == -np.inf:
        counts[CORRECTIONS] = 0
        return
    corrections = counts[CORRECTIONS]
    _evaluate_motions(fit[:rows], t_newest, p_newest, q_newest, max_extrapolation, deltas, starts, blends,
                      corrections, served, scratch)
    kept = 0
    for k in range(corrections):  # the steps still to come end after served; a full list drops its oldest
        if starts[k] + blends[k] > at and not (k == 0 and corrections == deltas.shape[0]):
            deltas[kept], starts[kept], blends[kept] = deltas[k], starts[k], blends[k]
            kept += 1
    interval = (t_newest - sample_times[first]) / max(count - 1 - first, 1)
    _motion_difference(served_motion[0], scratch[0], deltas[kept])
    starts[kept], blends[kept] = at, min(max(t_newest - at, interval), window)
    counts[CORRECTIONS] = kept + 1


@njit(cache=True)
def _quaternion_norm(t: float, position: np.ndarray, orientation: np.ndarray) -> float:
    """|orientation|, or NaN if any of t, position, orientation is not finite."""
    nan_if_not_finite = (t + np.sum(position) + np.sum(orientation)) * 0.0  # inf * 0 and NaN * 0 are NaN
    x, y, z, w = orientation[0], orientation[1], orientation[2], orientation[3]
    return np.sqrt(x * x + y * y + z * z + w * w) + nan_if_not_finite  # no temporary array


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
    for i in range(4):  # no temporary array
        orientation[i] /= norm
    distance, angle = _pose_deviation(p_latest, q_latest, position, orientation) if has_latest else (0.0, 0.0)
    return norm, rescaled, largest, distance, angle


@njit(cache=True)
def _pose_deviation(p_ref: np.ndarray, q_ref: np.ndarray, p: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """(distance [m], rotation angle [rad]) between two poses."""
    rotation = to_rotation_vector(multiply(conjugate(q_ref), q))
    dx, dy, dz = p[0] - p_ref[0], p[1] - p_ref[1], p[2] - p_ref[2]
    return np.sqrt(dx * dx + dy * dy + dz * dz), np.sqrt(dot3(rotation, rotation))


@njit(cache=True)
def _fit_samples(times: np.ndarray, t_newest: float, positions: np.ndarray, orientations: np.ndarray,
                 reference: np.ndarray, scale: float, coeffs: np.ndarray) -> None:
    """Fit of [position, rotation vector relative to ``reference``] at tau = times - t_newest into ``coeffs``
    (see :func:`_quadratic_fit`)."""
    inverse = conjugate(reference)
    coeffs[:, :] = 0.0  # the right-hand sides first
    s0 = s1 = s2 = s3 = s4 = 0.0
    for k in range(times.size):
        x = (times[k] - t_newest) / scale
        x2 = x * x
        x3 = x2 * x
        s0, s1, s2, s3, s4 = s0 + 1.0, s1 + x, s2 + x2, s3 + x3, s4 + x3 * x
        rotation = to_rotation_vector(multiply(inverse, orientations[k]))
        for column in range(6):  # no temporary array per sample and power
            value = positions[k, column] if column < 3 else rotation[column - 3]
            coeffs[0, column] += value
            coeffs[1, column] += x * value
            coeffs[2, column] += x2 * value
    _quadratic_fit(s0, s1, s2, s3, s4, scale, coeffs)


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
def _motion_difference(previous: np.ndarray, current: np.ndarray, delta: np.ndarray) -> None:
    """Packed motion ``previous`` minus ``current`` as the (6, 3) correction rows ``delta`` of
    :func:`_apply_correction`; the rotation as the world-frame rotation vector from the current to the previous
    orientation."""
    rotation = to_rotation_vector(multiply(previous[3:7], conjugate(current[3:7])))
    for j in range(3):  # scalar: no temporary arrays
        for row, at in ((0, 0), (1, 7), (2, 13), (4, 10), (5, 16)):
            delta[row, j] = previous[at + j] - current[at + j]
        delta[3, j] = rotation[j]


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
        c, c1, c2 = np.empty((3, 3))  # only here: most corrections have faded at most times
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
def _quadratic_fit(a: float, b: float, c: float, d: float, e: float, scale: float, coeffs: np.ndarray) -> None:
    """Coefficients c (3, m) of the least-squares quadratic values ~ c0 + c1 tau + c2 tau^2, in place of the
    right-hand sides ``coeffs`` (sum x^p values, p = 0, 1, 2) of the normal equations in x = tau / scale (scale =
    window length: the 3 x 3 system is well conditioned) with the normal matrix [[a, b, c], [b, c, d], [c, d, e]]
    (sums of x^0 ... x^4)."""
    # symmetric 3 x 3 inverse by cofactors (the normal matrix of >= 3 distinct times is positive definite)
    i00, i01, i02 = c * e - d * d, c * d - b * e, b * d - c * c
    i11, i12, i22 = a * e - c * c, b * c - a * d, a * c - b * b
    determinant = a * i00 + b * i01 + c * i02
    u0, u1, u2 = 1.0 / (determinant * scale ** 0), 1.0 / (determinant * scale ** 1), 1.0 / (determinant * scale ** 2)
    for column in range(coeffs.shape[1]):  # scalar: a 3 x m product through BLAS costs more than the whole fit
        r0, r1, r2 = coeffs[0, column], coeffs[1, column], coeffs[2, column]
        coeffs[0, column] = u0 * (i00 * r0 + i01 * r1 + i02 * r2)
        coeffs[1, column] = u1 * (i01 * r0 + i11 * r1 + i12 * r2)
        coeffs[2, column] = u2 * (i02 * r0 + i12 * r1 + i22 * r2)
