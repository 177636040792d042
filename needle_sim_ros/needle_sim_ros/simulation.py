"""The simulator's clock-driven core: fixed-step ANCF integration towards a target time (ROS-free).

A :class:`NeedleSimulation` owns the mutable part of the simulator (its ``NeedleData``: needle state, step grid,
integrator memory, point loads, tissue state; and the base-pose trajectory) and advances it with the one step of
``model.data`` (fixed steps of ``dt``, the compiled step sequence where it applies) up to a requested time, taking
the base motion at each step's end time from a provider: the trajectory of the received poses, or a prescribed
``base_at(t)`` (:meth:`NeedleSimulation.prescribed`). It is the one time loop that integrates the needle: the node
feeds it poses and calls :meth:`advance` from its real-time loop, the offline pipeline does the same over a bag, and
the scenarios, the ground truth of the sample bags and the benchmarks advance a prescribed simulation to their sample
times.

Timing rules (:meth:`target_time`):
* live: integrate up to now, extrapolating the newest pose for at most ``max_extrapolation``;
* live, ahead to the pose: also integrate the step that ends at or after the newest pose's stamp (at most one step
  past the clock; its base motion is the fit extrapolated by less than dt), so a pose's wrench is out as soon as
  the pose is in, without waiting for the step's end time. The step grid then follows the phase of the pose
  stream (:meth:`NeedleSimulation.lock_phase`): once the poses arrive at a consistent phase (a robot at a fixed
  rate), the grid is shifted so that the steps end half a step after them, and each pose is in a step of its own
  even with jitter up to half a step (on a grid through the poses, half of them would fall just after a step end
  and find their step already integrated by the clock, or push the next one a step ahead);
* deterministic (simulated time, offline): integrate up to min(now, newest pose stamp), so poses are always
  interpolated and the result depends on the recorded data only — unless the input timed out, then up to now
  holding the last pose.
"""
from __future__ import annotations

import cmath
import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable, NamedTuple, Sequence

import numpy as np

from needle_common.parameters import ParameterError
from needle_common.transforms import quaternion_matrix, unit_quaternion

from needle_sim_ros.base_trajectory import BaseTrajectory, PoseVerdict, TrajectoryLimits
from needle_sim_ros.compiled_advance import NO_TWIST, advance_from_trajectory, apply_twist
from needle_sim_ros.model import (
    BaseMotion,
    BaseWrench,
    Fixture,
    Gravity,
    Integrator,
    NeedleData,
    NeedleModel,
    NeedleProperties,
    needle_properties,
    PointLoad,
    State,
    StaticSolveFailed,
    StepFailed,
    StepInputs,
    acting_forces,
    build_model,
    check_forces,
    elastic_energy,
    initial_force_states,
    kinetic_energy,
    ModelShape,
    model_shape,
    reaction_wrench,
    solve_static,
    stateful_forces,
    step,
)
from needle_sim_ros.model.config import element_lengths
from needle_sim_ros.model.contribution import ContributionRun
from needle_sim_ros.model.integrators import SequenceResult, same_objects
from needle_sim_ros.model.sequence import IntegratorMemory
from needle_sim_ros.model.kinematics import compose_offsets
from needle_sim_ros.tissue.factory import build_tissue_model
from needle_sim_ros.tissue.tissue_model import TissueModel, TissueReadout


# Largest sum of point-load magnitudes, as a multiple of the needle's bending load scale E I / L^2. Found by
# experiment (README, reliability): with the default discretisation (10 elements, 2 axial Gauss points, dt = 1 ms,
# 4 sub-step halvings) a tip load applied at once to the straight needle integrates up to 20.7 E I / L^2 (7 N for
# the seed 000 needle) compressive and 30 E I / L^2 transverse, while 25 E I / L^2 (8.45 N) compressive fails half
# the steps; 20 keeps a margin (6.8 N).
POINT_LOAD_LIMIT = 20.0

# Phase lock of the step grid to the pose stream (live, ahead to the pose): the running mean of the poses' phase
# phasor weighs each new pose by PHASE_SMOOTHING (~1/0.01 = 100 poses); the grid is shifted once the mean's length
# (1 for poses at one phase; 0.23 for a uniform jitter of +-0.4 steps; ~0.07 for poses at random phases) is at
# least PHASE_COHERENCE and its phase more than PHASE_TOLERANCE steps from mid-step.
PHASE_SMOOTHING = 0.01
PHASE_COHERENCE = 0.15
PHASE_TOLERANCE = 0.15
# How long [steps] past its end time the live loop's clock waits for a late pose before it integrates a step that no
# pose reached (half a step made more deadline misses on the benchmark's VM).
LATE_POSE_WAIT = 0.25


def max_point_load(props: NeedleProperties) -> float:
    """Largest total point load [N] the simulator accepts for this needle (:data:`POINT_LOAD_LIMIT` E I / L^2)."""
    return POINT_LOAD_LIMIT * props.EI / props.length ** 2


def _magnitude(vector) -> float:
    """Euclidean norm, inf (without an overflow warning) for vectors beyond the float range."""
    with np.errstate(over="ignore"):
        return float(np.linalg.norm(np.asarray(vector, dtype=float)))


@dataclass(frozen=True)
class InputLimits:
    """Documented limits of the base input (node parameters ``pose_input.*``): twist magnitudes, and the distance
    [m] from the held pose beyond which a pose arriving after a gap (older than ``pose_timeout``) restarts the
    needle straight there instead of dragging it across in one step."""

    max_linear_speed: float = 5.0  # [m/s]
    max_angular_speed: float = 20.0  # [rad/s]
    resume_tolerance: float = 1e-3  # [m]


class StepRecord(NamedTuple):
    """What one accepted step produced: its end time, the base wrench and the integrator's effort."""

    t: float
    wrench: BaseWrench
    newton_iterations: int
    substeps: int
    wall_time: float


def step_wrenches(records: Sequence[StepRecord]):
    """(end time, force, torque) of each step's wrench on the holder in the base frame, force and torque as lists of
    floats: what the simulator publishes on ``wrench`` (a step whose wrench is not finite is left out: never NaN on
    the wire)."""
    for record in records:
        force, torque = record.wrench.force_base.tolist(), record.wrench.torque_base.tolist()
        if all(map(math.isfinite, force)) and all(map(math.isfinite, torque)):
            yield record.t, force, torque


@dataclass
class LoopStatistics:
    """Counters reported in diagnostics."""

    steps: int = 0
    failed_steps: int = 0
    skipped_time: float = 0.0
    max_newton_iterations: int = 0
    straight_starts: int = 0  # starts in the straight state because no static equilibrium was found
    # accepted poses stamped at or before the integrated time: their step was integrated before they arrived (with
    # the base extrapolated), so the first wrench that uses them is the next step's (live: a pose stream whose
    # timing spreads over more than a step puts two poses in one step)
    late_poses: int = 0
    step_wall_times: list[float] = field(default_factory=list)

    def take_step_times(self) -> np.ndarray:
        times, self.step_wall_times = np.array(self.step_wall_times), []
        return times


ModelBuilder = Callable[[tuple], tuple[NeedleModel, Integrator]]


class NeedleSimulation:
    """Mutable simulator around an immutable :class:`NeedleModel`.

    ``clamp_interval`` (s_start, s_end) [m] clamps that part of the needle to the world where it lies when the
    needle is (re)started — the distal 40 % in the dynamic experiment of seed 000, Fig. 8. Since the clamp pose is
    known only then, the model is rebuilt with that :class:`Fixture` by ``model_builder(fixtures)`` at each reset.

    ``extra_forces_builder(model)`` makes the extra force contributions (e.g. the tissue model, whose state --
    track, stick anchors -- is kept in the data) acting every step in addition to gravity and the named point
    loads; they are made anew at every reset (and checked against the force protocol, :func:`check_forces`), with
    fresh states, so a restarted needle starts in fresh tissue. A step that fails even after the integrator's
    sub-stepping changes nothing (:meth:`step`) and is counted in ``statistics.failed_steps``; :meth:`advance_to`
    then restarts the needle straight at the current base pose, the forces keeping the state of the last accepted
    step: the output never contains NaN (with ``restart_on_failure`` False it raises the StepFailed instead, the
    data as before the step).

    ``base_at(t)``: the motion of the clamp point A at time t, used instead of the trajectory (and the flange
    offset and twist) when given (:meth:`prescribed`). ``compiled_sequence`` False keeps every step on the general
    path (benchmarks of that path).

    ``start_in_equilibrium``: a (re)started needle is at rest in static equilibrium under gravity and the point loads
    (seed 000 eq. 17 without inertia) instead of straight, so it does not first drop and swing (a free 18 G needle
    would sag 2.3 mm and ring for seconds); if no equilibrium is found it starts straight
    (``statistics.straight_starts``).
    """

    def __init__(self, model: NeedleModel, integrator: Integrator, dt: float, trajectory: BaseTrajectory,
                 flange_offset: tuple[np.ndarray, np.ndarray] = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])),
                 extra_forces_builder: Callable[[NeedleModel], list] | None = None, max_catch_up: float = 0.05,
                 pose_timeout: float = 0.1,
                 twist_timeout: float = 0.05, clamp_interval: tuple[float, float] | None = None,
                 model_builder: ModelBuilder | None = None, input_limits: InputLimits = InputLimits(),
                 start_in_equilibrium: bool = False, base_at: Callable[[float], BaseMotion] | None = None,
                 restart_on_failure: bool = True) -> None:
        if clamp_interval is not None and model_builder is None:
            raise ValueError("a clamp interval needs a model_builder to rebuild the model with the fixture")
        self.model = model
        self.integrator = integrator
        self.dt = dt
        self.trajectory = trajectory
        self._offset_position = np.asarray(flange_offset[0], dtype=float)
        self._offset_rotation = quaternion_matrix(unit_quaternion(flange_offset[1], "flange_offset.orientation"))
        self.extra_forces_builder = extra_forces_builder
        self.extra_forces: list = []  # the model's contributions besides gravity (the tissue)
        self.max_catch_up = max_catch_up
        self.pose_timeout = pose_timeout
        self.twist_timeout = twist_timeout
        self.input_limits = input_limits
        self.twist: np.ndarray | None = None  # [t, linear velocity, angular velocity] (set_twist)
        self.clamp_interval = clamp_interval
        self.model_builder = model_builder
        self.after_step: Callable[[StepRecord], None] | None = None  # called with the state of each accepted step
        self.data = NeedleData(integrator=IntegratorMemory(model.n_dof))  # everything a step changes
        self.statistics = LoopStatistics()
        self._gravity = Gravity()
        self.start_in_equilibrium = start_in_equilibrium
        self.base_at = base_at
        self.motions_at: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None
        self.restart_on_failure = restart_on_failure
        self.compiled_sequence = True
        self._sequence_plan: tuple = ((), None)  # (key, forces) of _sequence_forces
        self._run_plan: ContributionRun | None = None  # the composed compiled run of _run_steps

    @classmethod
    def prescribed(cls, model: NeedleModel, integrator: Integrator, dt: float, base_at: Callable[[float], BaseMotion],
                   state: State, extra_forces: Sequence = (),
                   motions_at: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None) -> NeedleSimulation:
        """A simulation whose base follows ``base_at(t)`` (scenarios, ground truth, benchmarks), started from
        ``state`` at ``state.t`` with gravity and ``extra_forces`` (checked once, kept: no builder), never skipping
        time, raising StepFailed where a step fails. ``motions_at(times)``: the same motions for many times at once,
        packed as :meth:`base_motions` returns them (a run of steps then calls no Python per step)."""
        simulation = cls(model, integrator, dt, BaseTrajectory(), max_catch_up=np.inf, base_at=base_at,
                         restart_on_failure=False)
        simulation.motions_at = motions_at
        simulation.extra_forces = list(check_forces(list(extra_forces)))
        simulation.start_from(state)
        return simulation

    # -- configuration -----------------------------------------------------------------------------------
    def rebuild_model(self, model_builder: ModelBuilder) -> None:
        """Swap in a model built with other run-time parameters, keeping the fixtures in force."""
        self.model_builder = model_builder
        self.model, self.integrator = model_builder(self.model.fixtures)
        self.data.integrator = IntegratorMemory(self.model.n_dof)  # a new integrator starts afresh

    @property
    def state(self) -> State | None:
        return self.data.state

    @property
    def base(self) -> BaseMotion | None:
        return self.data.base

    @property
    def point_loads(self) -> dict[str, PointLoad]:
        return self.data.point_loads

    @property
    def model_forces(self) -> list:
        """The model's force contributions: gravity and the extra ones (the point loads are in the data)."""
        return [self._gravity, *self.extra_forces]

    @property
    def forces(self) -> list:
        """The contributions acting over the next step (:func:`acting_forces`)."""
        return acting_forces(self.model_forces, self.data)

    def tissue_readout(self) -> TissueReadout | None:
        """The tissue readout at the current state (None without tissue or before the start)."""
        if not self.started:
            return None
        for force, own in stateful_forces(self.model_forces, self.data.force_states):
            if isinstance(force, TissueModel):
                return force.readout(self.model, own, self.state, self.base)
        return None

    def set_point_load(self, name: str, arc_length: float, force_world: np.ndarray) -> None:
        """Set (or replace) a named point load; ValueError if outside the needle, not finite, or if the loads
        would sum to more than :func:`max_point_load` (more than the model integrates)."""
        if not 0.0 <= arc_length <= self.model.props.length:
            raise ValueError(f"arc_length {arc_length} m outside the needle [0, {self.model.props.length}] m")
        if not np.all(np.isfinite(force_world)):
            raise ValueError("force must be finite")
        others = sum(_magnitude(load.vector) for key, load in self.point_loads.items() if key != name)
        limit = max_point_load(self.model.props)
        if others + _magnitude(force_world) > limit:
            raise ValueError(f"point load '{name}' of {_magnitude(force_world):.4g} N (with the other "
                             f"loads {others:.4g} N) exceeds the {limit:.3g} N the needle model can integrate "
                             f"({POINT_LOAD_LIMIT:g} E I / L^2)")
        self.point_loads[name] = PointLoad(arc_length, np.asarray(force_world, dtype=float))

    def clear_point_loads(self, names: Sequence[str] = ()) -> int:
        targets = list(self.point_loads) if not names else [n for n in names if n in self.point_loads]
        for name in targets:
            del self.point_loads[name]
        return len(targets)

    # -- base input -----------------------------------------------------------------------------------------
    def offer_pose(self, t: float, position, orientation) -> PoseVerdict:
        """Offer a flange pose; the first valid pose (and a re-anchoring) starts the needle straight there."""
        trajectory, data = self.trajectory, self.data
        latest = trajectory.latest
        verdict = trajectory.offer(t, position, orientation)
        if verdict is PoseVerdict.ACCEPTED or verdict is PoseVerdict.NORMALIZED:
            if data.state is None:
                self.reset(self.base_motion_at(t), t)
            elif latest is not None and t - latest.t > self.pose_timeout and _magnitude(
                    np.asarray(position, dtype=float) - latest.position) > self.input_limits.resume_tolerance:
                trajectory.clear()
                trajectory.offer(t, position, orientation)
                self.reset(self.base_motion_at(t), t)
                return PoseVerdict.RESTARTED
            else:
                if t <= data.state.t:
                    self.statistics.late_poses += 1
                x = (float(t) - data.grid_origin) / self.dt
                data.pose_phase += PHASE_SMOOTHING * (cmath.exp(2j * math.pi * (x - math.floor(x))) - data.pose_phase)
        elif verdict is PoseVerdict.REANCHORED:
            self.reset(self.base_motion_at(t), t)
        return verdict

    def set_twist(self, t: float, linear_velocity: np.ndarray, angular_velocity: np.ndarray) -> None:
        """Velocity feed-forward of the flange (world frame); used instead of the estimate while fresh.
        ValueError beyond :class:`InputLimits` (the twist is then not used)."""
        speed, rate = _magnitude(linear_velocity), _magnitude(angular_velocity)
        limits = self.input_limits
        if not (speed <= limits.max_linear_speed and rate <= limits.max_angular_speed):
            raise ValueError(f"twist |v| = {speed:.3g} m/s, |w| = {rate:.3g} rad/s beyond pose_input.max_linear_speed "
                             f"{limits.max_linear_speed:g} m/s / max_angular_speed {limits.max_angular_speed:g} rad/s")
        self.twist = np.concatenate(([t], np.asarray(linear_velocity, dtype=float).reshape(3),
                                     np.asarray(angular_velocity, dtype=float).reshape(3)))

    def base_motion_at(self, t: float) -> BaseMotion:
        """Motion of the clamp point A at time t from the flange trajectory, the offset and the optional twist."""
        values, rotations = self.base_motions(np.array([t], dtype=float))
        return BaseMotion.from_packed(values[0], rotations[0])

    def base_motions(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Motions of the clamp point A at the given times (k,), packed (k, 19) as :meth:`BaseMotion.from_packed`
        takes them, and their rotations (k, 3, 3)."""
        if self.motions_at is not None:
            return self.motions_at(times)
        if self.base_at is not None:
            motions = [self.base_at(float(t)) for t in times]
            values = np.array([np.concatenate((m.position, m.orientation, m.linear_velocity, m.angular_velocity,
                                               m.linear_acceleration, m.angular_acceleration)) for m in motions])
            return values.reshape(len(times), 19), np.array([m.rotation for m in motions]).reshape(len(times), 3, 3)
        flange = self.trajectory.motions_at(times)
        apply_twist(flange, times, NO_TWIST if self.twist is None else self.twist, self.twist_timeout)
        values, rotations = np.empty_like(flange), np.empty((len(times), 3, 3))
        compose_offsets(flange, self._offset_position, self._offset_rotation, values, rotations)
        return values, rotations

    def pose_age(self, now: float) -> float:
        latest = self.trajectory.latest
        return now - latest.t if latest is not None else float("inf")

    def target_time(self, now: float, deterministic: bool, ahead_to_pose: bool = False) -> float:
        """Time the model should reach at clock time ``now`` (see the module docstring)."""
        latest = self.trajectory.latest
        if deterministic and latest is not None and now - latest.t <= self.pose_timeout:
            return min(now, latest.t)
        if ahead_to_pose and latest is not None and latest.t > now - self.dt:
            # grid indices (a pose within 1 us after a step's end time counts as at it: epoch-time resolution)
            to_pose = math.ceil((latest.t - self.data.grid_origin) / self.dt - 1e-3)
            after_now = math.floor((now - self.data.grid_origin) / self.dt + 1e-3) + 1
            return max(now, self._grid_time(min(to_pose, after_now)))
        return now

    # -- time stepping --------------------------------------------------------------------------------------
    @property
    def started(self) -> bool:
        return self.state is not None

    def reset(self, base: BaseMotion, t: float) -> None:
        """Straight, unloaded needle at rest relative to the base at time t (clamped there, if configured)."""
        if self.clamp_interval is not None:
            fixture = Fixture(interval=self.clamp_interval, frame="world",
                              needle_pose=(base.position, base.orientation))
            self.model, self.integrator = self.model_builder((fixture,))
            self.data.integrator = IntegratorMemory(self.model.n_dof)
        if self.extra_forces_builder is not None:
            self.extra_forces = list(check_forces(self.extra_forces_builder(self.model)))
        state = self.model.straight_state(base, t)
        self._start(self._equilibrium(state) if self.start_in_equilibrium else state, base)

    def start_from(self, state: State) -> None:
        """Continue from a given state (e.g. a static equilibrium) at ``state.t`` instead of the straight needle,
        the base at its motion then; the step grid restarts there."""
        self._start(state, state.base if state.base is not None else (
            self.base_at(state.t) if self.base_at is not None else self.base))

    def _start(self, state: State, base: BaseMotion) -> None:
        """The data of a (re)started needle: its state and base, a new step grid from state.t, fresh force states
        (the integrator's memory is kept, as a restart keeps the integrator)."""
        data = self.data
        data.state, data.base = state, base
        data.grid_origin, data.step_index, data.pose_phase = float(state.t), 0, 0j
        data.force_states = initial_force_states(self.model, self.model_forces)

    def _equilibrium(self, straight: State) -> State:
        """The needle at rest relative to the base in static equilibrium under gravity and the point loads (tissue,
        made anew at a reset, holds nothing yet); the straight state if Newton finds none."""
        try:
            q = solve_static(self.model, straight.base, [self._gravity, *self.point_loads.values()],
                             t=straight.t).state.q
        except StaticSolveFailed:
            self.statistics.straight_starts += 1
            return straight
        return replace(straight, q=q)

    def discard_state(self) -> None:
        """Forget the state (e.g. the clock jumped back); the next :meth:`reset` starts again."""
        self.data.state = None

    def advance(self, now: float, deterministic: bool, ahead_to_pose: bool = False) -> list[StepRecord]:
        """Integrate up to :meth:`target_time`; a clock that jumped back (looping bag) discards the state."""
        state = self.data.state
        if state is not None and now < state.t - self.pose_timeout:
            self.trajectory.clear()
            self.discard_state()
        elif ahead_to_pose and not deterministic and state is not None:
            self.lock_phase()
        return self.advance_to(self.target_time(now, deterministic, ahead_to_pose))

    def lock_phase(self) -> None:
        """Shift the step grid so that its steps end half a step after the poses' mean phase (``pose_phase``), if
        the poses come at a consistent phase (:data:`PHASE_COHERENCE`) more than :data:`PHASE_TOLERANCE` steps from
        mid-step. The next step then lasts (1 + shift) dt, shift in [-0.5, 0.5); the later ones dt."""
        data = self.data
        if abs(data.pose_phase) < PHASE_COHERENCE:
            return
        mean = cmath.phase(data.pose_phase) / (2.0 * math.pi)  # the poses' mean phase after the step ends
        shift = (mean - 0.5) - math.floor(mean)  # mean - 0.5 wrapped to [-0.5, 0.5)
        if abs(shift) > PHASE_TOLERANCE:
            data.grid_origin += shift * self.dt
            data.pose_phase *= cmath.exp(-2j * math.pi * shift)

    def advance_to(self, t_target: float) -> list[StepRecord]:
        """Integrate with fixed steps of dt until the next step would pass t_target.

        If the simulation lags more than ``max_catch_up`` behind, the skipped interval is not integrated: the
        state jumps forward in time (shape and velocities kept) and the skipped time is counted. Runs of steps go
        through the integrator's compiled sequence where it applies (:meth:`Integrator.supports_sequence`).
        """
        records: list[StepRecord] = []
        data = self.data
        if data.state is None:
            return records
        dt = self.dt
        lag = t_target - data.state.t
        if lag > self.max_catch_up:
            skip = math.floor((lag - self.max_catch_up) / dt)
            data.step_index += skip
            data.state = replace(data.state, t=self._grid_time(data.step_index))
            self.statistics.skipped_time += skip * dt
        # steps whose end time reaches t_target up to the float resolution of the times (0.24 us at epoch times)
        slack = 4.0 * math.ulp(abs(t_target)) + 1e-9 * dt
        count = math.floor((t_target + slack - data.grid_origin) / dt) - data.step_index
        if count <= 0:
            return records
        times = np.array([self._grid_time(index) for index in range(data.step_index + 1, data.step_index + count + 1)])
        # the compiled sequence takes time-invariant forces only; contributions that run compiled (the tissue,
        # CompiledContributions) take a run composing them all, a step at a time if a hook reads each step's state
        stateful = [force for force in self.extra_forces if force.stateful]
        runs = [force for force in self.extra_forces if force.compiled_run]
        sequence = self.compiled_sequence and not stateful and not runs
        run = runs if self.compiled_sequence and runs and all(f.compiled_run for f in stateful) else None
        first_dt = float(times[0]) - data.state.t
        regular = abs(first_dt - dt) <= 0.05 * dt + 4.0 * math.ulp(abs(t_target))  # not after a grid shift
        # the base from the received poses: a compiled run evaluates its motions and takes its steps in one call
        from_poses = self.base_at is None and self.motions_at is None
        run_sequence = self._advance_from_trajectory if from_poses else self._step_sequence
        forces = self._sequence_forces(sequence)
        if from_poses and regular and forces is not None:
            motions, rotations = np.empty((count, 19)), np.empty((count, 3, 3))  # the run fills them
        else:
            motions, rotations = self.base_motions(times)  # once: the general path takes them one at a time
        i = 0
        general = False  # whether a step left the compiled sequence (whose converged states are finite)
        if not regular:  # after a grid shift (lock_phase)
            if not (forces is not None
                    and self._step_sequence(forces, times[:1], motions[:1], rotations[:1], records, first_dt)):
                records.append(self._step_or_restart(BaseMotion.from_packed(motions[0], rotations[0]), times[0],
                                                     first_dt))
                general = True
            data.step_index += 1
            i = 1
            forces = self._sequence_forces(sequence)
        while i < count:
            if forces is not None:
                done = run_sequence(forces, times[i:], motions[i:], rotations[i:], records)
                data.step_index += done
                i += done
            elif run is not None and data.state.aux is not None:
                general = True
                stop = i + 1 if self.after_step is not None else count
                done = self._run_steps(run, times[i:stop], motions[i:stop], rotations[i:stop], records)
                data.step_index += done
                i += done
                if i == stop:  # all it was asked for: the next run (a step that failed takes the general step)
                    continue
            if i < count:
                records.append(self._step_or_restart(BaseMotion.from_packed(motions[i], rotations[i]), times[i]))
                general = True
                data.step_index += 1
                i += 1
                forces = self._sequence_forces(sequence)
        if general and not np.isfinite(data.state.q).all():  # never carry a non-finite state on
            self.statistics.failed_steps += 1
            data.state = self.model.straight_state(self.base, data.state.t)
        return records

    @property
    def next_step_end(self) -> float:
        """End time [s] of the next step on the grid (a shifted grid's next step is shorter or longer than dt)."""
        return self._grid_time(self.data.step_index + 1)

    def _grid_time(self, index):
        """End time of step ``index`` since the (re)start: origin + index dt, rounded once (no accumulation: at
        epoch times a sum of 1 ms steps would drift by 70 ns per step)."""
        return self.data.grid_origin + self.dt * index

    def _sequence_forces(self, sequence: bool) -> list | None:
        """The contributions of a compiled run from the current state, or None where it does not apply (``sequence``
        False: a stateful contribution; no consistent accelerations yet; or a contribution the sequence cannot take).
        Without stateful contributions they are the same objects while the integrator, the model's contributions
        and the point loads are: then the same list as before."""
        data = self.data
        if not (sequence and data.state.aux is not None):
            return None
        key = (self.integrator, *self.extra_forces, *data.point_loads.values())
        cached_key, forces = self._sequence_plan
        if not same_objects(key, cached_key):
            forces = self.forces
            forces = forces if self.integrator.supports_sequence(forces) else None
            self._sequence_plan = (key, forces)
        return forces

    def _step_sequence(self, forces: list, times: np.ndarray, motions: np.ndarray, rotations: np.ndarray,
                       records: list[StepRecord], dt: float | None = None) -> int:
        """Steps of ``dt`` (default: the simulation's) at the given times in one compiled run under ``forces`` (see
        :meth:`advance_to`); returns how many were done."""
        start = time.perf_counter()
        result = self.integrator.step_sequence(self.state, self.dt if dt is None else dt, motions, rotations, forces,
                                               self.data.integrator)
        self._record_run(result, start, times, motions, rotations, records)
        return result.done

    def _advance_from_trajectory(self, forces: list, times: np.ndarray, motions: np.ndarray, rotations: np.ndarray,
                                 records: list[StepRecord]) -> int:
        """Steps at ``times`` under ``forces`` with the base from the trajectory in one compiled call
        (:mod:`needle_sim_ros.compiled_advance`), the base motions at all the times written into ``motions`` and
        ``rotations`` first (a run that stops early leaves them for the general step); returns how many steps were
        done (as :meth:`_step_sequence`)."""
        start = time.perf_counter()
        state = self.data.state
        before, after = self.integrator.sequence_arguments(self.dt, forces, float(times[0]), times.size,
                                                           self.data.integrator)
        fit, corrections, done = advance_from_trajectory(
            *self.trajectory.fit_arguments(), times, np.empty((times.size, 19)),
            NO_TWIST if self.twist is None else self.twist, self.twist_timeout, self._offset_position,
            self._offset_rotation, motions, rotations, state.q, state.qd, state.qdd, state.aux, *before, *after)
        self.trajectory.take_fit(fit, corrections, float(times[-1]))
        self._record_run(SequenceResult.of_run(done, after), start, times, motions, rotations, records)
        return done

    def _record_run(self, result, start: float, times: np.ndarray, motions: np.ndarray, rotations: np.ndarray,
                    records: list[StepRecord]) -> None:
        """Records, hook calls, statistics and the final state of a compiled run started at ``start``."""
        done = result.done
        if not done:
            return
        wall = (time.perf_counter() - start) / done
        hook = self.after_step
        end_times, iterations = times[:done].tolist(), result.iterations.tolist()
        for i, (t, w) in enumerate(zip(end_times, result.wrenches)):
            record = StepRecord(t, BaseWrench(w[0:3], w[3:6], w[6:9], w[9:12]), iterations[i], 1, wall)
            records.append(record)
            if hook is not None:  # the hook reads the state of its step
                self._set_state(result.states[i], t, motions[i], rotations[i])
                hook(record)
        if hook is None:  # otherwise the last step's state is set already
            self._set_state(result.states[done - 1], end_times[-1], motions[done - 1], rotations[done - 1])
        stats = self.statistics
        stats.steps += done
        stats.step_wall_times.extend([wall] * done)
        stats.max_newton_iterations = max(stats.max_newton_iterations, *iterations)

    def _run_steps(self, runs: list, times: np.ndarray, motions: np.ndarray, rotations: np.ndarray,
                   records: list[StepRecord]) -> int:
        """Steps at the given times in one compiled run composing the contributions ``runs`` (the tissue,
        CompiledContributions; every stateful one among them) where the others are time-invariant (see
        :meth:`advance_to`); returns how many were done."""
        data = self.data
        others = [*(force for force in self.model_forces if not force.compiled_run), *data.point_loads.values()]
        if not self.integrator.supports_sequence(others):
            return 0
        start = time.perf_counter()
        if self._run_plan is None or not same_objects(runs, self._run_plan.contributions):
            self._run_plan = ContributionRun(runs)
        states = iter(data.force_states)  # in the order of the stateful contributions, all among ``runs``
        owns = [next(states) if force.stateful else None for force in runs]
        result, owns = self._run_plan(self.model, self.integrator, self.state, owns, self.dt, times, motions,
                                      rotations, others, data.integrator)
        data.force_states = tuple(own for force, own in zip(runs, owns) if force.stateful)
        self._record_run(result, start, times, motions, rotations, records)
        return result.done

    def _set_state(self, rows: np.ndarray, t: float, motion: np.ndarray, rotation: np.ndarray) -> None:
        base = BaseMotion.from_packed(motion, rotation)
        self.data.state, self.data.base = State(rows[0], rows[1], rows[2], float(t), rows[3], base), base

    def step(self, base_next: BaseMotion, t_next: float, dt: float | None = None) -> StepRecord:
        """One step of ``dt`` (default: the simulation's) with the general integrator path (sub-stepping,
        state-dependent forces) to t_next (:func:`needle_sim_ros.model.step`): if anything fails the data is as
        before the step and the error raised (StepFailed: counted in ``statistics.failed_steps``)."""
        start = time.perf_counter()
        try:
            output = step(self.model, self.integrator, self.model_forces, self.data,
                          StepInputs(self.dt if dt is None else dt, float(t_next), base_next))
        except StepFailed:
            self.statistics.failed_steps += 1
            raise
        return self._finish_step(start, output.wrench, output.newton_iterations, output.substeps)

    def _step_or_restart(self, base_next: BaseMotion, t_next: float, dt: float | None = None) -> StepRecord:
        """:meth:`step`, or if it fails the needle restarted straight at the base (the forces' state is that of the
        last accepted step: the restarted needle has not moved through the tissue); with ``restart_on_failure``
        False the StepFailed is raised."""
        start = time.perf_counter()
        try:
            return self.step(base_next, t_next, dt)
        except StepFailed:
            if not self.restart_on_failure:
                raise
            self.data.state = self.model.straight_state(base_next, float(t_next))
            self.data.base = base_next
            return self._finish_step(start, reaction_wrench(self.model, self.state, base_next, self.forces), 0, 0)

    def _finish_step(self, start: float, wrench: BaseWrench, iterations: int, substeps: int) -> StepRecord:
        """Statistics, record and hook of the step that led to the current state, with its base wrench."""
        wall = time.perf_counter() - start
        stats = self.statistics
        stats.steps += 1
        stats.max_newton_iterations = max(stats.max_newton_iterations, iterations)
        stats.step_wall_times.append(wall)
        record = StepRecord(self.state.t, wrench, iterations, substeps, wall)
        if self.after_step is not None:
            self.after_step(record)
        return record

    # -- outputs --------------------------------------------------------------------------------------------
    def shape(self, n_samples: int) -> ModelShape:
        """The shape output of the current state (the tip frame carries the base orientation)."""
        return model_shape(self.model, self.state.q, self.state.t, n_samples,
                           None if self.base is None else self.base.orientation)

    def energies(self) -> tuple[float, float]:
        return kinetic_energy(self.model, self.state.qd), elastic_energy(self.model, self.state.q)


def model_builder_from_parameters(p: dict) -> ModelBuilder:
    """fixtures -> (model, integrator) as the `needle_simulator` parameters (flat dotted names) describe them;
    ``needle.element_lengths`` [m] other than [0.0] sets the mesh instead of uniform ``needle.elements``."""
    props = needle_properties(p)
    lengths = element_lengths(p)

    def model_builder(fixtures: tuple = ()) -> tuple[NeedleModel, Integrator]:
        model = build_model(props, n_elements=len(lengths) if lengths else p["needle.elements"],
                            element_lengths=lengths, axial_gauss=p["needle.axial_gauss_points"],
                            bending_gauss=p["needle.bending_gauss_points"], rayleigh_alpha=p["damping.rayleigh_alpha"],
                            rayleigh_beta=p["damping.rayleigh_beta"], fixtures=fixtures)
        integrator = Integrator(model, method=p["integrator.method"], rho_inf=p["integrator.rho_inf"],
                                newton_tol=p["integrator.newton_tolerance"],
                                max_newton_iterations=p["integrator.max_newton_iterations"],
                                max_substep_halvings=p["integrator.max_substep_halvings"])
        return model, integrator

    return model_builder


def simulation_from_parameters(p: dict) -> NeedleSimulation:
    """The simulator described by the `needle_simulator` parameters (flat dotted names, validated values).

    One construction for the node and the offline pipeline, so both run the same simulator. Raises ParameterError
    for element lengths the mesh rejects, ValueError for tissue parameters that the tissue models reject.
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
    if len(clamp) == 2 and not 0.0 <= clamp[0] <= clamp[1] <= model.props.length:
        raise ParameterError(f"parameter 'fixtures.clamp_interval' = {list(clamp)}: must satisfy 0 <= s_start <= "
                             f"s_end <= needle.length = {model.props.length:g} m")
    if p["tissue.enable"]:
        tissue_builder(model)  # reject bad tissue parameters now, not at the first pose
    sim = NeedleSimulation(
        model, integrator, p["integrator.dt"], trajectory,
        flange_offset=(np.asarray(p["flange_offset.position"], dtype=float),
                       np.asarray(p["flange_offset.orientation"], dtype=float)),
        extra_forces_builder=tissue_builder if p["tissue.enable"] else None, max_catch_up=p["loop.max_catch_up"],
        pose_timeout=p["pose_input.timeout"],
        twist_timeout=p["pose_input.twist_timeout"], clamp_interval=tuple(clamp) if len(clamp) == 2 else None,
        model_builder=model_builder, input_limits=InputLimits(
            p["pose_input.max_linear_speed"], p["pose_input.max_angular_speed"], p["pose_input.resume_tolerance"]),
        start_in_equilibrium=p["needle.start_in_equilibrium"])
    tip_force = np.asarray(p["loads.tip_force"], dtype=float)
    if np.any(tip_force != 0.0):
        try:
            sim.set_point_load(TIP_FORCE_PARAMETER, model.props.length, tip_force)
        except ValueError as error:
            raise ValueError(f"parameter 'loads.tip_force' = {tip_force.tolist()}: {error}") from error
    return sim


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
