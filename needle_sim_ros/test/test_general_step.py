"""The general step (``Integrator.step``: scenarios, identification, ground truth, statics' users) is one step of
the compiled run where no contribution is state-dependent, and its wrench is the holder's load at rest."""
import numpy as np

from needle_sim_ros.model import BaseMotion, Gravity, PointLoad, integrators, solve_static
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import NeedleSimulation, model_builder_from_parameters

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
BASE = BaseMotion((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def test_the_general_step_is_one_compiled_call_and_holds_the_needle_and_its_load(monkeypatch):
    """A needle at rest in static equilibrium under gravity and a tip load stays there on the general path; each
    step after the first (which has no consistent accelerations yet) is one call of the compiled run, and the
    wrench on the holder is the weight plus the load (independent truth: the needle's mass from its geometry)."""
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    load = PointLoad(model.props.length, np.array([0.0, 0.0, -0.05]))
    start = solve_static(model, BASE, [Gravity(), load], newton_tol=1e-12).state
    simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, lambda t: BASE, start, [load])
    simulation.compiled_sequence = False  # every step on the general path
    calls = []
    original = integrators.step_to
    monkeypatch.setattr(integrators, "step_to", lambda *args: calls.append(1) or original(*args))
    records = simulation.advance_to(0.02)
    assert len(records) == 20 and len(calls) == 19
    props = model.props
    mass = props.density * np.pi * (props.radius ** 2 - props.inner_radius ** 2) * props.length
    weight = mass * np.asarray(props.gravity)
    for record in records:
        np.testing.assert_allclose(record.wrench.force_world, weight + load.vector, rtol=1e-6, atol=1e-9)
    assert np.abs(simulation.state.q - start.q).max() < 1e-9


def test_a_prescribed_base_on_the_general_path_is_taken_as_it_comes_with_the_same_bits():
    """With every step on the general path a prescribed base's motions go to the steps as base_at returns them (not
    packed and unpacked: the state carries base_at's own object, whose packed buffer holds its six fields), and the
    steps and wrenches are those of Integrator.step with each end time's motion, bit for bit."""
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    made = []

    def base_at(t: float) -> BaseMotion:  # pitching about y at 2 rad/s^2
        angle = t * t
        made.append(BaseMotion((0.0, 0.0, 0.0), (0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)),
                               angular_velocity=(0.0, 2.0 * t, 0.0), angular_acceleration=(0.0, 2.0, 0.0)))
        return made[-1]

    start = model.straight_state(base_at(0.0), 0.0)
    simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, base_at, start)
    simulation.compiled_sequence = False
    records = simulation.advance_to(0.03)
    base = simulation.base
    assert len(records) == 30 and any(base is motion for motion in made)
    np.testing.assert_array_equal(base.packed, np.concatenate(
        (base.position, base.orientation, base.linear_velocity, base.angular_velocity, base.linear_acceleration,
         base.angular_acceleration)))
    reference, state, forces = model_builder_from_parameters(PARAMETERS)()[1], start, simulation.forces
    for k in range(1, 31):
        result = reference.step(state, 1e-3, base_at(k * 1e-3), forces)
        state = result.state
        if result.wrench is not None:  # the first step (no consistent accelerations yet) computes none
            np.testing.assert_array_equal(records[k - 1].wrench.values, result.wrench.values)
    np.testing.assert_array_equal(simulation.state.q, state.q)
    np.testing.assert_array_equal(simulation.state.qd, state.qd)
