"""Cost of the compiled step's stages in isolation (issue 38): the needle released from a 10 g tip load under
gravity (10 elements, dt = 1 ms, the simulator's defaults), a run of steps on a fresh matrix every step
(``Integrator.step_sequence``, keep_matrix off), and each stage's kernel timed in a compiled loop at a state of that
run. Then the tissue's kernels (issue 38) the same way, at a state of the insertion scenario (``bench_tissue.py``'s
shipped Karnopp + lateral + bevel tissue, 50 mm inserted): the contributions' assembly (every Newton correction)
and their advance (once per step). CPU time of this process, best of 7; prints Markdown tables.

Usage (the installed package: source .venv/needle_env.sh first):
    python bench/bench_step_stages.py
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from needle_sim_ros.model import BaseMotion, Gravity, PointLoad, State, solve_static
from needle_sim_ros.model.banded import ELEMENT_BANDWIDTH, band_cholesky, band_width_columns, cholesky_solve
from needle_sim_ros.model.elastic import add_elastic
from needle_sim_ros.model.newton import assemble_system, element_work, model_tables, rate_coefficients, unpack_tables
from needle_sim_ros.model.reaction import base_wrench_kernel
from needle_sim_ros.model.step import base_tables
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.scenarios.insertion import InsertionMotion, shipped_tissue_config
from needle_sim_ros.simulation import NeedleSimulation, model_builder_from_parameters
from needle_sim_ros.tissue.coupling import ANCHOR, shaft_contact_points
from needle_sim_ros.tissue.factory import TissueConfig, build_tissue_model, flatten_tissue_config
from needle_sim_ros.tissue.shaft_force import lateral_part, shaft_acting, shaft_assemble
from needle_sim_ros.tissue.tip_forces import bevel_assemble
from needle_sim_ros.tissue.track import project_on_blocks

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
                    ELEMENT_BANDWIDTH, 1.0, with_matrix, element_work(tables), strain_rate_weights, 1.0, qd)


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
def wrench_loop(count, q, qd, qdd, rows, rotation, external, work, wrench):
    for _ in range(count):
        base_wrench_kernel(q, qd, qdd, *rows, rotation, external, work, wrench)


@njit
def tissue_assemble_loop(count, assemble, forces, q, qd, rotation, Q, band, kl, c_q, c_qd):
    for _ in range(count):
        assemble(forces, q, qd, rotation, Q, band, kl, c_q, c_qd)


@njit
def tissue_advance_loop(count, advance, carried, q, qd, t):
    for _ in range(count):
        advance(carried, q, qd, t)


@njit
def lateral_loop(count, contact, constants, q):
    c, k = contact, constants
    for _ in range(count):
        lateral_part(q, k[14], k[15], k[0][-1], k[16], k[17], c.vertices, c.arc, c.end_tangent, c.centres, c.radii,
                     k[10], k[11], k[12], k[13])


@njit
def contact_points_loop(count, contact, record, constants, q):
    c, k = contact, constants
    for _ in range(count):
        shaft_contact_points(q, k[0], k[0][-1] - c.tip_depth - k[2], k[3], k[4], k[5], k[10], k[11], k[12][-1],
                             record.active, np.zeros(k[0].size, dtype=np.bool_), record.anchor.copy(), c.vertices,
                             c.arc, c.end_tangent, c.centres, c.radii)


@njit
def projection_loop(count, contact, points):
    for _ in range(count):
        project_on_blocks(contact.vertices, contact.arc, contact.end_tangent, points, contact.centres, contact.radii)


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
    rows.append(("reaction wrench", per_call(wrench_loop, q, qd, qdd, base_tables(tables), np.eye(3), np.zeros(6),
                                                     element_work(tables), np.empty(12))))
    print("| stage | us |\n|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.2f} |")
    tissue_stages()


def tissue_stages() -> None:
    """The tissue kernels' costs at 50 mm inserted in the insertion scenario (module docstring)."""
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    config = dict(TissueConfig.from_any(flatten_tissue_config(shipped_tissue_config())).values)
    motion = InsertionMotion((0.09,), 0.006)
    config["tissue.entry_point"], config["tissue.enable"] = [model.props.length + motion.gap, 0.0, 0.0], True
    base = motion.base_at(0.0)
    state = State(solve_static(model, base, [Gravity()]).state.q, model.straight_state(base, 0.0).qd,
                  np.zeros(model.n_dof), 0.0)
    tissue = build_tissue_model(config, model)
    simulation = NeedleSimulation.prescribed(model, integrator, DT, motion.base_at, state, [tissue],
                                             motion.motions_at)
    simulation.advance_to(motion.gap / motion.speed + 0.05 / motion.speed)
    composition, q, qd = tissue.composition, simulation.state.q, simulation.state.qd
    carried = composition.load(simulation.data.force_states[0].record, tissue.constants)
    contact, shaft = carried[0].record, carried[1].record
    forces, rotation, n = composition.acting(carried), simulation.base.rotation, model.n_dof
    Q, band, no_band = np.zeros(n), np.zeros((n, band_width_columns(KL))), np.zeros((0, 0))
    print(f"\nTissue (shipped Karnopp + lateral + bevel, insertion scenario at 50 mm inserted): {contact.arc.size} "
          f"track vertices, {shaft.lateral_count} lateral and {shaft.slots.shape[0] - shaft.lateral_count} axial "
          "shaft points\n")
    shaft_forces = shaft_acting(carried[1])
    lateral_anchors = np.ascontiguousarray(shaft.points[:shaft.lateral_count, ANCHOR:ANCHOR + 3])
    rows = [("tissue assemble: forces and band matrix (a refactoring correction)",
             per_call(tissue_assemble_loop, composition.assemble, forces, q, qd, rotation, Q, band, KL, -1.0, -1e3)),
            ("tissue assemble: forces only (a chord correction)",
             per_call(tissue_assemble_loop, composition.assemble, forces, q, qd, rotation, Q, no_band, 0, 0.0, 0.0)),
            ("of which the shaft (lateral and axial), forces and band matrix",
             per_call(tissue_assemble_loop, shaft_assemble, shaft_forces, q, qd, rotation, Q, band, KL, -1.0, -1e3)),
            ("of which the bevel tip, forces and band matrix",
             per_call(tissue_assemble_loop, bevel_assemble, carried[2], q, qd, rotation, Q, band, KL, -1.0, -1e3)),
            ("tissue advance (once per step)",
             per_call(tissue_advance_loop, composition.advance, carried, q, qd, float(simulation.state.t))),
            ("of which the lateral part (cut interval, rest points on the track)",
             per_call(lateral_loop, contact, carried[1].constants, q)),
            ("of which its track projection of the lateral points",
             per_call(projection_loop, contact, lateral_anchors)),
            ("of which the axial points inside the tissue (anchors, offsets)",
             per_call(contact_points_loop, contact, shaft, carried[1].constants, q))]
    print("| tissue stage | us |\n|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.2f} |")


if __name__ == "__main__":
    main()
