"""The simulator core (NeedleSimulation) and its compiled step sequences: equilibrium at rest, agreement with the
one-step integrator under motion, and the fall-back to the general step."""
import math
import pickle

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from failing_forces import PoisonedAfter
from needle_sim_ros.model import BaseMotion, GeneralizedForce, Gravity, Integrator, PointLoad, StepFailed
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_common.parameters import ParameterError
from needle_sim_ros import clock_loop
from needle_sim_ros.base_trajectory import BaseTrajectory
from needle_sim_ros.simulation import simulation_from_parameters
from needle_sim_ros.tissue import tissue_model

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}


def pitching(t: float) -> tuple[np.ndarray, np.ndarray]:
    """Flange pose: 10 deg pitch at 0.5 Hz about world y plus a slow 5 mm/s advance along x."""
    angle = math.radians(10.0) * math.sin(2 * math.pi * 0.5 * t)
    return np.array([0.4 + 0.005 * t, 0.0, 0.3]), Rotation.from_rotvec([0.0, angle, 0.0]).as_quat()


def test_wrench_at_rest_is_the_weight_plus_the_tip_load_through_the_compiled_path():
    tip_force = np.array([0.0, 0.05, -0.2])
    sim = simulation_from_parameters({**PARAMETERS, "loads.tip_force": tip_force.tolist(),
                                      "damping.rayleigh_beta": 1e-3})
    records = []
    for k in range(3000):  # 3 s of poses at 1 kHz, integrated as they come (deterministic rule)
        sim.offer_pose(k * 1e-3, [0.4, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
        records += sim.advance(k * 1e-3, deterministic=True)
    assert sim.statistics.failed_steps == 0 and len(records) == 2999
    assert all(r.substeps == 1 for r in records[10:])  # after the first step: compiled sequences
    props = sim.model.props
    weight = props.mass_per_length * props.length * np.asarray(props.gravity)
    force = records[-1].wrench.force_world
    # the needle pulls its holder with its weight and the tip load (the swing decays with beta = 1e-3)
    np.testing.assert_allclose(force, weight + tip_force, atol=2e-3 * np.linalg.norm(weight + tip_force))
    # moment about A of the loads on the deflected needle: tip load at the tip, weight along the centerline
    line = sim.shape(401).line
    segment = np.diff(line.reference_arc_length)
    midpoints = 0.5 * (line.points[1:] + line.points[:-1]) - line.points[0]
    moment = np.cross(line.points[-1] - line.points[0], tip_force) + np.sum(
        np.cross(midpoints, props.mass_per_length * segment[:, None] * np.asarray(props.gravity)), axis=0)
    np.testing.assert_allclose(records[-1].wrench.torque_world, moment, atol=2e-3 * np.linalg.norm(moment))


def test_compiled_sequence_agrees_with_one_step_at_a_time():
    """The sequence keeps the iteration matrix across steps (modified Newton); both converge to the same
    solution of each step's equations within the Newton tolerance."""
    sim = simulation_from_parameters({**PARAMETERS, "integrator.newton_tolerance": 1e-9})
    for k in range(40):
        sim.offer_pose(k * 1e-3, *pitching(k * 1e-3))
    sim.advance(0.002, deterministic=True)  # the first step (consistent accelerations) takes the general path
    start = sim.state
    times = start.t + 1e-3 * np.arange(1, 31)
    motions, rotations = sim.base_motions(times)
    forces = [Gravity()]
    reference = Integrator(sim.model, rho_inf=PARAMETERS["integrator.rho_inf"], newton_tol=1e-9)
    result = sim.integrator.step_sequence(start, 1e-3, motions, rotations, forces)
    assert result.done == len(times)
    state = start
    for i in range(len(times)):
        state = reference.step(state, 1e-3, BaseMotion.from_packed(motions[i], rotations[i]), forces).state
        np.testing.assert_allclose(result.states[i, 0], state.q, atol=1e-9 * sim.model.props.length)
        np.testing.assert_allclose(result.states[i, 1], state.qd, atol=1e-5)


def test_a_shifted_step_runs_compiled_and_agrees_with_the_general_path(monkeypatch):
    """After a grid shift (lock_phase) the next step lasts (1 + shift) dt: it runs on the compiled sequence like the
    others (before: the general path, ~3x the time) and ends where the general path does."""
    sims = [simulation_from_parameters({**PARAMETERS, "integrator.newton_tolerance": 1e-9}) for _ in range(2)]
    sims[1].compiled_sequence = False  # the reference: every step on the general path
    for sim in sims:
        for k in range(60):
            sim.offer_pose(k * 1e-3, *pitching(k * 1e-3))
        sim.advance(0.010, deterministic=True)
        sim.data.grid_origin += 0.4e-3  # what lock_phase does: the next step lasts 1.4 dt
    general = []
    monkeypatch.setattr(sims[0].stepper, "step", lambda *args, **kwargs: general.append(args))
    compiled, reference = (sim.advance(0.030, deterministic=True) for sim in sims)
    assert not general
    assert [r.t for r in compiled] == [r.t for r in reference] and compiled[0].t == pytest.approx(0.0114)
    length = sims[0].model.props.length
    np.testing.assert_allclose(sims[0].state.q, sims[1].state.q, atol=1e-9 * length)
    for ours, theirs in zip(compiled, reference):
        np.testing.assert_allclose(ours.wrench.force_base, theirs.wrench.force_base,
                                   atol=1e-6 * np.abs(theirs.wrench.force_base).max())


def test_the_advance_in_one_compiled_call_agrees_with_the_general_path(monkeypatch):
    """The base from the received poses (flange offset, a fresh twist) and runs of 1-7 steps per advance: one
    compiled call per advance (compiled_advance) ends where the general path does, step by step, with the base
    motion the trajectory serves at each step end."""
    p = {**PARAMETERS, "integrator.newton_tolerance": 1e-9, "flange_offset.position": [0.01, 0.0, 0.02],
         "flange_offset.orientation": [0.0, 0.0, 0.38268343, 0.92387953]}
    sims = [simulation_from_parameters(p) for _ in range(2)]
    sims[1].compiled_sequence = False  # the reference: every step on the general path
    calls = []
    stepper = sims[0].stepper
    lane = stepper._advance_from_trajectory
    monkeypatch.setattr(stepper, "_advance_from_trajectory", lambda *args: calls.append(len(args[1])) or lane(*args))
    monkeypatch.setattr(stepper, "_step_sequence", lambda *args: pytest.fail("the staged sequence ran"))
    rng = np.random.default_rng(7)
    length, k = sims[0].model.props.length, 0
    for sim in sims:
        sim.set_twist(0.0205, np.array([0.004, 0.0, 0.001]), np.array([0.0, 0.05, 0.0]))
    while k < 120:
        run = int(rng.integers(1, 8))
        for _ in range(run):
            for sim in sims:
                sim.offer_pose(k * 1e-3, *pitching(k * 1e-3))
            k += 1
        records = [sim.advance((k - 1) * 1e-3, deterministic=True) for sim in sims]
        assert [r.t for r in records[0]] == [r.t for r in records[1]]
        for ours, theirs in zip(*records):
            np.testing.assert_allclose(ours.wrench.force_base, theirs.wrench.force_base,
                                       atol=1e-6 * max(np.abs(theirs.wrench.force_base).max(), 1e-3))
        np.testing.assert_allclose(sims[0].state.q, sims[1].state.q, atol=1e-9 * length)
        served = sims[0].base_motion_at(sims[0].state.t)  # the fit the last advance used, evaluated alone
        np.testing.assert_array_equal(sims[0].base.rotation, served.rotation)
        np.testing.assert_array_equal(sims[0].base.angular_velocity, served.angular_velocity)
    assert len(calls) > 20 and max(calls) > 1 and sims[0].statistics.steps == sims[1].statistics.steps


def test_the_trajectory_under_the_compiled_advance_cannot_be_replaced():
    """The one-call advance's plan holds the trajectory's buffers: a trajectory swapped in behind it (through the
    facade or the base input) would be fed poses the steps never see. Neither can be assigned; the poses offered
    after a run of compiled calls still move the base."""
    sim = simulation_from_parameters(PARAMETERS)
    for k in range(5):
        sim.offer_pose(k * 1e-3, [0.4, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
        sim.advance(k * 1e-3, deterministic=True)
    for owner in (sim, sim.source):
        with pytest.raises(AttributeError):
            owner.trajectory = BaseTrajectory()
    for k in range(5, 10):
        sim.offer_pose(k * 1e-3, [0.4 + 1e-4 * (k - 4), 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
        sim.advance(k * 1e-3, deterministic=True)
    assert sim.base.position[0] > 0.4 + 1e-4


def test_base_motions_of_a_sequence_equal_the_single_evaluations():
    sim = simulation_from_parameters({**PARAMETERS, "flange_offset.position": [0.01, 0.0, 0.02],
                                      "flange_offset.orientation": [0.0, 0.0, 0.38268343, 0.92387953]})
    for k in range(30):
        sim.offer_pose(k * 1e-3, *pitching(k * 1e-3))
    sim.set_twist(0.0255, np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.1, 0.0]))
    times = np.array([0.0201, 0.025, 0.029, 0.031, 0.045])  # interpolated, twist fed forward, extrapolated, held
    motions, rotations = sim.base_motions(times)
    for t, packed, rotation in zip(times, motions, rotations):
        single = sim.base_motion_at(t)
        np.testing.assert_array_equal(single.rotation, rotation)
        for name, value in (("position", packed[0:3]), ("orientation", packed[3:7]),
                            ("linear_velocity", packed[7:10]), ("angular_velocity", packed[10:13])):
            np.testing.assert_array_equal(getattr(single, name), value)
    np.testing.assert_allclose(motions[1, 10:13], [0.0, 0.1, 0.0])  # the fresh twist replaced the estimate
    np.testing.assert_allclose(rotations[0] @ rotations[0].T, np.eye(3), atol=1e-12)


def test_a_step_the_sequence_cannot_converge_is_left_to_the_general_path():
    sim = simulation_from_parameters(PARAMETERS)
    for k in range(20):
        sim.offer_pose(k * 1e-3, *pitching(k * 1e-3))
    sim.advance(0.002, deterministic=True)
    start = sim.state
    impatient = Integrator(sim.model, newton_tol=1e-14, max_newton_iterations=1, max_substep_halvings=0)
    motions, rotations = sim.base_motions(start.t + 1e-3 * np.arange(1, 6))
    result = impatient.step_sequence(start, 1e-3, motions, rotations, [Gravity()])
    assert result.done == 0 and result.states.shape[0] == 0
    np.testing.assert_array_equal(sim.state.q, start.q)  # the start state is untouched


@pytest.mark.parametrize("forces, expected", [([Gravity(), PointLoad(0.27, (0.0, 0.0, -0.1))], True),
                                              ([PointLoad(0.27, (0.0, 0.0, -0.1), frame="base")], False)])
def test_the_sequence_applies_to_constant_world_loads_only(forces, expected):
    sim = simulation_from_parameters(PARAMETERS)
    assert sim.integrator.supports_sequence(forces) is expected


@pytest.mark.parametrize("in_equilibrium", [True, False])
def test_the_needle_starts_at_rest_in_equilibrium_under_its_weight(in_equilibrium):
    """Default: the first pose starts the needle sagging as the Euler-Bernoulli cantilever under its own weight,
    w L^4 / (8 E I) (2.68 mm here, 1 % of L: the geometric nonlinearity is ~1e-4), and it stays there; with
    needle.start_in_equilibrium false it starts straight and drops (seed 000's 0.4 % damping rings for seconds)."""
    sim = simulation_from_parameters({**PARAMETERS, "needle.start_in_equilibrium": in_equilibrium})
    props = sim.model.props
    sag = props.mass_per_length * 9.81 * props.length ** 4 / (8 * props.youngs_modulus * props.second_moment)
    tips = []
    for k in range(301):
        sim.offer_pose(k * 1e-3, [0.4, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
        sim.advance(k * 1e-3, deterministic=True)
        tips.append(sim.shape(2).tip_position[2] - 0.3)
    if in_equilibrium:
        assert tips[0] == pytest.approx(-sag, rel=2e-3)
        assert np.abs(np.array(tips) - tips[0]).max() < 1e-3 * sag
    else:
        assert tips[0] == 0.0 and min(tips) < -0.5 * sag


def test_a_non_uniform_mesh_from_needle_element_lengths_sags_as_the_euler_bernoulli_cantilever():
    """``needle.element_lengths`` (a node parameter) sets the mesh: 4 elements, the short ones at the tip; at the
    mesh nodes the sag under the needle's weight is the cantilever's w x^2 (6 L^2 - 4 L x + x^2) / (24 E I)
    (cubic elements are nodally exact for a uniform load; the geometric nonlinearity is ~1e-4)."""
    assert PARAMETERS["needle.element_lengths"] == [0.0]  # the default: needle.elements uniform elements
    lengths = [0.1, 0.1, 0.04, 0.03]
    sim = simulation_from_parameters({**PARAMETERS, "needle.element_lengths": lengths})
    np.testing.assert_array_equal(sim.model.mesh.element_lengths, lengths)
    props = sim.model.props
    w, L, EI = props.mass_per_length * 9.81, props.length, props.youngs_modulus * props.second_moment
    sim.offer_pose(0.0, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
    sim.advance(0.0, deterministic=True)
    line = sim.shape(28).line  # samples every 10 mm: the nodes 0.1, 0.2, 0.27 m are samples 10, 20, 27
    for x, index in ((0.1, 10), (0.2, 20), (0.27, 27)):
        exact = w * x ** 2 * (6 * L ** 2 - 4 * L * x + x ** 2) / (24 * EI)
        assert line.points[index, 2] - 0.3 == pytest.approx(-exact, rel=2e-3)
    with pytest.raises(ParameterError, match="'needle.element_lengths': element_lengths sum to 0.2 m"):
        simulation_from_parameters({**PARAMETERS, "needle.element_lengths": [0.1, 0.1]})


def test_ahead_to_pose_integrates_the_step_that_contains_the_newest_pose_and_no_further():
    """Live, ahead to the pose (the node's loop.ahead_to_pose): the step ending at or after the newest pose's stamp
    is integrated at once, though its end time is still ahead of the clock; never more than one step past the
    clock, and without the option only the steps whose end time has passed."""
    sim = simulation_from_parameters(PARAMETERS)
    for k in range(5):
        sim.offer_pose(k * 1e-3, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
        sim.advance(k * 1e-3, deterministic=False)
    assert sim.state.t == pytest.approx(4e-3)
    sim.offer_pose(4.3e-3, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
    assert sim.advance(4.4e-3, deterministic=False) == []  # the step to 5 ms ends in the future
    records = sim.advance(4.4e-3, deterministic=False, ahead_to_pose=True)
    assert [record.t for record in records] == [pytest.approx(5e-3)]
    sim.offer_pose(7.9e-3, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])  # stamped 3.5 ms ahead of the clock
    records = sim.advance(4.4e-3, deterministic=False, ahead_to_pose=True)
    assert records == [] and sim.state.t == pytest.approx(5e-3)  # one step past the clock at most
    assert [r.t for r in sim.advance(5.2e-3, False, True)] == [pytest.approx(6e-3)]


def test_a_pose_whose_step_was_integrated_before_it_came_is_counted_late():
    """Live, ahead to the pose: a pose stamped within a step already integrated (by the pose before it, here) is
    counted in ``statistics.late_poses`` (the node's ``poses_late_for_their_step``); poses in steps still ahead,
    and rejected ones, are not."""
    sim = simulation_from_parameters(PARAMETERS)
    for k in range(5):
        sim.offer_pose(k * 1e-3, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
        sim.advance(k * 1e-3, deterministic=False, ahead_to_pose=True)
    sim.offer_pose(4.3e-3, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
    sim.advance(4.4e-3, deterministic=False, ahead_to_pose=True)  # the step to 5 ms, at once
    assert sim.statistics.late_poses == 0 and sim.state.t == pytest.approx(5e-3)
    sim.offer_pose(4.8e-3, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])  # in the step just integrated
    sim.offer_pose(4.9e-3, [0.0, 0.0, np.nan], [0.0, 0.0, 0.0, 1.0])  # rejected
    assert sim.statistics.late_poses == 1
    sim.offer_pose(5.2e-3, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])  # in the next step
    assert sim.statistics.late_poses == 1


def live_pose_stream(period: float, jitter: float, poses: int, delay: float = 2e-4, t0: float = 1.8e9):
    """The node's live loop (loop.ahead_to_pose) fed a pitching base at ``period`` [s], stamps jittered uniformly by
    +-jitter/2 steps, each pose taken ``delay`` after its stamp; the clock's ticks come a quarter period after a step's
    end time (the node's wait for a late pose). Returns the simulation, the records, and per pose after the first
    300 (lock-in): whether its stamp was already integrated when it came, the steps its advance made, and the steps
    the ticks made before it."""
    sim = simulation_from_parameters(PARAMETERS)
    stamps = t0 + np.arange(poses) * period + np.random.default_rng(0).uniform(-0.5, 0.5, poses) * jitter * 1e-3
    records, late, per_pose, ticked = [], [], [], []
    for k, stamp in enumerate(stamps):
        arrival, ticks = stamp + delay, 0
        while sim.started and (tick_time := sim.next_step_end + clock_loop.LATE_POSE_WAIT * 1e-3) <= arrival:
            tick = sim.advance(tick_time, deterministic=False, ahead_to_pose=True)
            records += tick
            ticks += len(tick)
        already = sim.started and stamp <= sim.state.t
        sim.offer_pose(stamp, *pitching(stamp - t0))
        made = sim.advance(arrival, deterministic=False, ahead_to_pose=True)
        records += made
        if k >= 300:
            late.append(already), per_pose.append(len(made)), ticked.append(ticks)
    return sim, records, np.array(late), np.array(per_pose), np.array(ticked)


@pytest.mark.parametrize("period, jitter", [(1e-3, 0.8), (1.0005e-3, 0.2)], ids=["jitter 0.8 steps", "500 ppm drift"])
def test_the_step_grid_locks_to_the_phase_of_the_pose_stream(period, jitter, monkeypatch):
    """Live, ahead to the pose, a 1 kHz pose stream (jittered by +-0.4 steps, or by +-0.1 with a clock 500 ppm slower
    than the node's): once locked, every pose lands in a step of its own, integrated when it comes (none finds its stamp
    already integrated, the clock integrates no step); the grid shifts follow the drift, the steps after a shift
    (0.5 to 1.5 dt) leave no mark on the wrench. On a grid through the poses (no lock) poses do find their step
    integrated."""
    sim, records, late, per_pose, ticked = live_pose_stream(period, jitter, 2000)
    assert not late.any() and (per_pose == 1).all() and not ticked.any()
    times = np.array([record.t for record in records])
    forces = np.array([record.wrench.force_base for record in records])
    steps, change = np.diff(times), np.abs(np.diff(forces, axis=0)).max(axis=1)
    shifted = np.flatnonzero(np.abs(steps - 1e-3) > 5e-5)
    assert len(shifted) >= (3 if period != 1e-3 else 1) and np.all((steps > 4.9e-4) & (steps < 1.51e-3))
    regular = np.setdiff1d(np.arange(100, len(change)), shifted)
    assert change[shifted[shifted >= 100]].max(initial=0.0) <= change[regular].max()
    assert sim.statistics.failed_steps == 0
    monkeypatch.setattr(clock_loop, "PHASE_COHERENCE", np.inf)
    _, _, late, per_pose, ticked = live_pose_stream(period, jitter, 2000)
    assert (late | (per_pose != 1) | (ticked > 0)).sum() >= 10


def test_poses_without_a_common_phase_leave_the_step_grid_where_it_is():
    """Poses every 1.5 steps alternate between two phases half a step apart: no consistent phase, no shift."""
    sim, records, late, per_pose, ticked = live_pose_stream(1.5e-3, 0.05, 600)
    assert abs(sim.data.pose_phase) < clock_loop.PHASE_COHERENCE
    assert np.allclose(np.diff([r.t for r in records]), 1e-3, atol=1e-6)  # no step but of dt: never shifted


def _tissue_state(sim) -> bytes:
    """The tissue's state in the simulation's data as bytes (contact, track, anchors, friction states)."""
    return pickle.dumps(sim.data.force_states)


def _inserted(overrides: dict | None = None, seconds: float = 0.7):
    """A simulation with tissue (bevel tip, lateral support, the shaft law of ``overrides``), inserting at 10 mm/s
    from t = 0.1 s: 4 mm into the tissue after 0.7 s."""
    sim = simulation_from_parameters({**PARAMETERS, "tissue.enable": True, "tissue.entry_point": [0.272, 0.0, 0.0],
                                      **(overrides or {})})
    for k in range(int(round(seconds * 1e3))):
        sim.offer_pose(k * 1e-3, *inserting(k * 1e-3))
        sim.advance(k * 1e-3, deterministic=True)
    assert sim.extra_forces and sim.data.force_states[0].records[0].arc.size  # the track started
    return sim


def inserting(t: float) -> tuple[list, list]:
    return [0.01 * max(t - 0.1, 0.0), 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]


def test_a_failed_step_leaves_the_tissue_state_as_the_last_accepted_step_made_it(monkeypatch):
    """Inserting at 10 mm/s 4 mm into the tissue; then a step fails: the needle restarts straight, but the track,
    anchors and friction states are those before the failed step (they used to be advanced with the straight
    needle, which had jumped through the tissue)."""
    sim = _inserted()
    before = _tissue_state(sim)

    def fail(*args, **kwargs):
        raise StepFailed("forced")
    monkeypatch.setattr(sim.integrator, "step", fail)
    sim.compiled_sequence = False  # the compiled run hands a step that fails to the general step: fail that one
    t = sim.state.t + sim.dt
    sim.offer_pose(t, *inserting(t))
    records = sim.advance(t, deterministic=True)
    assert sim.statistics.failed_steps == 1 and len(records) == 1
    np.testing.assert_array_equal(sim.state.q, sim.model.straight_state(sim.base, t).q)
    assert _tissue_state(sim) == before


def _simulation_state(sim, with_input: bool = True) -> dict[str, bytes]:
    """Every piece of state a step can change, pickled: each field of the NeedleData (needle state t, q, q', q'',
    a; base motion; step grid; the integrator's memory with the kept factorization; point loads; the tissue's
    contact, puncture, track, anchors, bevel and cutting phases, LuGre z and frozen forces), the model's force
    contributions (immutable) and the pose input (``with_input``; its spare buffer rows are uninitialised, so only
    comparable with itself)."""
    parts = {name: getattr(sim.data, name.lstrip("_")) for name in sim.data.__dataclass_fields__
             if name != "_run_end"}  # the state, made from a compiled run's end where it left one
    parts.update({"trajectory": sim.trajectory} if with_input else {})
    parts.update({f"force {i} ({type(force).__name__})": force for i, force in enumerate(sim.model_forces)})
    return {name: pickle.dumps(value) for name, value in parts.items()}


SHAFT_LAWS = [{"tissue.shaft.axial_model": "karnopp"},
              {"tissue.shaft.axial_model": "lugre", "tissue.insertion_profile.enable": True}]


@pytest.mark.parametrize("law", SHAFT_LAWS, ids=["karnopp", "lugre+profile"])
def test_a_failed_step_with_tissue_changes_nothing(law):
    """Mid-insertion (bevel tip, lateral support, Karnopp or LuGre shaft law with the seed 002 tip), a step whose
    Newton cannot converge (1 iteration, tolerance 1e-300, every sub-step) raises StepFailed and leaves every piece
    of the simulation's state bit for bit as before; the run then goes on exactly as one that never tried it."""
    sim, twin = _inserted(law), _inserted(law)
    assert _simulation_state(sim, False) == _simulation_state(twin, False)
    t = sim.state.t + sim.dt
    base = sim.base_motion_at(t)  # (serving a pose is remembered by the trajectory: the same for the twin)
    twin.base_motion_at(t)
    before = _simulation_state(sim)
    settings = sim.integrator.newton_tol, sim.integrator.max_newton_iterations
    sim.integrator.newton_tol, sim.integrator.max_newton_iterations = 1e-300, 1
    sim.stepper.restart_on_failure = False  # raise instead of restarting the needle
    with pytest.raises(StepFailed):
        sim.stepper.step(base, t)
    sim.stepper.restart_on_failure = True
    after = _simulation_state(sim)
    assert [name for name in before if after[name] != before[name]] == []
    assert sim.statistics.failed_steps == 1
    sim.integrator.newton_tol, sim.integrator.max_newton_iterations = settings
    for k in range(1, 101):
        for run in (sim, twin):
            run.offer_pose(t + k * 1e-3, *inserting(t + k * 1e-3))
            run.advance(t + k * 1e-3, deterministic=True)
    assert _simulation_state(sim, False) == _simulation_state(twin, False)


def test_a_step_failing_after_converged_sub_steps_restores_the_integrators_memory():
    """The step fails only in its last 40 %: its first sub-steps converge from q_n and switch the integrator back to
    the extrapolating predictor (as after a fallback, it was on q_n); the failed step leaves it on q_n."""
    sim = _inserted(SHAFT_LAWS[0])
    t = sim.state.t + sim.dt
    base = sim.base_motion_at(t)
    sim.extra_forces.append(PoisonedAfter(t - 0.4 * sim.dt))
    sim.data.integrator.control[0] = 0  # on q_n, as after a fallback
    before = _simulation_state(sim)
    sim.stepper.restart_on_failure = False  # raise instead of restarting the needle
    with pytest.raises(StepFailed):
        sim.stepper.step(base, t)
    sim.stepper.restart_on_failure = True
    after = _simulation_state(sim)
    assert [name for name in before if after[name] != before[name]] == []
    assert sim.data.integrator.extrapolate is False


def test_a_force_that_fails_to_advance_rolls_the_step_back(monkeypatch):
    """The stateful forces advance once the integrator has accepted the step; if one fails (here the tissue's
    compiled advance of its contact, track, shaft anchors and LuGre z), its error is raised with the whole
    simulation as before the step."""
    sim = _inserted(SHAFT_LAWS[1])
    t = sim.state.t + sim.dt
    base = sim.base_motion_at(t)
    before = _simulation_state(sim)

    def broken(*args):
        raise FloatingPointError("broken tissue law")
    monkeypatch.setattr(tissue_model.TissueModel, "advance", broken)
    with pytest.raises(FloatingPointError):
        sim.stepper.step(base, t)
    monkeypatch.undo()
    after = _simulation_state(sim)
    assert [name for name in before if after[name] != before[name]] == []
    assert sim.statistics.failed_steps == 0


def test_extra_forces_are_checked_against_the_force_protocol_at_the_reset():
    class Undeclared:
        def evaluate(self, model, q, qd, t, base):
            return GeneralizedForce(np.zeros(model.n_dof))

    sim = simulation_from_parameters(PARAMETERS)
    sim.stepper.extra_forces_builder = lambda model: [Undeclared()]
    with pytest.raises(TypeError, match="Undeclared must declare state_dependent"):
        sim.offer_pose(0.0, [0.4, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])


def test_a_copy_of_the_data_replays_an_insertion_exactly():
    """All of a simulation's state is in its NeedleData: restoring a copy taken mid-insertion (LuGre shaft, seed
    002 tip) and stepping through the same base motions again gives the same wrenches and data bit for bit."""
    sim = _inserted(SHAFT_LAWS[1])
    t0 = sim.state.t
    motions = [(t0 + k * sim.dt, sim.base_motion_at(t0 + k * sim.dt)) for k in range(1, 41)]
    saved = sim.data.copy()

    def run() -> tuple[list, dict]:
        wrenches = [sim.stepper.step(base, t).wrench for t, base in motions]
        return pickle.dumps(wrenches), _simulation_state(sim, False)

    first = run()
    assert sim.data.force_states[0].records[0].arc[-1] > saved.force_states[0].records[0].arc[-1]  # the track grew
    sim.data.restore(saved)
    assert run() == first


def test_the_state_of_a_compiled_run_is_made_when_read():
    """The node path's compiled run leaves its last step's rows in the data and the State is made when first read:
    a run that reads the state after every pose and one that never does give the same wrenches and final state bit
    for bit, and a copy of the data taken between poses (its state not yet made) restores that pose's state."""
    quaternion = np.array([0.0, 0.0, 0.0, 1.0])

    def run(read_each: bool) -> tuple:
        sim = simulation_from_parameters({**PARAMETERS, "loads.tip_force": [0.0, 0.1, -0.2]})
        wrenches, states, saved = [], [], None
        for k in range(60):
            t = k * 1e-3
            sim.offer_pose(t, np.array([0.4 + 0.02 * t, 0.0, 0.3 - 0.5 * t * t]), quaternion)
            wrenches += [record.wrench.values for record in sim.advance(t, deterministic=True)]
            states += [sim.state] if read_each else []
            saved = sim.data.copy() if k == 40 else saved
        return sim, np.array(wrenches), states, saved

    eager, eager_wrenches, states, _ = run(True)
    lazy, lazy_wrenches, _, saved = run(False)
    assert len(lazy_wrenches) == 59
    np.testing.assert_array_equal(lazy_wrenches, eager_wrenches)
    for part in ("q", "qd", "qdd", "aux", "t"):
        np.testing.assert_array_equal(getattr(lazy.state, part), getattr(eager.state, part))
    np.testing.assert_array_equal(lazy.base.packed, eager.base.packed)
    lazy.data.restore(saved)
    assert lazy.state.t == states[40].t == pytest.approx(0.04)
    for part in ("q", "qd", "qdd", "aux"):
        np.testing.assert_array_equal(getattr(lazy.state, part), getattr(states[40], part))
    np.testing.assert_array_equal(lazy.base.packed, states[40].base.packed)


def test_the_compiled_advance_holds_the_pose_past_its_max_extrapolation(monkeypatch):
    """Live, with the newest pose older than ``pose_input.max_extrapolation``: the one compiled call per advance
    extrapolates the fit of a constant-velocity flange up to newest + max_extrapolation and holds it there at rest
    (the base's closed form p0 + v t; a window of another length than max_extrapolation tells the two apart)."""
    p = {**PARAMETERS, "pose_input.window": 0.02, "pose_input.max_extrapolation": 0.004}
    sim = simulation_from_parameters(p)
    p0, v = np.array([0.4, 0.0, 0.3]), np.array([0.01, -0.004, 0.002])
    quaternion = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(51):
        sim.offer_pose(k * 1e-3, p0 + v * k * 1e-3, quaternion)
        sim.advance(k * 1e-3, deterministic=False)
    monkeypatch.setattr(sim.stepper, "_step_sequence", lambda *args: pytest.fail("the staged sequence ran"))
    monkeypatch.setattr(sim.stepper, "step", lambda *args, **kwargs: pytest.fail("the general step ran"))
    for now, held_since in ((0.052, 0.052), (0.070, 0.054)):
        sim.advance(now, deterministic=False)
        assert sim.state.t == pytest.approx(now)
        np.testing.assert_allclose(sim.base.position, p0 + v * held_since, rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(sim.base.linear_velocity, v if now < 0.054 else np.zeros(3), atol=1e-9)
