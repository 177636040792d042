"""The simulator's one time loop driven by a prescribed base motion (scenarios, ground truth, benchmarks): the
compiled sequence where it applies, agreement with stepping the general integrator by hand, failures raised, and
the mesh of ``needle.element_lengths`` on the node's path."""
import dataclasses
import math
import pickle

import numpy as np
import pytest

from needle_sim_ros.experiments.ground_truth import TruthModel, run_ground_truth
from needle_sim_ros.experiments.protocols import EXPERIMENTS
from failing_forces import PoisonedAfter
from needle_sim_ros.base_input import BaseInput
from needle_sim_ros.model import (BaseMotion, Fixture, Gravity, Integrator, PointLoad, StepFailed, build_model,
                                  solve_static)
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import NeedleSimulation, model_builder_from_parameters, simulation_from_parameters
from needle_sim_ros.stepper import Stepper

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
DT = 1e-3


def pitching(t: float) -> BaseMotion:
    """Base at the origin pitching 10 deg at 0.5 Hz about y (exact rate and acceleration)."""
    omega, amplitude = 2.0 * math.pi * 0.5, math.radians(10.0)
    angle = amplitude * math.sin(omega * t)
    return BaseMotion((0.0, 0.0, 0.0), (0.0, math.sin(0.5 * angle), 0.0, math.cos(0.5 * angle)),
                      angular_velocity=(0.0, amplitude * omega * math.cos(omega * t), 0.0),
                      angular_acceleration=(0.0, -amplitude * omega ** 2 * math.sin(omega * t), 0.0))


def test_a_prescribed_simulation_runs_the_compiled_sequence_and_agrees_with_the_general_step():
    model = build_model(TruthModel().props, n_elements=10)
    integrator = Integrator(model, newton_tol=1e-9)
    runs = []
    original = integrator.step_sequence
    integrator.step_sequence = lambda *args, **kwargs: runs.append(1) or original(*args, **kwargs)
    start = model.straight_state(pitching(0.0), 0.0)
    simulation = NeedleSimulation.prescribed(model, integrator, DT, pitching, start)
    records = [record for t in (0.05, 0.1, 0.15, 0.2) for record in simulation.advance_to(t)]
    assert len(records) == 200 and runs and simulation.statistics.failed_steps == 0
    np.testing.assert_allclose([r.t for r in records], DT * np.arange(1, 201), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(simulation.base.orientation, pitching(0.2).orientation)
    reference, state = Integrator(model, newton_tol=1e-9), start
    gravity = simulation.forces
    for k in range(1, 201):
        state = reference.step(state, DT, pitching(k * DT), gravity).state
    np.testing.assert_allclose(simulation.state.q, state.q, rtol=0, atol=1e-9 * model.props.length)


def test_a_prescribed_simulation_raises_a_failed_step_with_the_last_accepted_state():
    model = build_model(TruthModel().props, n_elements=6)
    start = model.straight_state(pitching(0.0), 0.0)
    simulation = NeedleSimulation.prescribed(model, Integrator(model), DT, pitching, start,
                                             extra_forces=[PoisonedAfter(0.0105)])
    with pytest.raises(StepFailed):
        simulation.advance_to(0.05)
    assert simulation.statistics.failed_steps == 1
    assert simulation.state.t == pytest.approx(0.010) and np.isfinite(simulation.state.q).all()


def test_the_node_path_builds_the_mesh_of_element_lengths():
    lengths = [0.03, 0.03, 0.05, 0.05, 0.06, 0.05]  # a node at 0.16 m: the clamp below starts there
    p = {**PARAMETERS, "needle.element_lengths": lengths, "fixtures.clamp_interval": [0.16, 0.27]}
    model, _ = model_builder_from_parameters(p)(())
    np.testing.assert_allclose(model.mesh.element_lengths, lengths)
    assert model_builder_from_parameters({**PARAMETERS, "needle.element_lengths": []})(())[0].n_elements == \
        PARAMETERS["needle.elements"]
    simulation = simulation_from_parameters(p)
    for k in range(21):
        simulation.offer_pose(k * DT, [0.4, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
    simulation.advance(20 * DT, deterministic=True)
    assert simulation.statistics.failed_steps == 0 and simulation.statistics.steps == 20
    np.testing.assert_allclose(simulation.model.mesh.element_lengths, lengths)
    assert simulation.model.fixtures[0].interval == (0.16, 0.27)


def test_the_ground_truth_runs_in_the_time_loop_and_hangs_on_its_holder_with_its_weight():
    experiment = dataclasses.replace(EXPERIMENTS["static_tip_load"](), duration=0.2)
    truth = TruthModel(n_elements=10, dt=DT)
    samples = run_ground_truth(experiment, truth, shape_times=[0.0, 0.1, 0.2], wrench_rate=50.0, shape_samples=11)
    np.testing.assert_allclose(samples.wrench_times, 0.02 * np.arange(1, 11), atol=1e-12)
    props = truth.props
    weight = props.mass_per_length * props.length * np.asarray(props.gravity)
    np.testing.assert_allclose(samples.force_base, np.tile(weight, (10, 1)), atol=1e-3 * np.linalg.norm(weight))
    np.testing.assert_allclose(samples.shapes[-1].points, samples.shapes[0].points, atol=1e-6)


def test_a_copy_of_the_data_keeps_the_sequences_factorization():
    """A needle held still, vibrating slightly under a tip load, runs the compiled sequence on a factorization kept
    across steps; a copy of the data taken mid-run carries that factorization, so restoring it replays the run bit
    for bit (it used to stay in the integrator: the replay started from the later run's matrix and differed)."""
    model = build_model(TruthModel().props, n_elements=10)

    def held(t: float) -> BaseMotion:
        return BaseMotion((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    # at rest under 0.3 N, then 0.3005 N: a small vibration, one correction per step from ~30 ms on
    start = solve_static(model, held(0.0), [Gravity(), PointLoad(model.props.length, (0.0, 0.0, -0.3))]).state
    simulation = NeedleSimulation.prescribed(model, Integrator(model, newton_tol=1e-4), DT, held, start,
                                             extra_forces=[PointLoad(model.props.length, (0.0, 0.0, -0.3005))])
    simulation.advance_to(0.04)
    saved = simulation.data.copy()
    assert saved.integrator.control[1] == 1

    def replay() -> tuple[bytes, bytes]:
        records = simulation.advance_to(0.09)
        return pickle.dumps([(r.t, r.wrench) for r in records]), pickle.dumps(simulation.data)

    first = replay()
    simulation.data.restore(saved)
    assert replay() == first


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "general"])
def test_a_restart_with_a_new_clamp_pose_keeps_the_model_and_clamps_where_the_needle_restarted(compiled):
    """The distal 40 % clamped (seed 000 Fig. 8), restarted at another pose of the pitching base: the model is the
    same object, and the steps after the restart are those of a model built with the clamp fixed in the world at
    that pose (the independent reference: a world-frame Fixture at the restart pose, a fresh integrator)."""
    clamp = (0.6 * TruthModel().props.length, TruthModel().props.length)
    model = build_model(TruthModel().props, n_elements=10, fixtures=(Fixture(interval=clamp, frame="start"),))
    sim = NeedleSimulation(Stepper(model, Integrator(model), DT, restart_on_failure=False), BaseInput(base_at=pitching),
                           max_catch_up=math.inf)
    sim.compiled_sequence = compiled
    sim.reset(pitching(0.0), 0.0)
    sim.advance_to(0.05)
    restart = 0.3  # the base pitched by 8.1 deg
    sim.reset(pitching(restart), restart)
    assert sim.model is model
    base = pitching(restart)
    world = build_model(TruthModel().props, n_elements=10, fixtures=(
        Fixture(interval=clamp, frame="world", needle_pose=(base.position, base.orientation)),))
    reference = NeedleSimulation.prescribed(world, Integrator(world), DT, pitching, world.straight_state(base, restart))
    reference.compiled_sequence = compiled
    np.testing.assert_array_equal(sim.state.q, reference.state.q)
    ours, theirs = sim.advance_to(restart + 0.1), reference.advance_to(restart + 0.1)
    assert len(ours) == len(theirs) == 100
    np.testing.assert_allclose([r.wrench.force_base for r in ours], [r.wrench.force_base for r in theirs],
                               rtol=0, atol=1e-9 * np.abs([r.wrench.force_base for r in theirs]).max())
    np.testing.assert_allclose(sim.state.q, reference.state.q, rtol=0, atol=1e-12)
    clamped = model.partition.held[0].dofs
    np.testing.assert_array_equal(sim.state.q[clamped], world.straight_state(base, restart).q[clamped])  # held
