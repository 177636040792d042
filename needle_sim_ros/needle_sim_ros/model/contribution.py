"""A state-dependent force law written once, as compiled kernels, for every path.

A :class:`CompiledContribution` subclass names its ``assemble`` kernel (and, if it acts on the base element,
``touches_base``; see :mod:`needle_sim_ros.model.step`) on a float64 array of its parameters (``state``). The
general path (``Integrator.step``: sub-stepping, statics) calls the kernel through ``assemble_banded``; the
simulator's compiled run composes it into :func:`~needle_sim_ros.model.step.run_steps` (``run_steps`` below),
so the law runs at compiled speed with no change to the engine. ``docs/extending.md`` walks through an example.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np

from .forces import ElementLocalForce
from .integrators import SequenceResult, run_outputs
from .step import compiled_run, off_base


class CompiledContribution(ElementLocalForce):
    """Base of a stateless, state-dependent contribution given by compiled kernels on ``state`` (float64 array)."""

    state_dependent: ClassVar[bool] = True
    time_invariant: ClassVar[bool] = False
    stateful: ClassVar[bool] = False
    compiled_run: ClassVar[bool] = True
    assemble: ClassVar  # numba kernel (state, q, qd, rotation, Q, band, kl, c_q, c_qd) -> bool
    touches_base: ClassVar = off_base
    _run: ClassVar = None

    def __init__(self, state: np.ndarray) -> None:
        self.state = np.ascontiguousarray(state, dtype=float)

    def assemble_banded(self, model, q, qd, t, base, band, kl, c_q, c_qd) -> np.ndarray:
        Q = np.zeros(model.n_dof)
        if not type(self).assemble(self.state, q, qd, base.rotation, Q, band, kl, c_q, c_qd):
            raise FloatingPointError(f"{type(self).__name__}: the force cannot be assembled at this state")
        return Q

    def touches_element(self, model, element: int) -> bool:
        return element != 0 or bool(type(self).touches_base(self.state))

    def run_steps(self, model, integrator, state, own, dt: float, times: np.ndarray, motions: np.ndarray,
                  rotations: np.ndarray, forces, memory) -> tuple[SequenceResult, None]:
        """Steps of dt from ``state`` (with ``aux``) to the end times in one compiled call, under ``forces``
        (time-invariant) and this law (the ``compiled_run`` protocol of :class:`ForceContribution`)."""
        cls = type(self)
        if cls.__dict__.get("_run") is None:  # composed once per law
            cls._run = compiled_run(cls.assemble, touches_base=cls.touches_base)
        k, n = times.size, model.n_dof
        needle, constant_Q = integrator.run_arguments(forces, dt, float(times[0]), memory)
        history = np.empty((4, n))
        history[0], history[1], history[2], history[3] = state.q, state.qd, state.qdd, state.aux
        outputs = run_outputs(k, n)
        done, _ = cls._run(history, times, motions, rotations, needle[0], constant_Q, *needle[1:], memory.control,
                           self.state, *outputs)
        return SequenceResult.of_run(done, outputs), own
