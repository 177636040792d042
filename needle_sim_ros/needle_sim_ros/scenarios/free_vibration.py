"""Scenario ``free_vibration``: release of a tip mass.

The cantilever (base fixed, needle along world x) rests in equilibrium under its weight and a tip mass, removed at
t = 0. Written per sample: tip position (base frame = world frame), kinetic, elastic and gravitational energy
(eqs. 7, 9) and their sum, and the base wrench (eq. 20). Without damping (--beta 0) and rho_inf = 0.95 the total
energy stays within ~0.2 % per second (rho_inf = 1 is unstable here: ``needle_sim_ros.model.integrators``).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from needle_sim_ros.model import (BaseMotion, Gravity, Integrator, PointLoad, build_model, elastic_energy,
                                  gravitational_energy, kinetic_energy, reaction_wrench, solve_static)
from needle_sim_ros.model.integrators import METHODS

from needle_sim_ros.simulation import NeedleSimulation

from .common import (IDENTITY, figure, needle_configuration, run_sampled, save_figure, scenario_parser, shape_json,
                     wrench_json, write_outputs)


def simulate_release(props, build: dict, integrator_kwargs: dict, tip_mass: float, dt: float, duration: float,
                     sample_interval: float, n_samples: int) -> dict:
    """Run the release; the JSON-ready result (module docstring)."""
    for name, value in (("dt", dt), ("duration", duration), ("sample_interval", sample_interval)):
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"free_vibration scenario: {name} must be > 0, got {value!r}")
    if not (np.isfinite(tip_mass) and tip_mass >= 0.0):
        raise ValueError(f"free_vibration scenario: tip mass must be >= 0 kg, got {tip_mass!r}")
    start = time.perf_counter()
    model = build_model(props, **build)
    integrator = Integrator(model, **integrator_kwargs)
    base = BaseMotion((0.0, 0.0, 0.0), IDENTITY)
    g = float(np.linalg.norm(props.gravity))
    state = solve_static(model, base, [Gravity(), PointLoad(props.length, (0.0, 0.0, -g * tip_mass))]).state
    simulation = NeedleSimulation.prescribed(model, integrator, dt, lambda t: base, state)
    n_steps = int(round(duration / dt))
    every = max(1, int(round(sample_interval / dt)))

    def sample() -> dict:
        state = simulation.state
        energies = {"kinetic_energy_j": kinetic_energy(model, state.qd),
                    "elastic_energy_j": elastic_energy(model, state.q),
                    "gravitational_energy_j": gravitational_energy(model, state.q)}
        return {"t_s": state.t, "tip_position_m": state.q[-6:-3].tolist(), **energies,
                "total_energy_j": sum(energies.values()),
                "base_wrench": wrench_json(reaction_wrench(model, state, base, simulation.forces))}

    summary, samples = run_sampled(simulation, integrator_kwargs, n_steps, every, sample)
    return {"scenario": "free_vibration", **summary, "tip_mass_kg": tip_mass,
            **shape_json(model, simulation.state.q, base, n_samples), "base_wrench": samples[-1]["base_wrench"],
            "wall_time_s": time.perf_counter() - start, "samples": samples}


def plot_release(result: dict, path) -> None:
    """Tip deflection and energies over time."""
    fig, (top, bottom) = figure(2, (7.0, 6.0))
    t = np.array([s["t_s"] for s in result["samples"]])
    top.plot(t, [s["tip_position_m"][2] * 1e3 for s in result["samples"]])
    top.set(ylabel="tip z [mm]", title=f"release of a {result['tip_mass_kg'] * 1e3:g} g tip mass "
            f"({result['elements']} elements, dt = {result['dt_s'] * 1e3:g} ms)")
    for key, label in (("kinetic_energy_j", "kinetic"), ("elastic_energy_j", "elastic")):
        bottom.plot(t, [s[key] * 1e3 for s in result["samples"]], label=label)
    total = [s["total_energy_j"] for s in result["samples"]]
    bottom.set(title=f"change of the total energy (incl. gravity): {(total[-1] - total[0]) * 1e3:+.5f} mJ",
               xlabel="t [s]", ylabel="energy [mJ]")
    bottom.legend()
    for ax in (top, bottom):
        ax.grid(True)
    save_figure(fig, path)


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = scenario_parser(subparsers, "free_vibration", __doc__, "release of a tip mass, energy over time")
    parser.add_argument("--tip-mass", type=float, default=0.02, help="released tip mass [kg]")
    parser.add_argument("--duration", type=float, default=1.0, help="simulated time [s]")
    parser.add_argument("--method", choices=METHODS, default=None,
                        help="integrator (overrides config)")
    parser.add_argument("--rho-inf", type=float, default=None, help="spectral radius at infinity (overrides config)")
    parser.add_argument("--alpha", type=float, default=None, help="Rayleigh alpha [1/s] (overrides config)")
    parser.add_argument("--beta", type=float, default=None, help="Rayleigh beta [s] (overrides config)")
    parser.add_argument("--sample-interval", type=float, default=0.002, help="time between JSON samples [s]")
    return parser


def run(args: argparse.Namespace) -> int:
    props, build, integrator_kwargs, dt = needle_configuration(args)
    overrides = ((args.method, "method", integrator_kwargs), (args.rho_inf, "rho_inf", integrator_kwargs),
                 (args.alpha, "rayleigh_alpha", build), (args.beta, "rayleigh_beta", build))
    for option, key, target in overrides:
        if option is not None:
            target[key] = option
    result = simulate_release(props, build, integrator_kwargs, args.tip_mass, dt, args.duration,
                              args.sample_interval, args.centerline_samples)
    write_outputs(args, result, plot_release)
    energy = [s["total_energy_j"] for s in result["samples"]]
    print(f"free_vibration: {result['steps']} steps, real-time factor {result['real_time_factor']:.1f}, total energy "
          f"{energy[0] * 1e3:.4f} -> {energy[-1] * 1e3:.4f} mJ")
    return 0
