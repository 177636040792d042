"""A run of time steps in one compiled call without state-dependent contributions (gravity, world-frame point
loads): the fast path of the simulator's fixed-rate loop, :func:`~needle_sim_ros.model.step.run_steps` with no
contribution, and the buffers the compiled runs use.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .banded import ELEMENT_BANDWIDTH, band_width_columns
from .newton import model_tables, no_forces
from .step import EXTRAPOLATE, FACTORED, itself, keep, off_base, run_steps

class SequenceBuffers:
    """Work arrays of the compiled step sequence of one model (the factorization kept across steps is in the
    ``IntegratorMemory`` of the needle's data)."""

    def __init__(self, model) -> None:
        n = model.n_dof
        self.tables = model_tables(model)
        self.active = model.partition.active
        self.scale = model.increment_scale
        self.history = np.empty((4, n))  # rows q, q', q'', a of the start state
        self.residual = np.empty(n)
        groups = model.partition.groups
        self.supported = all(g.fixed is not None or g.frame in ("base", "start") for g in groups)
        moving = [g for g in groups if g.frame == "base"]
        self.base_nodes = np.concatenate([g.nodes for g in moving]).astype(np.int64)
        self.base_local_r = np.ascontiguousarray(np.concatenate([g.local_r for g in moving]))
        self.base_local_rx = np.ascontiguousarray(np.concatenate([g.local_rx for g in moving]))
        self.prescribed = np.zeros((3, n))  # world-fixed coordinates once; the base nodes are written per step
        for group in groups:
            if group.fixed is not None:
                self.prescribed[:, group.dofs] = group.fixed
        self.held, self.clamp = model.partition.held, None  # the groups held where the needle started, their pose

    def hold(self, clamp) -> None:
        """Write the rows of the groups held where the needle started at ``clamp`` (``IntegratorMemory.clamp``)."""
        if clamp is self.clamp or not self.held:
            return
        if clamp is None:
            raise ValueError("a fixture of the frame 'start' needs the pose the needle started at (memory.clamp)")
        for group in self.held:
            clamp.impose_nodes(group.local_r, group.local_rx, group.nodes, self.prescribed)
        self.clamp = clamp


class IntegratorMemory:
    """What the integrator carries from one step to the next (part of the needle's data, changed in place by the
    integrator): ``control`` [extrapolate, factored]: whether Newton starts from the extrapolating predictor and
    whether the kept factorization is valid; the kept factorization of the compiled sequence (``band``, ``pivots``,
    ``factorization``), the step length ``h`` and the packed base motion ``last_motion`` it was made for; ``clamp``:
    the pose of the fixtures of the frame "start", where the needle was (re)started (None: none yet)."""

    def __init__(self, n_dof: int) -> None:
        self.control = np.array([1, 0], dtype=np.int64)
        self.band = np.zeros((n_dof, band_width_columns(ELEMENT_BANDWIDTH)))
        self.pivots = np.zeros(n_dof, dtype=np.int64)
        self.factorization = np.zeros(1, dtype=np.int64)
        self.last_motion = np.full(19, np.nan)
        self.h = 0.0
        self.clamp = None

    @property
    def extrapolate(self) -> bool:
        return bool(self.control[EXTRAPOLATE])

    def invalidate(self) -> None:
        """The kept factorization no longer belongs to the current motion (e.g. after a general step)."""
        self.control[FACTORED] = 0

    def copy(self) -> IntegratorMemory:
        memory = IntegratorMemory.__new__(IntegratorMemory)
        memory.__dict__.update({name: value.copy() if isinstance(value, np.ndarray) else value
                                for name, value in self.__dict__.items()})
        return memory


@njit(cache=True)
def integrate_sequence(history, times, motions, rotations, coef, ext_Q, tol, max_iterations, prescribed, base_nodes,
                       base_local_r, base_local_rx, active, scale, tables, residual, band, pivots, factorization, kl,
                       control, last_motion, states, wrenches, iterations):
    """:func:`~needle_sim_ros.model.step.run_steps` without state-dependent contributions (the matrix kept across
    steps where it may be); returns the number of steps done."""
    done, _ = run_steps(history, times, motions, rotations, ext_Q,
                        (coef, tol, max_iterations, active, scale, tables, kl),
                        (prescribed, base_nodes, base_local_r, base_local_rx),
                        (residual, band, np.zeros((0, 0)), pivots, factorization), control, last_motion, True, 0.0,
                        itself, no_forces, keep, off_base, (states, wrenches, iterations))
    return done
