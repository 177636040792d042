"""The live loop's advance in one compiled call: base motions from the pose trajectory, then the step sequence.

Where the compiled step sequence applies (:meth:`Integrator.supports_sequence`) and the base follows the received
poses, the simulator's :meth:`~needle_sim_ros.simulation.NeedleSimulation.advance_to` takes its steps with a single
numba call instead of one per stage: the trajectory's fit (refitted once per new sample) evaluated at the step
end times, the fresh twist feed-forward, the flange-to-clamp offset, and the steps themselves
(:func:`~needle_sim_ros.model.step.integrate_sequence`). Each stage is the same compiled function the staged
path calls, so both give the same bits.

The arguments that hold from one call to the next travel in one :class:`AdvancePlan` record, made once per plan,
typed in C by its ``_numba_type_`` (numba 0.59 too: ``test_kernel_dispatch``): 8 arguments, not 51, to unbox per
call; the stepper calls it for their types directly (:func:`~needle_sim_ros.model.records.compiled_entry`: the
dispatcher types a record at ~0.6 us).
"""
from __future__ import annotations

import numpy as np
from numba import njit
from numba.core import types
from numba.experimental import structref

from needle_sim_ros.base_trajectory import trajectory_motions
from needle_sim_ros.model.kinematics import compose_offsets
from needle_sim_ros.model.step import integrate_sequence

# The sequence's arguments after the start rows, motions and rotations (Integrator.sequence_arguments after its
# history, the memory's last motion), the trajectory's buffers (BaseTrajectory.buffers), the packed offset and twist.
PLAN_FIELDS = ("coef", "ext_Q", "tol", "max_iterations", "prescribed", "base_nodes", "base_local_r",
               "base_local_rx", "active", "scale", "tables", "residual", "band", "pivots", "factorization", "kl",
               "control", "last_motion", "sample_times", "positions", "orientations", "deltas", "starts", "blends",
               "fit", "counts", "served", "served_motion", "scratch", "window", "max_extrapolation", "packed")


@structref.register
class AdvancePlanType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(field)) for name, field in fields)


class AdvancePlan(structref.StructRefProxy):
    """The arguments of :func:`advance_from_trajectory` that hold while the integrator, forces, memory and base
    input do (:data:`PLAN_FIELDS`), in one typed record (:func:`advance_plan` makes it)."""


structref.define_proxy(AdvancePlan, AdvancePlanType, PLAN_FIELDS)


@njit(cache=True)
def advance_plan(*fields):
    """The :class:`AdvancePlan` of the fields (compiled and cached: the proxy's own constructor compiles anew in
    every process)."""
    return AdvancePlan(*fields)


@njit(cache=True)
def apply_twist(flange: np.ndarray, times: np.ndarray, twist: np.ndarray, twist_timeout: float) -> None:
    """Replace the fitted velocities of the packed flange motions (k, 19) at times within ``twist_timeout`` of the
    twist's time by the twist [t, v, w] (world frame); NaN t: no twist."""
    for i in range(times.size):
        if abs(times[i] - twist[0]) <= twist_timeout:
            flange[i, 7:10] = twist[1:4]
            flange[i, 10:13] = twist[4:7]


@njit(cache=True)
def advance_from_trajectory(plan, times, motions, rotations, start, index, states, wrenches, iterations):
    """Steps at the end times ``times`` from the trajectory's fit, returning how many were done (the plan's buffers:
    :func:`trajectory_motions`' arguments, :attr:`BaseTrajectory.buffers`, with the fit and its state): the flange
    motions into ``motions`` (k, 19), there in place the twist within its timeout and the flange-to-clamp offset (the
    plan's ``packed``: :attr:`BaseInput.packed`) with the rotations into ``rotations`` (k, 3, 3), then the steps from
    the start state ``start[index]`` ((m, 4, n_dof) [q, q', q'', a]) by :func:`integrate_sequence` with the
    factorization kept across steps, into the outputs (states, wrenches, iterations: ``integrators.run_outputs``).
    Every argument is an array, a number or the :class:`AdvancePlan` (numba 0.59 types a tuple in Python per call)."""
    p = plan
    trajectory_motions(p.sample_times, p.positions, p.orientations, p.deltas, p.starts, p.blends, p.fit, p.counts,
                       p.served, p.served_motion, p.scratch, p.window, p.max_extrapolation, times, motions)
    packed = p.packed
    apply_twist(motions, times, packed[1:8], packed[0])
    compose_offsets(motions, packed[8:11], packed[11:20].reshape((3, 3)), motions, rotations)
    return integrate_sequence(start[index], times, motions, rotations, p.coef, p.ext_Q, p.tol, p.max_iterations,
                              p.prescribed, p.base_nodes, p.base_local_r, p.base_local_rx, p.active, p.scale,
                              p.tables, p.residual, p.band, p.pivots, p.factorization, p.kl, p.control, True,
                              p.last_motion, states, wrenches, iterations)
