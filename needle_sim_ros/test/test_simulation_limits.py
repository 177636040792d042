"""The simulator core's documented input limits (issue 15): point-load bound, working volume, twist speeds, restart
after a gap, no non-finite output."""
import math

import numpy as np
import pytest

from needle_sim_ros.base_trajectory import PoseVerdict
from needle_common.parameters import ParameterError

from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import POINT_LOAD_LIMIT, max_point_load, simulation_from_parameters, step_wrenches

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def started(**overrides):
    p = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
    p.update(overrides)
    sim = simulation_from_parameters(p)
    sim.max_catch_up = math.inf
    sim.offer_pose(0.0, np.zeros(3), IDENTITY)
    return sim


def test_the_bound_is_20_EI_over_L_squared():
    sim = started()
    props = sim.model.props
    bending = props.youngs_modulus * math.pi * props.radius**4 / 4 / props.length**2
    assert max_point_load(props) == pytest.approx(POINT_LOAD_LIMIT * bending) == pytest.approx(6.76, abs=0.01)


@pytest.mark.parametrize("direction", [(0.0, 0.0, -1.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
def test_a_load_at_the_bound_applied_at_once_integrates_without_a_failed_step(direction):
    sim = started()
    sim.set_point_load("tip", sim.model.props.length, max_point_load(sim.model.props) * np.array(direction))
    records = sim.advance_to(0.3)
    assert len(records) == 300 and sim.statistics.failed_steps == 0
    assert len(list(step_wrenches(records))) == 300  # every wrench finite


def test_loads_beyond_the_bound_are_refused_and_the_sum_counts():
    sim = started()
    limit = max_point_load(sim.model.props)
    with pytest.raises(ValueError, match="exceeds"):
        sim.set_point_load("a", 0.27, np.array([0.0, 0.0, -1.01 * limit]))
    with pytest.raises(ValueError, match="exceeds"):
        sim.set_point_load("a", 0.27, np.array([0.0, 0.0, 1e308]))
    sim.set_point_load("a", 0.27, np.array([0.0, 0.0, -0.6 * limit]))
    with pytest.raises(ValueError, match="with the other loads"):
        sim.set_point_load("b", 0.1, np.array([0.0, 0.6 * limit, 0.0]))
    sim.set_point_load("a", 0.27, np.array([0.0, 0.0, -0.9 * limit]))  # replacing a load counts it once


def test_positions_outside_the_working_volume_and_fast_twists_are_refused():
    sim = started()
    assert sim.offer_pose(0.001, np.array([1e150, 0.0, 0.0]), IDENTITY) is PoseVerdict.OUT_OF_RANGE
    assert sim.offer_pose(0.001, np.array([0.0, 1e308, 0.0]), IDENTITY) is PoseVerdict.OUT_OF_RANGE
    assert sim.offer_pose(0.001, np.zeros(3), np.array([0.0, 0.0, 0.0, 1e200])) is PoseVerdict.NORMALIZED
    with pytest.raises(ValueError, match="max_angular_speed"):
        sim.set_twist(0.001, np.zeros(3), np.array([0.0, 0.0, 1e6]))
    with pytest.raises(ValueError, match="max_linear_speed"):
        sim.set_twist(0.001, np.array([1e308, 1e308, 0.0]), np.zeros(3))
    assert sim.twist is None
    records = sim.advance_to(0.05)
    assert len(list(step_wrenches(records))) == len(records) == 50


def test_a_pose_after_a_gap_away_from_the_held_pose_restarts_the_needle():
    sim = started()
    for k in range(1, 20):
        sim.offer_pose(k * 1e-3, np.zeros(3), IDENTITY)
    sim.advance_to(0.019)
    assert sim.offer_pose(3.0, np.array([0.015, 0.0, 0.0]), IDENTITY) is PoseVerdict.RESTARTED
    assert sim.state.t == 3.0 and np.allclose(sim.base.position, [0.015, 0.0, 0.0])
    records = sim.advance_to(3.1)
    force = np.array([r.wrench.force_base for r in records])
    assert np.abs(force).max() < 0.1  # the weight (0.027 N) and no spike
    # Within the tolerance after a gap: the trajectory goes on (no restart).
    assert sim.offer_pose(4.0, np.array([0.0155, 0.0, 0.0]), IDENTITY) is PoseVerdict.ACCEPTED


@pytest.mark.parametrize("interval", [[0.1, 0.5], [-0.01, 0.1]])
def test_a_clamp_interval_off_the_needle_is_a_parameter_error(interval):
    """Before, it passed the parameter check and failed at the node's configure with an unnamed exception."""
    p = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
    p["fixtures.clamp_interval"] = interval
    with pytest.raises(ParameterError, match=r"'fixtures.clamp_interval' = .* <= needle.length = 0.27 m"):
        simulation_from_parameters(p)
