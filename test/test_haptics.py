"""The haptic output's shaping without ROS (needle_sim_ros.haptics): limits, watchdog, resume ramp, frames."""
import math
from types import SimpleNamespace

import numpy as np

from needle_sim_ros.haptics import HapticShaper


def shaper(**overrides) -> HapticShaper:
    values = {"max_force": 3.0, "max_torque": 0.3, "pose_timeout": 0.02, "resume_ramp": 0.5} | overrides
    return HapticShaper(**values)


def test_saturation_scales_to_the_limit_keeping_the_direction_and_counts():
    s = shaper(resume_ramp=0.0)
    s.pose_arrived(10.0)
    # |(3, 4, 0)| = 5 N > 3 N: (1.8, 2.4, 0); |(0, 0.6, 0.8)| = 1 N m > 0.3: (0, 0.18, 0.24)
    (t, force, torque), = s.shape([(1.0, [3.0, 4.0, 0.0], [0.0, 0.6, 0.8])], 10.001)
    np.testing.assert_allclose(force, [1.8, 2.4, 0.0])
    np.testing.assert_allclose(torque, [0.0, 0.18, 0.24])
    assert (s.clipped_forces, s.clipped_torques) == (1, 1)
    (_, force, torque), = s.shape([(1.001, [0.1, -0.2, 0.3], [0.01, 0.0, 0.0])], 10.002)  # within: unchanged
    np.testing.assert_allclose(force, [0.1, -0.2, 0.3])
    np.testing.assert_allclose(torque, [0.01, 0.0, 0.0])
    assert (s.clipped_forces, s.clipped_torques) == (1, 1)


def test_the_watchdog_zeroes_after_the_timeout_and_ramps_back_linearly():
    s = shaper(pose_timeout=0.02, resume_ramp=0.5)
    wrench = [(0.0, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0])]
    assert next(s.shape(wrench, 0.0))[1] == (0.0, 0.0, 0.0)  # no pose yet
    for k in range(26):  # a steady stream (100 Hz) from 1.0 s: soft start from the first pose, half way at 1.25 s
        s.pose_arrived(1.0 + 0.01 * k)
    assert math.isclose(next(s.shape(wrench, 1.25))[1][0], 0.5)
    for k in range(26, 51):
        s.pose_arrived(1.0 + 0.01 * k)
    assert math.isclose(next(s.shape(wrench, 1.5))[1][0], 1.0)
    assert next(s.shape(wrench, 1.5 + 0.019))[1][0] == 1.0  # silent, but not for longer than the timeout
    assert next(s.shape(wrench, 1.5 + 0.021))[1] == (0.0, 0.0, 0.0)
    assert s.watchdog_trips == 1
    expected = {0: 0.0, 10: 0.2, 25: 0.5, 50: 1.0, 70: 1.0}  # back at 3.0 s: from zero, linearly over 0.5 s
    for k in range(71):
        s.pose_arrived(3.0 + 0.01 * k)
        if k in expected:
            assert math.isclose(next(s.shape(wrench, 3.0 + 0.01 * k))[1][0], expected[k], abs_tol=1e-9)
    assert s.watchdog_trips == 1


def test_a_non_finite_wrench_becomes_zero():
    s = shaper(resume_ramp=0.0)
    s.pose_arrived(0.0)
    (_, force, torque), = s.shape([(0.0, [math.nan, 0.0, 0.0], [0.0, 0.0, 0.0])], 0.001)
    assert force == torque == (0.0, 0.0, 0.0)


def test_the_frame_picks_the_world_or_the_holder_copy_of_the_wrench():
    wrench = SimpleNamespace(force_world=np.array([1.0, 2.0, 3.0]), torque_world=np.array([4.0, 5.0, 6.0]),
                             force_base=np.array([-1.0, -2.0, -3.0]), torque_base=np.array([-4.0, -5.0, -6.0]))
    records = [SimpleNamespace(t=1.5, wrench=wrench)]
    assert shaper(world_frame=True).frame_wrenches(records) == [(1.5, [1.0, 2.0, 3.0], [4.0, 5.0, 6.0])]
    assert shaper(world_frame=False).frame_wrenches(records) == [(1.5, [-1.0, -2.0, -3.0], [-4.0, -5.0, -6.0])]
