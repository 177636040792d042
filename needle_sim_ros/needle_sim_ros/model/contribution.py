"""Force laws written once, as compiled kernels, for every path, and the compiled run that composes them.

A ``compiled_run`` contribution declares its :class:`~needle_sim_ros.model.step.Kernels` (``kernels``, or its
parts', :func:`~needle_sim_ros.model.step.parts_of`), its constants in one float64 array (``constants``) and, if
stateful, its packed state (``packed_state``, ``unpacked_state``). :class:`ContributionRun` composes any number of
them into one compiled run of steps (:func:`~needle_sim_ros.model.step.compiled_run`). A
:class:`CompiledContribution` subclass (a law without state) names its ``assemble`` kernel (and ``touches_base``)
on a float64 parameter array; the general path calls the same kernel through ``assemble_banded``. Example:
``docs/extending.md``.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np

from .forces import ElementLocalForce
from .integrators import SequenceResult, run_outputs
from .step import Kernels, compiled_run, constants_only, itself, keep, nothing, off_base, pack, unpack

NO_STATE = np.zeros(0)


class CompiledContribution(ElementLocalForce):
    """Base of a stateless, state-dependent contribution given by compiled kernels on ``state`` (float64 array)."""

    state_dependent: ClassVar[bool] = True
    time_invariant: ClassVar[bool] = False
    stateful: ClassVar[bool] = False
    compiled_run: ClassVar[bool] = True
    assemble: ClassVar  # numba kernel (state, q, qd, rotation, Q, band, kl, c_q, c_qd) -> bool
    touches_base: ClassVar = off_base
    kernels: ClassVar[Kernels]

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        cls.kernels = Kernels(constants_only, nothing, itself, cls.assemble, keep, cls.touches_base)

    def __init__(self, state: np.ndarray) -> None:
        self.state = np.ascontiguousarray(state, dtype=float)

    @property
    def constants(self) -> np.ndarray:
        return self.state

    def assemble_banded(self, model, q, qd, t, base, band, kl, c_q, c_qd) -> np.ndarray:
        Q = np.zeros(model.n_dof)
        if not type(self).assemble(self.state, q, qd, base.rotation, Q, band, kl, c_q, c_qd):
            raise FloatingPointError(f"{type(self).__name__}: the force cannot be assembled at this state")
        return Q

    def touches_element(self, model, element: int) -> bool:
        return element != 0 or bool(type(self).touches_base(self.state))


class ComposedForces(ElementLocalForce):
    """The forces of a composition (:func:`~needle_sim_ros.model.step.compose`) over one step at its packed state
    and constants: the general path runs the same kernels as the compiled run."""

    state_dependent: ClassVar[bool] = True
    time_invariant: ClassVar[bool] = False
    stateful: ClassVar[bool] = False

    def __init__(self, composition, state: np.ndarray, constants: np.ndarray) -> None:
        self.composition, self.state, self.constants = composition, state, constants

    def assemble_banded(self, model, q, qd, t, base, band, kl, c_q, c_qd) -> np.ndarray:
        Q = np.zeros(model.n_dof)
        if not self.composition.packed_assemble(self.state, self.constants, q, qd, base.rotation, Q, band, kl, c_q,
                                                c_qd):
            raise FloatingPointError("the composed forces cannot be assembled at this state")
        return Q

    def touches_element(self, model, element: int) -> bool:
        return element != 0 or model.n_elements == 1 or bool(
            self.composition.packed_touches_base(self.state, self.constants))

    def parts(self, q: np.ndarray, qd: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """Each composed contribution's generalized force alone at (q, q') (count, n_dof)."""
        return self.composition.packed_parts(self.state, self.constants, q, qd, rotation)


class ContributionRun:
    """The compiled run of steps through the given ``compiled_run`` contributions, composed once."""

    def __init__(self, contributions) -> None:
        self.contributions = tuple(contributions)
        self.run = compiled_run(tuple(force.kernels for force in self.contributions))
        self.constants = pack([force.constants for force in self.contributions])

    def __call__(self, model, integrator, state, owns: list, dt: float, times: np.ndarray, motions: np.ndarray,
                 rotations: np.ndarray, forces, memory) -> tuple[SequenceResult, list]:
        """Steps of dt from ``state`` (with ``aux``) to the end times (k,), the base at each given packed (k, 19) with
        rotations (k, 3, 3), under ``forces`` (time-invariant) and the contributions (``owns``: their states, None if
        stateless), in one compiled call, ending early at a step that does not converge (for the general step).
        Returns the steps done and the contributions' states."""
        k, n = times.size, model.n_dof
        needle, constant_Q = integrator.run_arguments(forces, dt, float(times[0]), memory)
        history = np.stack((state.q, state.qd, state.qdd, state.aux))
        outputs = run_outputs(k, n)
        packed = pack([NO_STATE if own is None else force.packed_state(own)
                       for force, own in zip(self.contributions, owns)])
        done, after = self.run(history, times, motions, rotations, needle[0], constant_Q, *needle[1:],
                               memory.control, packed, self.constants, *outputs)
        result = SequenceResult.of_run(done, outputs)
        if done == 0:
            return result, owns
        return result, [own if own is None else force.unpacked_state(array)
                        for force, own, array in zip(self.contributions, owns, unpack(after, len(owns)))]
