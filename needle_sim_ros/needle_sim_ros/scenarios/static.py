"""Scenario ``static``: cantilever under its own weight plus a tip mass (seed 000 Fig. 7), one mass or a sweep.

Base fixed, needle along world x (base frame = world frame, z up); a tip mass m adds -m g e_z at the tip. Solved by
``solve_static``, a sweep continuing from the previous equilibrium. Written: tip position, base wrench (eq. 20),
centerline.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from needle_sim_ros.model import BaseMotion, Gravity, PointLoad, build_model, reaction_wrench, solve_static

from .common import (IDENTITY, figure, material, needle_configuration, save_figure, scenario_parser, shape_json,
                     wrench_json, write_outputs)


def solve_tip_masses(model, masses, n_samples: int) -> list[dict]:
    """One result dict per tip mass [kg] (continuation from the previous equilibrium)."""
    props = model.props
    base = BaseMotion((0.0, 0.0, 0.0), IDENTITY)
    g = float(np.linalg.norm(props.gravity))
    results, previous = [], None
    for mass in masses:
        if not (np.isfinite(mass) and mass >= 0.0):
            raise ValueError(f"--tip-mass must be >= 0 kg, got {mass!r}")
        forces = [Gravity(), PointLoad(props.length, (0.0, 0.0, -g * mass))]
        start = time.perf_counter()
        solution = solve_static(model, base, forces, initial=previous)
        wall = time.perf_counter() - start
        previous = solution.state
        results.append({"scenario": "static", "elements": model.n_elements, "material": material(props),
                        "axial_gauss_points": model.axial_gauss, "bending_gauss_points": model.bending_gauss,
                        "tip_mass_kg": float(mass),
                        **shape_json(model, solution.state.q, base, n_samples),
                        "base_wrench": wrench_json(reaction_wrench(model, solution.state, base, forces)),
                        "newton_iterations": solution.newton_iterations, "load_steps": solution.load_steps,
                        "wall_time_s": wall})
    return results


def plot_deflections(results: list[dict], path) -> None:
    """Deflection z versus x in the base frame for each tip mass (seed 000 Fig. 7 style)."""
    fig, (ax,) = figure()
    for result in results:
        line = np.asarray(result["centerline_m"]) * 1e3
        ax.plot(line[:, 0], line[:, 2], label=f"{result['tip_mass_kg'] * 1e3:g} g")
    ax.set(xlabel="x [mm] (base frame, along the undeformed needle)", ylabel="z [mm]",
           title=f"needle deflection under tip loads ({results[0]['elements']} ANCF elements)")
    ax.grid(True)
    ax.legend(title="tip mass")
    save_figure(fig, path)


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = scenario_parser(subparsers, "static", __doc__, "cantilever with tip mass(es), seed 000 Fig. 7", dt=False)
    parser.add_argument("--tip-mass", type=float, nargs="+", default=[0.08],
                        help="tip mass(es) [kg]; several values make a sweep (seed 000: 0 ... 0.08)")
    return parser


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    props, build, _, _ = needle_configuration(args)
    model = build_model(props, **build)
    results = solve_tip_masses(model, args.tip_mass, args.centerline_samples)
    if len(results) == 1:
        output = results[0]
    else:
        output = {"scenario": "static", "elements": model.n_elements, "material": results[0]["material"],
                  "results": results, "wall_time_s": time.perf_counter() - start}
    write_outputs(args, output, lambda _, path: plot_deflections(results, path))
    for result in results:
        tip = result["tip_position_m"]
        print(f"static: tip mass {result['tip_mass_kg'] * 1e3:6.1f} g -> tip (x, z) = ({tip[0] * 1e3:.3f}, "
              f"{tip[2] * 1e3:.3f}) mm, base force z {result['base_wrench']['force_n'][2]:.4f} N, "
              f"{result['wall_time_s'] * 1e3:.1f} ms")
    return 0
