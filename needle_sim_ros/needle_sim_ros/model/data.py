"""All mutable state of a simulated needle, and the one step that advances it (MuJoCo's mjData and mj_step).

The :class:`NeedleModel`, the integrator's settings and the force contributions' parameters never change while a
needle is simulated; everything that does is in one :class:`NeedleData`. :func:`step` advances it by one step
in fixed phases and changes it only once the step has succeeded: a failed step leaves it bit for bit as it was.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .forces import PointLoad, check_forces
from .integrators import Integrator, IntegratorMemory, StepResult
from .kinematics import BaseMotion
from .model import NeedleModel, State
from .reaction import reaction_wrench


@dataclass
class NeedleData:
    """Everything a step changes, in one place:

    * ``state``: t, q, q', q'', the integrator's history a of the last accepted step and the base motion (clamp
      point A) at t (None: not started; :attr:`base` is the state's). A compiled run leaves its outputs and the
      index and end time of its last step (:meth:`end_run`); its :class:`State` is made when first read (the live
      loop's next step reads only the rows and the time: :meth:`start_rows`, :attr:`time`);
    * ``grid_origin`` [s], ``step_index``: steps end at grid_origin + step_index dt (set at each (re)start; the
      live time loop may shift the origin by less than a step to keep the grid half a step from the poses);
    * ``pose_phase``: the poses' phase on the step grid, a running mean of exp(2 pi i x) over the accepted poses,
      x = (pose time - grid_origin) / dt (0 at each (re)start; see ``ClockLoop.lock_phase``);
    * ``integrator``: the integrator's memory between steps: which predictor Newton starts from, and the
      factorization the compiled sequence keeps across steps while the base holds still (with its validity, step
      length and base motion);
    * ``point_loads``: the named external point loads (world frame);
    * ``force_states``: the state of each stateful force contribution, in the order of the contributions (the
      tissue: contact, puncture, track, shaft anchors, LuGre bristle state, the next step's frozen forces).

    Every value but the integrator's memory is replaced, never changed in place (states, base motions, force
    states), so :meth:`copy` copies references and the memory's few small arrays, and :meth:`restore` puts them
    back: both cost microseconds whatever the tissue holds.
    """

    integrator: IntegratorMemory
    grid_origin: float = 0.0
    step_index: int = 0
    pose_phase: complex = 0j
    point_loads: dict[str, PointLoad] = field(default_factory=dict)
    force_states: tuple = ()
    _state: State | None = None
    _run_end: tuple | None = None  # (states, index, t, motions, rotations) of end_run, until read

    @property
    def state(self) -> State | None:
        end = self._run_end
        if end is not None:
            states, i, t, motions, rotations = end
            rows = states[i]
            self._state = State(rows[0], rows[1], rows[2], t, rows[3], BaseMotion.from_packed(motions[i], rotations[i]))
            self._run_end = None
        return self._state

    @state.setter
    def state(self, state: State | None) -> None:
        self._state, self._run_end = state, None

    def end_run(self, states: np.ndarray, index: int, t: float, motions: np.ndarray, rotations: np.ndarray) -> None:
        """The state a compiled run ended at: step ``index`` of its rows [q, q', q'', a] (k, 4, n_dof) at time t
        and of its packed base motions (k, 19) and rotations (:meth:`BaseMotion.from_packed`), never changed after."""
        self._state, self._run_end = None, (states, index, t, motions, rotations)

    @property
    def started(self) -> bool:
        return self._run_end is not None or self._state is not None

    @property
    def time(self) -> float:
        """The state's time t (started)."""
        end = self._run_end
        return end[2] if end is not None else self._state.t

    @property
    def with_history(self) -> bool:
        """Whether the (started) state has the integrator's history a (aux), as a compiled run needs."""
        return self._run_end is not None or self._state.aux is not None

    def start_rows(self) -> tuple[np.ndarray, int]:
        """(rows [q, q', q'', a] (k, 4, n_dof), the state's index) (started, :attr:`with_history`): a run's start."""
        end = self._run_end
        if end is not None:
            return end[0], end[1]
        state = self._state
        return np.stack((state.q, state.qd, state.qdd, state.aux))[None], 0

    @property
    def base(self) -> BaseMotion | None:
        """The base motion at the state's time (None before the start)."""
        return None if self.state is None else self.state.base

    def copy(self) -> NeedleData:
        return replace(self, point_loads=dict(self.point_loads), integrator=self.integrator.copy())

    def restore(self, saved: NeedleData) -> None:
        """Put back the values of ``saved`` (a :meth:`copy`)."""
        self._state, self._run_end, self.grid_origin, self.step_index, self.pose_phase = (
            saved._state, saved._run_end, saved.grid_origin, saved.step_index, saved.pose_phase)
        self.integrator, self.point_loads, self.force_states = (saved.integrator.copy(), dict(saved.point_loads),
                                                                saved.force_states)


def initial_force_states(model: NeedleModel, forces) -> tuple:
    """The initial state of each stateful contribution in ``forces`` (checked against the force protocol)."""
    return tuple(force.initial_state(model) for force in check_forces(forces) if force.stateful)


def stateful_forces(forces, force_states: tuple):
    """(contribution, its state) for each stateful contribution in ``forces`` (``NeedleData.force_states`` order)."""
    return zip([force for force in forces if force.stateful], force_states, strict=True)


def acting_forces(forces, data: NeedleData) -> list:
    """The contributions acting over the step that starts from ``data``: those of ``forces`` without state, the
    point loads, then each stateful one's contributions ``at`` its state in ``data``."""
    acting = [force for force in forces if not force.stateful]
    stateful = len(acting) < len(forces) or data.force_states
    acting += data.point_loads.values()
    for force, own in stateful_forces(forces, data.force_states) if stateful else ():
        acting += force.at(own)
    return acting


def step(model: NeedleModel, integrator: Integrator, forces, data: NeedleData, dt: float, t_next: float,
         base_next: BaseMotion) -> StepResult:
    """One step of ``data`` (started) of length ``dt`` to ``t_next`` (on the time loop's grid: t + dt up to
    rounding), the base motion then ``base_next``, under the contributions ``forces``, in fixed phases:

    1. inputs: the contributions acting over the step (:func:`acting_forces`), the integrator's memory;
    2. integrate: predictor, Newton, sub-stepping (:meth:`Integrator.step`; StepFailed if it cannot);
    3. accept: each stateful contribution advances its state to the new needle state;
    4. commit: ``data`` takes the new state (with its base) and force states (the step index is the time loop's);
       any error before this leaves ``data`` as it was (the integrator's memory, updated in place, is put back);
    5. outputs: the base wrench of the new state under the contributions of the next step (the compiled run's
       where it took the step without state-dependent contributions), in the returned :class:`StepResult`.
    """
    control = data.integrator.control.copy()
    acting = acting_forces(forces, data)
    try:
        result = integrator.step(data.state, dt, base_next, acting, data.integrator)
        state = result.state
        state.t = t_next
        stateful = tuple(force.advance(model, state, base_next, own)
                         for force, own in stateful_forces(forces, data.force_states)) if data.force_states else ()
    except BaseException:
        data.integrator.control[:] = control
        raise
    data.state = state
    if stateful:
        data.force_states = stateful
        acting = acting_forces(forces, data)
    if result.wrench is None or stateful:
        result = result._replace(wrench=reaction_wrench(model, state, base_next, acting))
    return result
