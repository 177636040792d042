"""Cost of the compiled step's stages in isolation (issue 38): the needle released from a 10 g tip load under
gravity (10 elements, dt = 1 ms, the simulator's defaults), a run of steps on a fresh matrix every step
(``Integrator.step_sequence``, keep_matrix off), and each stage's kernel timed in a compiled loop at a state of that
run. CPU time of this process, best of 7; prints a Markdown table.

Usage (the installed package: source .venv/needle_env.sh first):
    python bench/bench_step_stages.py
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from needle_sim_ros.model import BaseMotion, Gravity, PointLoad, solve_static
from needle_sim_ros.model.banded import ELEMENT_BANDWIDTH, band_cholesky, band_width_columns, cholesky_solve
from needle_sim_ros.model.elastic import add_elastic
from needle_sim_ros.model.newton import assemble_system, model_tables, rate_coefficients, unpack_tables
from needle_sim_ros.model.reaction import base_wrench_kernel
from needle_sim_ros.model.step import base_tables
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import model_builder_from_parameters

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
DT, STEPS, REPEATS, CALLS, G = 1e-3, 3000, 7, 20000, 9.81
KL = ELEMENT_BANDWIDTH


@njit
def assemble_loop(count, q, qd, qdd, tables, axis, ext_Q, c_M, c_C, active, residual, band, with_matrix, lower):
    for _ in range(count):
        assemble_system(q, qd, qdd, tables, axis, ext_Q, np.zeros((0, 0)), 1.0, c_M, c_C, active, residual, band,
                        ELEMENT_BANDWIDTH, with_matrix, lower)


@njit
def elastic_loop(count, q, qd, tables, residual, band, with_matrix):
    (axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, _, _, _,
     strain_rate_weights) = unpack_tables(tables)
    for _ in range(count):
        add_elastic(q, axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, residual, band,
                    ELEMENT_BANDWIDTH, 1.0, with_matrix, strain_rate_weights, 1.0, qd)


@njit
def cholesky_loop(count, source, band):
    for _ in range(count):
        band[:, :] = source
        band_cholesky(band, ELEMENT_BANDWIDTH)


@njit
def copy_loop(count, source, band):
    for _ in range(count):
        band[:, :] = source


@njit
def solve_loop(count, factor, rhs, work):
    for _ in range(count):
        work[:] = rhs
        cholesky_solve(factor, ELEMENT_BANDWIDTH, work)


@njit
def wrench_loop(count, q, qd, qdd, rows, rotation, external):
    for _ in range(count):
        base_wrench_kernel(q, qd, qdd, *rows, rotation, external)


def per_call(loop, *arguments) -> float:
    """Best CPU time [us] per call of CALLS calls."""
    loop(1, *arguments)
    best = np.inf
    for _ in range(REPEATS):
        start = time.process_time()
        loop(CALLS, *arguments)
        best = min(best, time.process_time() - start)
    return best / CALLS * 1e6


def main() -> None:
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    base = BaseMotion(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    forces = [Gravity()]
    loaded = solve_static(model, base, [*forces, PointLoad(model.props.length, (0.0, 0.0, -0.010 * G))]).state
    state = integrator.step(loaded, DT, base, forces).state  # released: the first step gives the accelerations
    motions = np.tile(np.concatenate([base.position, base.orientation, np.zeros(12)]), (STEPS, 1))
    rotations = np.tile(base.rotation, (STEPS, 1, 1))
    best, run = np.inf, None
    for _ in range(REPEATS):
        memory = integrator.memory.copy()
        start = time.process_time()
        run = integrator.step_sequence(state, DT, motions, rotations, forces, memory, keep_matrix=False)
        best = min(best, time.process_time() - start)
    if run.done != STEPS:
        raise RuntimeError(f"the run stopped after {run.done} of {STEPS} steps")
    print(f"10 g tip load released, 10 elements, dt = {DT * 1e3:g} ms: {run.iterations.mean():.3f} Newton "
          f"corrections per step; CPU time, best of {REPEATS}\n")
    rows = [("a step of the compiled run (fresh matrix every step), reaction wrench included", best / STEPS * 1e6)]
    q, qd, qdd = (np.ascontiguousarray(row) for row in run.states[200, :3])
    tables, n = model_tables(model), model.n_dof
    c_M, c_C = rate_coefficients(np.concatenate([[DT], integrator.coefficients]), True)
    axis, ext_Q, active = np.array([1.0, 0.0, 0.0]), np.zeros(n), model.partition.active
    residual, band = np.zeros(n), np.zeros((n, band_width_columns(KL)))
    for name, with_matrix, lower in (("assemble: residual and full band matrix", True, False),
                                     ("assemble: residual and lower band (a Cholesky's)", True, True),
                                     ("assemble: residual only (a chord correction)", False, False)):
        rows.append((name, per_call(assemble_loop, q, qd, qdd, tables, axis, ext_Q, c_M, c_C, active, residual,
                                    band, with_matrix, lower)))
    rows.append(("of which the elastic and axial damping forces and matrix", per_call(elastic_loop, q, qd, tables,
                                                                                     residual, band, True)))
    rows.append(("of which the elastic and axial damping forces", per_call(elastic_loop, q, qd, tables, residual,
                                                                          band, False)))
    assemble_system(q, qd, qdd, tables, axis, ext_Q, np.zeros((0, 0)), 1.0, c_M, c_C, active, residual, band, KL,
                    True)
    source, rhs = band.copy(), residual.copy()
    copy = per_call(copy_loop, source, band)
    rows.append(("banded Cholesky", per_call(cholesky_loop, source, band) - copy))
    factor = source.copy()
    band_cholesky(factor, KL)
    rows.append(("Cholesky solve", per_call(solve_loop, factor, rhs, residual)))
    rows.append(("reaction wrench", per_call(wrench_loop, q, qd, qdd, base_tables(tables), np.eye(3), np.zeros(6))))
    print("| stage | us |\n|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.2f} |")


if __name__ == "__main__":
    main()
