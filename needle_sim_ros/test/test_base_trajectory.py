"""Base-pose input: exact for constant-acceleration motion, smooth under noise, defined on bad input."""
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from needle_sim_ros.base_input import BaseInput
from needle_sim_ros.base_trajectory import BaseTrajectory, PoseVerdict, TrajectoryLimits
from needle_sim_ros.model import BaseMotion

ACCEL = np.array([0.3, -0.2, 0.1])
VEL0 = np.array([0.05, 0.02, -0.01])
OMEGA = np.array([0.0, 0.4, 0.0])  # constant angular velocity [rad/s] about world y


def pose(t: float):
    position = np.array([0.4, 0.0, 0.3]) + VEL0 * t + 0.5 * ACCEL * t**2
    orientation = Rotation.from_rotvec(OMEGA * t).as_quat()
    return position, orientation


def motion_at(trajectory: BaseTrajectory, t: float) -> SimpleNamespace:
    """The packed motion at t (``motions_at``) by name; ``extrapolated``: t beyond the newest sample."""
    m = trajectory.motions_at(np.array([t]))[0]
    return SimpleNamespace(position=m[0:3], orientation=m[3:7], linear_velocity=m[7:10], angular_velocity=m[10:13],
                           linear_acceleration=m[13:16], angular_acceleration=m[16:19],
                           extrapolated=t > trajectory.latest.t)


def filled(rate_hz=1000.0, duration=0.05, jitter=0.0, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    trajectory = BaseTrajectory(TrajectoryLimits(window=0.02))
    for k in range(int(duration * rate_hz)):
        t = k / rate_hz + jitter * rng.uniform(-0.5, 0.5) / rate_hz
        p, q = pose(t)
        assert trajectory.offer(t, p + noise * rng.standard_normal(3), q) is PoseVerdict.ACCEPTED
    return trajectory


def test_constant_acceleration_motion_is_reproduced_exactly_between_jittered_samples():
    trajectory = filled(rate_hz=250.0, jitter=0.3)
    t = 0.0371
    m = motion_at(trajectory, t)
    p, q = pose(t)
    # Exact up to round-off: a quadratic fit reproduces a quadratic trajectory whatever the sample times.
    np.testing.assert_allclose(m.position, p, atol=1e-12)
    np.testing.assert_allclose(m.linear_velocity, VEL0 + ACCEL * t, atol=1e-9)
    np.testing.assert_allclose(m.linear_acceleration, ACCEL, atol=1e-6)
    # A constant-rate rotation about a fixed axis is linear in the rotation vector: exact as well.
    assert (Rotation.from_quat(m.orientation).inv() * Rotation.from_quat(q)).magnitude() < 1e-9
    np.testing.assert_allclose(m.angular_velocity, OMEGA, atol=1e-9)
    np.testing.assert_allclose(m.angular_acceleration, 0.0, atol=1e-6)


def test_noisy_poses_give_bounded_acceleration():
    noise = 1e-5  # 10 um position noise, typical of a robot's reported tool pose
    trajectory = filled(noise=noise)
    m = motion_at(trajectory, 0.049)
    # Raw second differences at 1 kHz would scatter by ~ noise * sqrt(6) / dt^2 = 24 m/s^2. The 20-sample
    # quadratic fit must stay within a small fraction of that: 3 m/s^2 is 8x better than finite differences.
    assert np.linalg.norm(m.linear_acceleration - ACCEL) < 3.0


def test_beyond_the_newest_sample_the_pose_is_extrapolated_then_held():
    trajectory = filled(duration=0.05)
    newest = trajectory.latest.t
    short = motion_at(trajectory, newest + 0.005)
    assert short.extrapolated
    np.testing.assert_allclose(short.position, pose(newest + 0.005)[0], atol=1e-9)
    held = motion_at(trajectory, newest + 1.0)
    np.testing.assert_allclose(held.position, pose(newest + 0.01)[0], atol=1e-9)  # held at max_extrapolation
    assert np.all(held.linear_velocity == 0) and np.all(held.angular_acceleration == 0)


@pytest.mark.parametrize(
    "position, orientation, verdict",
    [
        ([np.nan, 0, 0], [0, 0, 0, 1], PoseVerdict.NOT_FINITE),
        ([0.4, 0, 0.3], [0, 0, np.inf, 1], PoseVerdict.NOT_FINITE),
        ([0.4, 0, 0.3], [0, 0, 0, 0], PoseVerdict.ZERO_QUATERNION),
        ([0.4, 0, 0.3], [0, 0, 0, 2.0], PoseVerdict.NORMALIZED),
        ([0.9, 0, 0.3], [0, 0, 0, 1], PoseVerdict.JUMP),
        ([0.4, 0, 0.3], [0, 1, 0, 0], PoseVerdict.JUMP),
    ],
)
def test_bad_poses_get_their_verdict(position, orientation, verdict):
    trajectory = BaseTrajectory()
    assert trajectory.offer(0.0, [0.4, 0, 0.3], [0, 0, 0, 1]) is PoseVerdict.ACCEPTED
    assert trajectory.offer(0.001, position, orientation) is verdict
    if verdict is PoseVerdict.NORMALIZED:
        np.testing.assert_allclose(np.linalg.norm(trajectory.latest.orientation), 1.0)
    else:
        assert trajectory.latest.t == 0.0  # rejected samples never enter the buffer



@pytest.mark.parametrize("orientation, unit", [([0.0, 0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0]),
                                               ([0.0, 0.0, 3e200, 3e200], [0.0, 0.0, 0.5 ** 0.5, 0.5 ** 0.5])])
def test_a_normalized_pose_leaves_the_callers_arrays_as_they_were(orientation, unit):
    """The check normalizes the trajectory's own copy in place (also one whose |q|^2 would overflow): the caller's
    arrays (a message's) are not touched, and the sample is the unit quaternion (written out by hand)."""
    position, given = np.array([0.4, 0.0, 0.3]), np.array(orientation)
    trajectory = BaseTrajectory()
    assert trajectory.offer(0.0, position, given) is PoseVerdict.NORMALIZED
    assert given.tolist() == orientation and position.tolist() == [0.4, 0.0, 0.3]
    np.testing.assert_allclose(trajectory.latest.orientation, unit, rtol=0.0, atol=1e-15)
    assert trajectory.latest.orientation is not given

def test_out_of_order_and_duplicate_stamps_are_rejected():
    trajectory = BaseTrajectory()
    trajectory.offer(1.0, [0, 0, 0], [0, 0, 0, 1])
    assert trajectory.offer(1.0, [0, 0, 0], [0, 0, 0, 1]) is PoseVerdict.OUT_OF_ORDER
    assert trajectory.offer(0.5, [0, 0, 0], [0, 0, 0, 1]) is PoseVerdict.OUT_OF_ORDER


def test_consistent_jumped_poses_reanchor_the_trajectory():
    limits = TrajectoryLimits(reanchor_after=5)
    trajectory = BaseTrajectory(limits)
    trajectory.offer(0.0, [0, 0, 0], [0, 0, 0, 1])
    verdicts = [trajectory.offer(0.001 * (k + 1), [0.5, 0, 0], [0, 0, 0, 1]) for k in range(5)]
    assert verdicts[:4] == [PoseVerdict.JUMP] * 4 and verdicts[4] is PoseVerdict.REANCHORED
    np.testing.assert_allclose(motion_at(trajectory, 0.005).position, [0.5, 0, 0])


def test_a_small_buffer_wraps_around_without_losing_the_window():
    trajectory = BaseTrajectory(TrajectoryLimits(window=0.02), capacity=8)
    for k in range(100):  # the buffer holds 8 to 16 samples: the 20 ms window at 1 kHz is cut to the newest ones
        p, q = pose(k * 1e-3)
        assert trajectory.offer(k * 1e-3, p, q) is PoseVerdict.ACCEPTED
    m = motion_at(trajectory, 0.0985)
    np.testing.assert_allclose(m.position, pose(0.0985)[0], atol=1e-12)
    np.testing.assert_allclose(m.linear_acceleration, ACCEL, atol=1e-6)


def test_served_motion_stays_continuous_when_new_samples_change_the_fit():
    """A cosine speed ramp (not quadratic) sampled at 200 Hz and served at 1 kHz up to the newest sample, as the
    offline pipeline steps: each new sample changes the fit by up to ~0.5 um where the last step was served. The
    served pose must continue smoothly (the C2 correction), checked against its own served velocity by the
    trapezoid rule, and stay within 1 um / 20 urad of the exact motion. Without the correction the trapezoid
    mismatch was 8.6e-4 m/s (a jump of ~1 um in one step)."""
    speed, ramp, rate = 0.02, 0.1, 20.0  # [m/s], [s], [rad/m]: the rotation about z follows the travel

    def travel(t: float) -> float:
        x = np.clip(t - 0.1, 0.0, ramp)
        return speed * (0.5 * (x - ramp / np.pi * np.sin(np.pi * x / ramp)) + max(t - 0.1 - ramp, 0.0))

    trajectory = BaseTrajectory(TrajectoryLimits(window=0.02))
    served = []
    for k in range(61):
        t_sample = 0.005 * k
        angle = rate * travel(t_sample)
        trajectory.offer(t_sample, [travel(t_sample), 0.0, 0.0], [0.0, 0.0, np.sin(angle / 2), np.cos(angle / 2)])
        if k:
            times = t_sample - 0.001 * np.arange(4, -1, -1)
            served += [(t, m[0], 2 * np.arctan2(m[5], m[6]), m[7], m[12]) for t, m in
                       zip(times, trajectory.motions_at(times))]
    t, x, angle, v, omega = np.array(served).T
    exact = np.array([travel(s) for s in t])
    assert np.abs(x - exact).max() < 1e-6
    assert np.abs(angle - rate * exact).max() < 2e-5
    dt = np.diff(t)
    assert np.abs(np.diff(x) / dt - 0.5 * (v[1:] + v[:-1])).max() < 1e-4
    assert np.abs(np.diff(angle) / dt - 0.5 * (omega[1:] + omega[:-1])).max() < 2e-3


@pytest.mark.parametrize("clock_hz", [200.0, 100.0, 40.0])
def test_served_motion_stays_exact_when_samples_come_ahead_of_the_served_time(clock_hz):
    """A 1 kHz pose stream in simulated time, integrated tick by tick of a /clock at 40-200 Hz: at each tick the
    samples up to the next tick are in, ahead of the 1 ms steps served up to this tick (a bag played with
    ``--clock``). Against the exact derivatives of the motion (10 deg pitch at 0.5 Hz, 5 mm/s advance). Before,
    the single restated correction fed on itself: at 100 and 200 Hz the served pose grew to 1e15-1e57 m."""
    amplitude, w = np.radians(10.0), np.pi

    def flange(t: float):
        return (np.array([0.4 + 0.005 * t, 0.0, 0.3]),
                Rotation.from_rotvec([0.0, amplitude * np.sin(w * t), 0.0]).as_quat())

    trajectory = BaseTrajectory(TrajectoryLimits(window=0.02))
    served, k, step = [], 0, 0
    for tick in np.arange(1, int(2.0 * clock_hz)) / clock_hz:
        while k * 1e-3 < tick + 1.0 / clock_hz - 1e-12:
            assert trajectory.offer(k * 1e-3, *flange(k * 1e-3)) is PoseVerdict.ACCEPTED
            k += 1
        times = np.arange(step + 1, int(round(tick * 1e3)) + 1) * 1e-3
        step += times.size
        served += [(t, m) for t, m in zip(times, trajectory.motions_at(times)) if t > 0.1]
    t = np.array([s[0] for s in served])
    m = np.array([s[1] for s in served])
    position = np.array([flange(s)[0] for s in t])
    np.testing.assert_allclose(m[:, 0:3], position, atol=1e-9)
    np.testing.assert_allclose(m[:, 7:10], [[0.005, 0.0, 0.0]] * len(t), atol=1e-9)
    np.testing.assert_allclose(m[:, 13:16], 0.0, atol=1e-6)
    angular_velocity = amplitude * w * np.cos(w * t)
    angular_acceleration = -amplitude * w * w * np.sin(w * t)
    assert np.abs(m[:, 11] - angular_velocity).max() < 2e-3 and np.abs(m[:, [10, 12]]).max() < 1e-9
    # the quadratic fit of the 20 ms before the newest sample, evaluated up to 25 ms behind it (40 Hz): 0.45 rad/s^2
    # of the 1.7 rad/s^2 amplitude; 0.05 at 100-200 Hz
    assert np.abs(m[:, 17] - angular_acceleration).max() < (0.6 if clock_hz < 100 else 0.08)


def test_the_received_poses_reach_the_clamp_by_the_one_flange_offset_composition():
    """The node's base input and BaseMotion.from_flange (checked against finite differences in
    test_model_kinematics) compose the flange-to-clamp offset alike."""
    offset = (np.array([0.02, -0.01, 0.15]), Rotation.from_euler("zyx", [0.3, -0.2, 0.5]).as_quat())
    source = BaseInput(filled(), offset)
    clamp = source.motion_at(0.037)
    flange = motion_at(source.trajectory, 0.037)
    expected = BaseMotion.from_flange(flange.position, flange.orientation, *offset, flange.linear_velocity,
                                      flange.angular_velocity, flange.linear_acceleration, flange.angular_acceleration)
    np.testing.assert_allclose(clamp.packed, expected.packed, rtol=0.0, atol=1e-14)
    np.testing.assert_allclose(clamp.rotation, expected.rotation, rtol=0.0, atol=1e-14)
