"""The live loop's advance in one compiled call: base motions from the pose trajectory, then the step sequence.

Where the compiled step sequence applies (:meth:`Integrator.supports_sequence`) and the base follows the received
poses, the simulator's :meth:`~needle_sim_ros.simulation.NeedleSimulation.advance_to` takes its steps with a single
numba call instead of one per stage: the trajectory's fit (refitted once per new sample) evaluated at the step
end times, the fresh twist feed-forward, the flange-to-clamp offset, and the steps themselves
(:func:`~needle_sim_ros.model.sequence.integrate_sequence`). Each stage is the same compiled function the staged
path calls, so both give the same bits.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.base_trajectory import trajectory_motions
from needle_sim_ros.model.kinematics import compose_offsets
from needle_sim_ros.model.sequence import integrate_sequence

NO_TWIST = np.full(7, np.nan)  # twist argument without a twist: [t, linear velocity, angular velocity]


@njit(cache=True)
def apply_twist(flange: np.ndarray, times: np.ndarray, twist: np.ndarray, twist_timeout: float) -> None:
    """Replace the fitted velocities of the packed flange motions (k, 19) at times within ``twist_timeout`` of the
    twist's time by the twist [t, v, w] (world frame); NaN t: no twist."""
    for i in range(times.size):
        if abs(times[i] - twist[0]) <= twist_timeout:
            flange[i, 7:10] = twist[1:4]
            flange[i, 10:13] = twist[4:7]


@njit(cache=True)
def advance_from_trajectory(*arguments):
    """Steps at the given end times from the trajectory's 21 arguments (:meth:`BaseTrajectory.fit_arguments`),
    followed by the times, the flange motions buffer (k, 19), the twist and its timeout, the offset position and
    rotation, the clamp motions (k, 19) and rotations (k, 3, 3) buffers, the start state's q, q', q'' and a, and
    the arguments of :func:`integrate_sequence` after its motions and rotations, from its history buffer on
    (:meth:`Integrator.sequence_arguments`). Returns (fit, number of corrections, steps done)."""
    times, flange, twist, twist_timeout, offset, offset_rotation, motions, rotations = arguments[21:29]
    fit, corrections = trajectory_motions(*arguments[:21], times, flange)
    apply_twist(flange, times, twist, twist_timeout)
    compose_offsets(flange, offset, offset_rotation, motions, rotations)
    history = arguments[33]
    history[0], history[1], history[2], history[3] = arguments[29:33]
    done = integrate_sequence(history, times, motions, rotations, *arguments[34:])
    return fit, corrections, done
