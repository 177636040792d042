"""The live loop's advance in one compiled call: base motions from the pose trajectory, then the step sequence.

Where the compiled step sequence applies (:meth:`Integrator.supports_sequence`) and the base follows the received
poses, the simulator's :meth:`~needle_sim_ros.simulation.NeedleSimulation.advance_to` takes its steps with a single
numba call instead of one per stage: the trajectory's fit (refitted once per new sample) evaluated at the step
end times, the fresh twist feed-forward, the flange-to-clamp offset, and the steps themselves
(:func:`~needle_sim_ros.model.step.integrate_sequence`). Each stage is the same compiled function the staged
path calls, so both give the same bits.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.base_trajectory import trajectory_motions
from needle_sim_ros.model.kinematics import compose_offsets
from needle_sim_ros.model.step import integrate_sequence

@njit(cache=True)
def apply_twist(flange: np.ndarray, times: np.ndarray, twist: np.ndarray, twist_timeout: float) -> None:
    """Replace the fitted velocities of the packed flange motions (k, 19) at times within ``twist_timeout`` of the
    twist's time by the twist [t, v, w] (world frame); NaN t: no twist."""
    for i in range(times.size):
        if abs(times[i] - twist[0]) <= twist_timeout:
            flange[i, 7:10] = twist[1:4]
            flange[i, 10:13] = twist[4:7]


@njit(cache=True)
def advance_from_trajectory(sample_times, positions, orientations, count, t_newest, p_newest, q_newest, window,
                            max_extrapolation, fit, refit, continued, served, t_previous, p_previous, q_previous,
                            previous_fit, deltas, starts, blends, corrections, times, packed, motions, rotations, q, qd,
                            qdd, aux, history, coef, ext_Q, tol, max_iterations, prescribed, base_nodes, base_local_r,
                            base_local_rx, active, scale, tables, residual, band, pivots, factorization, kl, control,
                            last_motion, states, wrenches, iterations):
    """Steps at the end times ``times`` from the trajectory's fit (sample_times ... corrections:
    :meth:`BaseTrajectory.fit_arguments`, the arguments of :func:`trajectory_motions`): the flange motions, the
    twist within its timeout and the flange-to-clamp offset (``packed``: :attr:`BaseInput.packed`), the clamp
    motions and rotations into ``motions`` (k, 19) and ``rotations`` (k, 3, 3), then the steps from the start state
    (q, qd, qdd, aux) by :func:`integrate_sequence` with the factorization kept across steps (history ...
    iterations: its arguments after the motions and rotations, :meth:`Integrator.sequence_arguments`). Every
    argument is an array or a number: numba types each in C (0.59 types a tuple in Python on every call); the
    fewer, the cheaper the call (each array is unboxed on every call). Returns (fit, number of corrections, steps
    done)."""
    flange = np.empty((times.size, 19))
    fit, corrections = trajectory_motions(sample_times, positions, orientations, count, t_newest, p_newest, q_newest,
                                          window, max_extrapolation, fit, refit, continued, served, t_previous,
                                          p_previous, q_previous, previous_fit, deltas, starts, blends, corrections,
                                          times, flange)
    apply_twist(flange, times, packed[1:8], packed[0])
    compose_offsets(flange, packed[8:11], packed[11:20].reshape((3, 3)), motions, rotations)
    history[0], history[1], history[2], history[3] = q, qd, qdd, aux
    done = integrate_sequence(history, times, motions, rotations, coef, ext_Q, tol, max_iterations, prescribed,
                              base_nodes, base_local_r, base_local_rx, active, scale, tables, residual, band, pivots,
                              factorization, kl, control, True, last_motion, states, wrenches, iterations)
    return fit, corrections, done

