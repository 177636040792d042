"""Wrench error of a batch row against closed forms: linear model force, constant reference; empty without one."""
import numpy as np
import pytest

from needle_sim_ros.offline.results import PipelineLog, WrenchSeries, wrench_differences

NS = 1_000_000_000


def series(times_s, force, torque):
    return WrenchSeries(np.asarray(times_s) * NS, np.asarray(force, float), np.asarray(torque, float))


def test_wrench_error_interpolates_the_model_at_the_reference_stamps():
    t = np.arange(11.0)
    model = series(t, np.column_stack([t, 0 * t, 0 * t]), np.column_stack([0 * t, 2 * t, 0 * t]))
    reference = series([0.5, 1.5, 20.0], np.eye(3), np.zeros((3, 3)))  # 20 s: outside the model's span
    force, torque, reference_force = wrench_differences(PipelineLog(0, wrench=model, truth_wrench=reference))
    np.testing.assert_allclose(force, [[-0.5, 0.0, 0.0], [1.5, -1.0, 0.0]])
    np.testing.assert_array_equal(reference_force, np.eye(3)[:2])
    np.testing.assert_allclose(torque[:, 1], [1.0, 3.0])
    assert np.sqrt(np.mean(np.sum(force ** 2, axis=1))) == pytest.approx(np.sqrt((0.25 + 2.25 + 1.0) / 2))


def test_no_reference_wrench_gives_no_wrench_error():
    t = np.arange(3.0)
    model = series(t, np.zeros((3, 3)), np.zeros((3, 3)))
    assert wrench_differences(PipelineLog(0, wrench=model)) is None
    assert wrench_differences(PipelineLog(0, wrench=model, truth_wrench=series([9.0], np.zeros((1, 3)),
                                                                                 np.zeros((1, 3))))) is None
