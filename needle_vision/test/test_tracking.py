"""Velocity and acceleration of tracked centerlines against an exactly known motion."""
import numpy as np
import pytest

from needle_vision.matching.tracking import CenterlineTracker, TrackingConfig

ARC = np.linspace(0.0, 0.27, 271)


def shape_at(t: float) -> np.ndarray:
    """A needle translating with constant acceleration and bending with a constant-acceleration tip sweep."""
    xi = ARC / 0.27
    base = np.array([0.01, -0.02, 0.005]) * t + 0.5 * np.array([0.3, 0.1, -0.2]) * t ** 2
    bend = (0.02 * t + 0.5 * 0.8 * t ** 2) * xi ** 2
    return np.column_stack([ARC, np.zeros_like(ARC), bend]) + base


def truth(t: float) -> tuple[np.ndarray, np.ndarray]:
    xi = ARC / 0.27
    velocity = np.array([0.01, -0.02, 0.005]) + np.array([0.3, 0.1, -0.2]) * t
    acceleration = np.tile([0.3, 0.1, -0.2], (len(ARC), 1))
    velocity = np.tile(velocity, (len(ARC), 1))
    velocity[:, 2] += (0.02 + 0.8 * t) * xi ** 2
    acceleration[:, 2] += 0.8 * xi ** 2
    return velocity, acceleration


def test_constant_acceleration_motion_is_recovered_exactly():
    tracker = CenterlineTracker(TrackingConfig(window=5, max_gap=0.05))
    stamps = 1.0 + np.arange(8) / 220.0  # the paper's camera rate
    results = [tracker.update(t, ARC, shape_at(t)) for t in stamps]
    assert all(result is None for result in results[:4])  # the window fills first
    velocity, acceleration = truth(stamps[-1])
    # A quadratic fit reproduces quadratic motion: only rounding (positions ~0.3 m, dt² ~ 2e-5 s²) remains.
    np.testing.assert_allclose(results[-1].velocity, velocity, atol=1e-8)
    np.testing.assert_allclose(results[-1].acceleration, acceleration, atol=1e-4)


def test_noise_is_averaged_not_amplified():
    rng = np.random.default_rng(0)
    tracker = CenterlineTracker(TrackingConfig(window=9, max_gap=0.05))
    stamps = np.arange(12) / 220.0
    for t in stamps:
        result = tracker.update(t, ARC, shape_at(t) + rng.normal(0, 3e-5, (len(ARC), 3)))
    velocity, _ = truth(stamps[-1])
    # 30 µm noise: a finite difference over one frame would scatter by ~30e-6 * 220 * 1.4 = 9 mm/s; the
    # 9-frame quadratic fit keeps the end-point velocity error a few times smaller.
    assert np.std(result.velocity - velocity) < 4e-3


@pytest.mark.parametrize("second", [1.0, 0.5, 1.2])  # same stamp, backwards, gap > max_gap
def test_stamp_problems_restart_the_window(second):
    tracker = CenterlineTracker(TrackingConfig(window=3, max_gap=0.05))
    for t in (0.99, 0.995, 1.0):
        tracker.update(t, ARC, shape_at(t))
    assert tracker.update(second, ARC, shape_at(second)) is None


def test_window_below_three_frames_is_refused():
    with pytest.raises(ValueError, match="at least 3"):
        CenterlineTracker(TrackingConfig(window=2))
