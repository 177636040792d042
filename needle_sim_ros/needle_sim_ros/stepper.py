"""The simulator's stepper (ROS-free): model, data and integrator, taking the steps at the end times the clock loop
hands it -- compiled runs where they apply, the general step (:func:`needle_sim_ros.model.step`) otherwise, a
straight restart where a step fails -- with the base motions from a base source (:mod:`needle_sim_ros.base_input`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from itertools import repeat
from typing import Callable, NamedTuple, Sequence

import numpy as np

from needle_sim_ros.compiled_advance import advance_from_trajectory, advance_plan
from needle_sim_ros.model import (BaseMotion, BaseWrench, Gravity, Integrator, ModelShape, NeedleData, NeedleModel,
                                  NeedleProperties, PointLoad, State, StaticSolveFailed, StepFailed,
                                  acting_forces, check_forces, elastic_energy, initial_force_states, kinetic_energy,
                                  model_shape, reaction_wrench, solve_static, stateful_forces, step)
from needle_sim_ros.model.contribution import ContributionRun
from needle_sim_ros.model.integrators import IntegratorMemory, run_outputs, same_objects
from needle_sim_ros.model.partition import held_at
from needle_sim_ros.model.records import compiled_entry

# Largest sum of point-load magnitudes, as a multiple of the needle's bending load scale E I / L^2. Found by
# experiment (README, reliability): with the default discretisation (10 elements, 2 axial Gauss points, dt = 1 ms,
# 4 sub-step halvings) a tip load applied at once to the straight needle integrates up to 20.7 E I / L^2 (7 N for
# the seed 000 needle) compressive and 30 E I / L^2 transverse, while 25 E I / L^2 (8.45 N) compressive fails half
# the steps; 20 keeps a margin (6.8 N).
POINT_LOAD_LIMIT = 20.0

ModelBuilder = Callable[[tuple], tuple[NeedleModel, Integrator]]


def max_point_load(props: NeedleProperties) -> float:
    """Largest total point load [N] the simulator accepts for this needle (:data:`POINT_LOAD_LIMIT` E I / L^2)."""
    return POINT_LOAD_LIMIT * props.EI / props.length ** 2


def magnitude(vector) -> float:
    """Euclidean norm, inf (without an overflow warning) for vectors beyond the float range."""
    with np.errstate(over="ignore"):
        return float(np.linalg.norm(np.asarray(vector, dtype=float)))


def _motion(motions, rotations: np.ndarray | None, index: int) -> BaseMotion:
    """Base motion ``index`` of a run's: packed (k, 19) with ``rotations``, or BaseMotions (``rotations`` None)."""
    return motions[index] if rotations is None else BaseMotion.from_packed(motions[index], rotations[index])


class StepRecord(NamedTuple):
    """What one accepted step produced: its end time, the base wrench and the integrator's effort."""

    t: float
    wrench: BaseWrench
    newton_iterations: int
    substeps: int
    wall_time: float


@dataclass
class LoopStatistics:
    """Counters reported in diagnostics: the stepper's steps and failures, the clock loop's skipped time and late
    poses."""

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

    def count_steps(self, done: int, wall: float, newton_iterations: int) -> None:
        """``done`` accepted steps of ``wall`` [s] each, the most Newton iterations among them
        ``newton_iterations``."""
        self.steps += done
        self.step_wall_times += [wall] * done
        if newton_iterations > self.max_newton_iterations:
            self.max_newton_iterations = newton_iterations

    def take_step_time_ms(self, empty: float | None) -> dict[str, float | None]:
        """``step_time_mean_ms`` and ``step_time_max_ms`` [ms] of the steps since the last call (``empty`` without
        steps)."""
        times, self.step_wall_times = np.array(self.step_wall_times), []
        return {"step_time_mean_ms": float(times.mean() * 1e3) if times.size else empty,
                "step_time_max_ms": float(times.max() * 1e3) if times.size else empty}


class Stepper:
    """The model, its data and the integrator; steps at given end times.

    The model never changes while the needle is simulated: a clamp (a :class:`Fixture` of the frame "start", e.g.
    the distal 40 % in the dynamic experiment of seed 000, Fig. 8) holds its nodes where they lay when the needle was
    (re)started, a pose kept in the data (``data.integrator.clamp``).

    ``extra_forces_builder(model)`` makes the extra force contributions (e.g. the tissue model, whose state --
    track, stick anchors -- is kept in the data) acting every step in addition to gravity and the named point
    loads; they are made anew at every reset (and checked against the force protocol, :func:`check_forces`), with
    fresh states, so a restarted needle starts in fresh tissue. A step that fails even after the integrator's
    sub-stepping restarts the needle straight at the current base pose (:meth:`step`): the output never
    contains NaN. ``compiled_sequence`` False keeps every step on the general path (benchmarks of that path).

    ``start_in_equilibrium``: a (re)started needle is at rest in static equilibrium under gravity and the point loads
    (seed 000 eq. 17 without inertia) instead of straight, so it does not first drop and swing (a free 18 G needle
    would sag 2.3 mm and ring for seconds); if no equilibrium is found it starts straight
    (``statistics.straight_starts``).
    """

    def __init__(self, model: NeedleModel, integrator: Integrator, dt: float,
                 extra_forces_builder: Callable[[NeedleModel], list] | None = None, start_in_equilibrium: bool = False,
                 restart_on_failure: bool = True) -> None:
        self.model = model
        self.integrator = integrator
        self.dt = dt
        self.extra_forces_builder = extra_forces_builder
        self.extra_forces: list = []  # the model's contributions besides gravity (the tissue)
        self.after_step: Callable[[StepRecord], None] | None = None  # called with the state of each accepted step
        self.data = NeedleData(integrator=IntegratorMemory(model.n_dof))  # everything a step changes
        self.statistics = LoopStatistics()
        self._gravity = Gravity()
        self.start_in_equilibrium = start_in_equilibrium
        self.restart_on_failure = restart_on_failure
        self.compiled_sequence = True
        self._sequence_plan: tuple = ((), None)  # (key, forces) of _sequence_forces
        self._run_plan: ContributionRun | None = None  # the composed compiled run of _run_steps
        # (integrator, forces, memory, base source, AdvancePlan, compiled entry) of _advance_from_trajectory's call:
        # the plan while the others hold
        self._advance_plan: tuple = (None,) * 6
        self.source = None  # the base source of the current run

    def rebuild_model(self, model_builder: ModelBuilder) -> None:
        """Swap in a model built with other damping (the one run-time model parameter), keeping the fixtures and the
        pose of the clamp."""
        self.model, self.integrator = model_builder(self.model.fixtures)
        clamp = self.data.integrator.clamp
        self.data.integrator = IntegratorMemory(self.model.n_dof)  # a new integrator starts afresh
        self.data.integrator.clamp = clamp

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

    def tissue_readout(self):
        """The readout of the first contribution that has one (the tissue: ``readout(model, own, state, base)``) at
        the current state; None without such a contribution or before the start."""
        if self.state is None:
            return None
        for force, own in stateful_forces(self.model_forces, self.data.force_states):
            if hasattr(force, "readout"):
                return force.readout(self.model, own, self.state, self.base)
        return None

    def set_point_load(self, name: str, arc_length: float, force_world: np.ndarray) -> None:
        """Set (or replace) a named point load; ValueError if outside the needle, not finite, or if the loads
        would sum to more than :func:`max_point_load` (more than the model integrates)."""
        if not 0.0 <= arc_length <= self.model.props.length:
            raise ValueError(f"arc_length {arc_length} m outside the needle [0, {self.model.props.length}] m")
        if not np.all(np.isfinite(force_world)):
            raise ValueError("force must be finite")
        others = sum(magnitude(load.vector) for key, load in self.point_loads.items() if key != name)
        limit = max_point_load(self.model.props)
        if others + magnitude(force_world) > limit:
            raise ValueError(f"point load '{name}' of {magnitude(force_world):.4g} N (with the other "
                             f"loads {others:.4g} N) exceeds the {limit:.3g} N the needle model can integrate "
                             f"({POINT_LOAD_LIMIT:g} E I / L^2)")
        self.point_loads[name] = PointLoad(arc_length, np.asarray(force_world, dtype=float))

    def clear_point_loads(self, names: Sequence[str] = ()) -> int:
        targets = list(self.point_loads) if not names else [n for n in names if n in self.point_loads]
        for name in targets:
            del self.point_loads[name]
        return len(targets)

    # -- (re)start --------------------------------------------------------------------------------------------
    def reset(self, base: BaseMotion, t: float) -> None:
        """Straight, unloaded needle at rest relative to the base at time t (clamped there, if the model clamps)."""
        if self.model.partition.held:  # the integrator starts afresh with the new clamp pose
            self.data.integrator = IntegratorMemory(self.model.n_dof)
        if self.extra_forces_builder is not None:
            self.extra_forces = list(check_forces(self.extra_forces_builder(self.model)))
        state = self.model.straight_state(base, t)
        self.start(self._equilibrium(state) if self.start_in_equilibrium else state, base)

    def start(self, state: State, base: BaseMotion) -> None:
        """The data of a (re)started needle: its state and base, the clamp held there, fresh force states (the
        integrator's memory is kept, as a restart keeps the integrator; the step grid is the clock loop's)."""
        data = self.data
        data.state = state if state.base is base else replace(state, base=base)
        data.integrator.clamp = held_at(base)
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

    # -- steps ------------------------------------------------------------------------------------------------
    def run(self, times: np.ndarray, source, t_target: float) -> list[StepRecord]:
        """Steps ending at ``times`` (the clock loop's grid up to ``t_target``; the first may be shorter or longer
        than dt after a grid shift) with the base motions from ``source`` (a
        :class:`~needle_sim_ros.base_input.BaseInput`). Runs of steps go through the integrator's compiled sequence
        where it applies (:meth:`Integrator.supports_sequence`)."""
        records: list[StepRecord] = []
        data, dt, count = self.data, self.dt, times.size
        # the compiled sequence takes time-invariant forces only; contributions that run compiled (the tissue,
        # CompiledContributions) take a run composing them all, a step at a time if a hook reads each step's state
        sequence, run = self.compiled_sequence, None
        if self.extra_forces:
            stateful = [force for force in self.extra_forces if force.stateful]
            runs = [force for force in self.extra_forces if force.compiled_run]
            sequence = sequence and not stateful and not runs
            run = runs if self.compiled_sequence and runs and all(f.compiled_run for f in stateful) else None
        first_dt = float(times[0]) - data.time
        regular = abs(first_dt - dt) <= 0.05 * dt + 4.0 * math.ulp(abs(t_target))  # not after a grid shift
        # the base from the received poses: a compiled run evaluates its motions and takes its steps in one call
        from_poses = source.from_poses
        self.source = source
        run_sequence = self._advance_from_trajectory if from_poses else self._step_sequence
        forces = self._sequence_forces(sequence)
        if from_poses and regular and forces is not None:
            motions, rotations = np.empty((count, 19)), np.empty((count, 3, 3))  # the run fills them
        else:  # once: the general path takes them one at a time (a prescribed base's own, where every step does)
            prescribed = None if sequence or run is not None else source.prescribed_motions(times)
            motions, rotations = source.motions(times) if prescribed is None else (prescribed, None)

        i = 0
        general = False  # whether a step left the compiled sequence (whose converged states are finite)
        if not regular:  # after a grid shift (lock_phase)
            if not (forces is not None
                    and self._step_sequence(forces, times[:1], motions[:1], rotations[:1], records, first_dt)):
                records.append(self.step(_motion(motions, rotations, 0), times[0], first_dt))
                general = True
            data.step_index += 1
            i = 1
            forces = self._sequence_forces(sequence)
        while i < count:
            if forces is not None:
                done = run_sequence(forces, times[i:], motions[i:], rotations[i:], records) if i else \
                    run_sequence(forces, times, motions, rotations, records)
                data.step_index += done
                i += done
            elif run is not None and data.with_history:
                general = True
                stop = i + 1 if self.after_step is not None else count
                done = self._run_steps(run, times[i:stop], motions[i:stop], rotations[i:stop], records)
                data.step_index += done
                i += done
                if i == stop:  # all it was asked for: the next run (a step that failed takes the general step)
                    continue
            if i < count:
                records.append(self.step(_motion(motions, rotations, i), times[i]))
                general = True
                data.step_index += 1
                i += 1
                forces = self._sequence_forces(sequence) if sequence else None
        if general and not np.isfinite(data.state.q).all():  # never carry a non-finite state on
            self.statistics.failed_steps += 1
            data.state = self.model.straight_state(self.base, data.state.t, data.integrator.clamp)
        return records

    def _sequence_forces(self, sequence: bool) -> list | None:
        """The contributions of a compiled run from the current state, or None where it does not apply (``sequence``
        False: a stateful contribution; no consistent accelerations yet; or a contribution the sequence cannot take).
        Without stateful contributions they are the same objects while the integrator, the model's contributions
        and the point loads are: then the same list as before."""
        data = self.data
        if not (sequence and data.with_history):
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
        :meth:`run`); returns how many were done."""
        start = time.perf_counter()
        result = self.integrator.step_sequence(self.state, self.dt if dt is None else dt, motions, rotations, forces,
                                               self.data.integrator)
        self._record_run(result.done, result[1:], start, times, motions, rotations, records)
        return result.done

    def _advance_from_trajectory(self, forces: list, times: np.ndarray, motions: np.ndarray, rotations: np.ndarray,
                                 records: list[StepRecord]) -> int:
        """Steps at ``times`` under ``forces`` with the base from the trajectory of :meth:`run`'s ``source`` in one
        compiled call (:mod:`needle_sim_ros.compiled_advance`), the base motions at all the times written into
        ``motions`` and ``rotations`` first (a run that stops early leaves them for the general step); returns how
        many steps were done (as :meth:`_step_sequence`)."""
        began = time.perf_counter()
        data, source = self.data, self.source
        memory, integrator, work = data.integrator, self.integrator, self.integrator.work
        start, index = data.start_rows()
        outputs = run_outputs(times.size, start.shape[2])
        plan_integrator, plan_forces, plan_memory, plan_source, plan, advance = self._advance_plan
        if not (plan_forces is forces and plan_memory is memory and plan_integrator is integrator
                and plan_source is source and memory.h == self.dt and (not work.held or work.clamp is memory.clamp)):
            # else: the checks and caches of sequence_arguments
            before = integrator.sequence_arguments(self.dt, forces, float(times[0]), memory)
            plan = advance_plan(*before[1:], memory.last_motion, *source.trajectory.buffers, source.packed)
            # the arguments' types hold with the plan: times (k,) of the clock loop, the rows and arrays made here
            advance = compiled_entry(advance_from_trajectory, plan, times, motions, rotations, start, index, *outputs)
            self._advance_plan = (integrator, forces, memory, source, plan, advance)
        done = advance(plan, times, motions, rotations, start, index, *outputs)
        self._record_run(done, outputs, began, times, motions, rotations, records)
        return done

    def _record_run(self, done: int, outputs: tuple, start: float, times: np.ndarray, motions: np.ndarray,
                    rotations: np.ndarray, records: list[StepRecord]) -> None:
        """Records, hook calls, statistics and the final state of the first ``done`` steps of a compiled run's
        ``outputs`` (states, wrenches, iterations: :func:`~needle_sim_ros.model.integrators.run_outputs`) started at
        ``start``."""
        if not done:
            return
        wall = (time.perf_counter() - start) / done
        hook = self.after_step
        states, wrenches, iterations = outputs
        if done == 1 and hook is None:  # the live loop's run: one step per pose
            w, n, t = wrenches[0], iterations.item(0), float(times[0])
            records.append(StepRecord(t, BaseWrench(w), n, 1, wall))
            self.data.end_run(states, 0, t, motions, rotations)
            self.statistics.count_steps(1, wall, n)
            return
        end_times, counts = times[:done].tolist(), iterations[:done].tolist()
        if hook is None:  # the records, then the last step's state
            records += map(StepRecord, end_times, map(BaseWrench, wrenches), counts, repeat(1), repeat(wall))
            self.data.end_run(states, done - 1, end_times[-1], motions, rotations)
        else:  # the hook reads the state of its step
            for i, (t, w) in enumerate(zip(end_times, wrenches)):
                record = StepRecord(t, BaseWrench(w), counts[i], 1, wall)
                records.append(record)
                self.data.end_run(states, i, t, motions, rotations)
                hook(record)
        self.statistics.count_steps(done, wall, max(counts))

    def _run_steps(self, runs: list, times: np.ndarray, motions: np.ndarray, rotations: np.ndarray,
                   records: list[StepRecord]) -> int:
        """Steps at the given times in one compiled run composing the contributions ``runs`` (the tissue,
        CompiledContributions; every stateful one among them) where the others are time-invariant (see
        :meth:`run`); returns how many were done."""
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
        self._record_run(result.done, result[1:], start, times, motions, rotations, records)
        return result.done

    def step(self, base_next: BaseMotion, t_next: float, dt: float | None = None) -> StepRecord:
        """One step of ``dt`` (default: the simulation's) to t_next on the general integrator path (sub-stepping,
        state-dependent forces: :func:`needle_sim_ros.model.step`). A step that fails (StepFailed, counted in
        ``statistics.failed_steps``) leaves the data as before it; the needle then restarts straight at the base
        (the forces' state is that of the last accepted step: the restarted needle has not moved through the
        tissue), or with ``restart_on_failure`` False the StepFailed is raised."""
        start = time.perf_counter()
        try:
            output = step(self.model, self.integrator, self.model_forces, self.data, self.dt if dt is None else dt,
                          float(t_next), base_next)
        except StepFailed:
            self.statistics.failed_steps += 1
            if not self.restart_on_failure:
                raise
            self.data.state = self.model.straight_state(base_next, float(t_next), self.data.integrator.clamp)
            return self._finish_step(start, reaction_wrench(self.model, self.state, base_next, self.forces), 0, 0)
        return self._finish_step(start, output.wrench, output.newton_iterations, output.substeps)

    def _finish_step(self, start: float, wrench: BaseWrench, iterations: int, substeps: int) -> StepRecord:
        """Statistics, record and hook of the step that led to the current state, with its base wrench."""
        wall = time.perf_counter() - start
        self.statistics.count_steps(1, wall, iterations)
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
