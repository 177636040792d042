"""The simulator core (ROS-free): a thin :class:`NeedleSimulation` over its three parts, and its construction from
the `needle_simulator` parameters.

A base pose goes down the layers: :meth:`NeedleSimulation.offer_pose` hands it to the base input
(:mod:`needle_sim_ros.base_input`: the pose fit, offset, twist); :meth:`NeedleSimulation.advance` asks the clock loop
(:mod:`needle_sim_ros.clock_loop`: target time, phase lock, catch-up, step grid) for the steps up to the clock, and
the clock hands their end times to the stepper (:mod:`needle_sim_ros.stepper`: model, data, integrator), which
takes the base motions from the base input and returns each step's record with its base wrench.
"""
from __future__ import annotations

import math
import time
from functools import partial
from operator import attrgetter
from typing import Callable, Sequence

import numpy as np

from needle_common.parameters import ParameterError

from needle_sim_ros.base_input import BaseInput, InputLimits, MotionsAt
from needle_sim_ros.base_trajectory import BaseTrajectory, PoseVerdict, TrajectoryLimits
from needle_sim_ros.clock_loop import LATE_POSE_WAIT, ClockLoop
from needle_sim_ros.model import (BaseMotion, Fixture, Integrator, NeedleModel, State, build_model, check_forces,
                                  load_needle_config)
from needle_sim_ros.stepper import (POINT_LOAD_LIMIT, LoopStatistics, ModelBuilder, Stepper, StepRecord,
                                    max_point_load)
from needle_sim_ros.tissue.factory import build_tissue_model

# Verdicts of an offered pose that the simulator uses.
USED_POSES = (PoseVerdict.ACCEPTED, PoseVerdict.NORMALIZED, PoseVerdict.REANCHORED, PoseVerdict.RESTARTED)

__all__ = ["LATE_POSE_WAIT", "POINT_LOAD_LIMIT", "USED_POSES", "InputLimits", "LoopStatistics", "NeedleSimulation",
           "StepRecord", "max_point_load", "simulation_from_parameters"]


def step_wrenches(records: Sequence[StepRecord]):
    """(end time, force, torque) of each step's wrench on the holder in the base frame, force and torque as lists of
    floats: what the simulator publishes on ``wrench`` (a step whose wrench is not finite is left out: never NaN on
    the wire)."""
    for record in records:
        values = record.wrench.base.tolist()
        if all(map(math.isfinite, values)):
            yield record.t, values[:3], values[3:]


def _set(part: str, name: str, sim, value) -> None:
    setattr(getattr(sim, part), name, value)


def _via(part: str, names: str) -> tuple[property, ...]:
    """Attributes ``names`` of one of the simulation's parts, in order, read (with a C getter: the node reads some
    per pose) and written through the facade."""
    return tuple(property(attrgetter(f"{part}.{name}"), partial(_set, part, name)) for name in names.split())


class NeedleSimulation:
    """The simulator: a :class:`Stepper`, the :class:`BaseInput` that drives it and the :class:`ClockLoop` that
    decides its steps (``max_catch_up``, ``pose_timeout`` [s]). It holds no logic of its own: it routes inputs to the
    base input, restarts the needle (stepper and step grid together) and advances the clock loop."""

    (model, integrator, dt, data, state, base, statistics, extra_forces, point_loads, forces, model_forces,
     compiled_sequence, after_step, set_point_load, clear_point_loads, tissue_readout, shape, energies) = _via(
        "stepper", "model integrator dt data state base statistics extra_forces point_loads forces model_forces "
                   "compiled_sequence after_step set_point_load clear_point_loads tissue_readout shape energies")
    twist, set_twist, pose_age, base_motions, base_motion_at = _via(
        "source", "twist set_twist pose_age motions motion_at")
    trajectory = property(attrgetter("source.trajectory"))  # read only: a compiled plan holds its buffers
    max_catch_up, next_step_end = _via("clock", "max_catch_up next_step_end")

    def __init__(self, stepper: Stepper, source: BaseInput, max_catch_up: float = 0.05,
                 pose_timeout: float = 0.1) -> None:
        self.stepper = stepper
        self.source = source
        self.clock = ClockLoop(stepper, max_catch_up, pose_timeout)

    @classmethod
    def prescribed(cls, model: NeedleModel, integrator: Integrator, dt: float, base_at: Callable[[float], BaseMotion],
                   state: State, extra_forces: Sequence = (), motions_at: MotionsAt | None = None) -> NeedleSimulation:
        """A simulation whose base follows ``base_at(t)`` (scenarios, ground truth, benchmarks), started from
        ``state`` at ``state.t`` with gravity and ``extra_forces`` (checked once, kept: no builder), never skipping
        time, raising StepFailed where a step fails. ``motions_at(times)``: the same motions for many times at once,
        packed as :meth:`BaseInput.motions` returns them (a run of steps then calls no Python per step)."""
        simulation = cls(Stepper(model, integrator, dt, restart_on_failure=False),
                         BaseInput(base_at=base_at, motions_at=motions_at), max_catch_up=np.inf)
        simulation.stepper.extra_forces = list(check_forces(list(extra_forces)))
        simulation.start_from(state)
        return simulation

    @property
    def started(self) -> bool:
        return self.stepper.data.started

    def offer_pose(self, t: float, position, orientation) -> PoseVerdict:
        """Offer a flange pose; the first valid pose (and a re-anchoring or a restart after a gap) starts the
        needle straight there."""
        started = self.stepper.data.started
        verdict = self.source.offer_pose(t, position, orientation, self.clock.pose_timeout if started else math.inf)
        if started and (verdict is PoseVerdict.ACCEPTED or verdict is PoseVerdict.NORMALIZED):
            self.clock.pose_arrived(t)
        elif verdict in USED_POSES:  # the first pose, or one the needle restarts at
            self.reset(self.source.motion_at(t), t)
        return verdict

    def reset(self, base: BaseMotion, t: float) -> None:
        """Straight, unloaded needle at rest relative to the base at time t (:meth:`Stepper.reset`), a new grid."""
        self.stepper.reset(base, t)
        self.clock.restart(t)

    def start_from(self, state: State) -> None:
        """Continue from a given state (e.g. a static equilibrium) at ``state.t`` instead of the straight needle,
        the base at its motion then; the step grid restarts there."""
        base = self.source.base_at
        self.stepper.start(state, state.base if state.base is not None else (
            base(state.t) if base is not None else self.stepper.base))
        self.clock.restart(state.t)

    def discard_state(self) -> None:
        """Forget the state (e.g. the clock jumped back); the next :meth:`reset` starts again."""
        self.stepper.data.state = None

    def advance(self, now: float, deterministic: bool, ahead_to_pose: bool = False) -> list[StepRecord]:
        """Integrate up to :meth:`ClockLoop.target_time`; a clock that jumped back (looping bag) discards the
        state and the received poses."""
        data = self.stepper.data
        started = data.started
        if started and now < data.time - self.clock.pose_timeout:
            self.source.trajectory.clear()
            self.discard_state()
        elif ahead_to_pose and not deterministic and started:
            self.clock.lock_phase()
        source = self.source
        return self.clock.advance_to(self.clock.target_time(now, deterministic, ahead_to_pose,
                                                            source.trajectory.latest_time), source)

    def advance_to(self, t_target: float) -> list[StepRecord]:
        """Integrate with fixed steps of dt until the next step would pass t_target (:meth:`ClockLoop.advance_to`)."""
        return self.clock.advance_to(t_target, self.source)


def model_builder_from_parameters(p: dict) -> ModelBuilder:
    """fixtures -> (model, integrator) as the `needle_simulator` parameters (flat dotted names) describe them
    (:func:`~needle_sim_ros.model.load_needle_config`: ``needle.element_lengths`` other than [0.0] sets the mesh)."""
    props, build, integrator_kwargs = load_needle_config(p)

    def model_builder(fixtures: tuple = ()) -> tuple[NeedleModel, Integrator]:
        model = build_model(props, **{**build, "fixtures": fixtures})
        return model, Integrator(model, **integrator_kwargs)

    return model_builder


def simulation_from_parameters(p: dict) -> NeedleSimulation:
    """The simulator described by the `needle_simulator` parameters (flat dotted names, validated values).

    One construction for the node and the offline pipeline, so both run the same simulator. ``fixtures.clamp_interval``
    clamps that part of the needle where it lies at each (re)start (a :class:`Fixture` of the frame "start"). Raises
    ParameterError for element lengths or a clamp the mesh rejects, ValueError for tissue parameters that the tissue
    models reject.
    """
    model_builder = model_builder_from_parameters(p)
    tissue_config = {name: value for name, value in p.items() if name.startswith("tissue.")}

    def tissue_builder(model: NeedleModel) -> list:
        return [build_tissue_model(tissue_config, model)]

    trajectory = BaseTrajectory(TrajectoryLimits(
        window=p["pose_input.window"], max_extrapolation=p["pose_input.max_extrapolation"],
        max_position_jump=p["pose_input.max_position_jump"], max_orientation_jump=p["pose_input.max_orientation_jump"],
        reanchor_after=p["pose_input.reanchor_after"], max_position=p["pose_input.max_position"]))
    clamp = p["fixtures.clamp_interval"]
    try:
        model, integrator = model_builder(())
    except ValueError as error:  # the mesh rejects element lengths that do not sum to the needle length
        raise ParameterError(f"parameter 'needle.element_lengths': {error}") from error
    if len(clamp) == 2:
        message = f"parameter 'fixtures.clamp_interval' = {list(clamp)}: "
        if not 0.0 <= clamp[0] <= clamp[1] <= model.props.length:
            raise ParameterError(f"{message}must satisfy 0 <= s_start <= s_end <= needle.length = "
                                 f"{model.props.length:g} m")
        try:
            model, integrator = model_builder((Fixture(interval=tuple(clamp), frame="start"),))
        except ValueError as error:  # given element lengths without a node at an end of the clamp
            raise ParameterError(f"{message}{error}") from error
    if p["tissue.enable"]:
        tissue_builder(model)  # reject bad tissue parameters now, not at the first pose
    stepper = Stepper(model, integrator, p["integrator.dt"], tissue_builder if p["tissue.enable"] else None,
                      p["needle.start_in_equilibrium"])
    source = BaseInput(trajectory, (p["flange_offset.position"], p["flange_offset.orientation"]),
                       p["pose_input.twist_timeout"], InputLimits(p["pose_input.max_linear_speed"],
                                                                  p["pose_input.max_angular_speed"],
                                                                  p["pose_input.resume_tolerance"]))
    sim = NeedleSimulation(stepper, source, p["loop.max_catch_up"], p["pose_input.timeout"])
    apply_tip_force(sim, p["loads.tip_force"])
    return sim


def apply_tip_force(sim: NeedleSimulation, force) -> None:
    """The ``loads.tip_force`` parameter [N]: the point load at the tip (zero: none); ValueError naming the parameter
    for a load the needle cannot carry."""
    force = np.asarray(force, dtype=float)
    if not np.any(force != 0.0):
        sim.clear_point_loads([TIP_FORCE_PARAMETER])
        return
    try:
        sim.set_point_load(TIP_FORCE_PARAMETER, sim.model.props.length, force)
    except ValueError as error:
        raise ValueError(f"parameter 'loads.tip_force' = {force.tolist()}: {error}") from error


TIP_FORCE_PARAMETER = "tip_force_parameter"  # name of the point load set by the `loads.tip_force` parameter
TIP_LOAD_TOPIC = "tip_load_topic"  # name of the point load set from the `tip_load` topic


def compile_kernels(p: dict) -> float:
    """Run a scratch simulation for a few steps so that every numba kernel on the step path is compiled or loaded
    from the cache now (up to ~50 s on a fresh machine) rather than at the first real pose. Returns the wall time."""
    start = time.perf_counter()
    scratch = simulation_from_parameters(p)
    dt = scratch.dt
    for k in range(6):  # advancing between poses also compiles the base-trajectory refit (its C2 correction)
        scratch.offer_pose(k * dt, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
        if k >= 3:
            scratch.advance((k + 1) * dt, deterministic=False)
    # a grid shifted to the poses (lock_phase): its first step runs the step sequence alone, not the one-call advance
    scratch.data.grid_origin += 0.5 * dt
    scratch.advance(8 * dt, deterministic=False)
    scratch.shape(10)
    scratch.energies()
    if p["tissue.enable"]:
        compile_tissue_kernels(p)
    return time.perf_counter() - start


def compile_tissue_kernels(p: dict, steps: int = 10) -> None:
    """Advance scratch needles a few steps with the tip in the configured tissue (the entry surface moved across
    the needle; before and after the capsule puncture if the insertion profile is on), with the tissue readout,
    so that the kernels of the tissue models are compiled or loaded from the cache now. The install hook calls it
    whether or not the tissue is enabled, :func:`compile_kernels` when it is."""
    model, integrator = model_builder_from_parameters(p)(())
    config = {name: value for name, value in p.items() if name.startswith("tissue.")}
    puncture = float(p["tissue.insertion_profile.puncture_depth"]) if p["tissue.insertion_profile.enable"] else 0.0
    dt = p["integrator.dt"]
    velocity = np.array([6e-3, 0.0, 0.0])

    def base_at(t: float) -> BaseMotion:
        return BaseMotion(velocity * t, np.array([0.0, 0.0, 0.0, 1.0]), linear_velocity=velocity)

    for depth in ((0.5 * puncture,) if puncture > 0.0 else ()) + (puncture + 5e-3,):
        config.update({"tissue.enable": True, "tissue.entry_normal": [1.0, 0.0, 0.0],
                       "tissue.entry_point": [model.props.length - depth, 0.0, 0.0]})
        scratch = NeedleSimulation.prescribed(model, integrator, dt, base_at, model.straight_state(base_at(0.0)),
                                              [build_tissue_model(config, model)])
        scratch.advance_to(steps * dt)
        scratch.tissue_readout()
        scratch.energies()
