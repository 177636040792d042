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
