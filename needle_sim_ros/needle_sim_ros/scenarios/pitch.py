"""Scenario ``pitch``: seed 000's dynamic experiment (Sec. III, Fig. 8).

The distal ``clamp_fraction`` (seed 000: 40 %) is clamped where the straight needle lay (along world x); the base
pitches about its y axis, theta(t) = A sin(2 pi f t) (seed 000: A = 5 deg, f = 0.2 Hz), from static equilibrium.
Written per sample: time, pitch, tip and centerline (base frame), centerline (world frame), base wrench (base frame).
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from needle_sim_ros.model import (BaseMotion, Fixture, Gravity, Integrator, build_model, centerline,
                                  reaction_wrench, solve_static)

from needle_sim_ros.simulation import NeedleSimulation

from .common import (figure, needle_configuration, run_sampled, save_figure, scenario_parser, shape_json, wrench_json,
                     write_outputs)


def pitch_motion(amplitude: float, frequency: float):
    """t -> BaseMotion of the base at the origin pitching by amplitude sin(2 pi f t) [rad] about y."""
    omega = 2.0 * math.pi * frequency

    def motion(t: float) -> BaseMotion:
        angle = amplitude * math.sin(omega * t)
        rate = amplitude * omega * math.cos(omega * t)
        acceleration = -amplitude * omega**2 * math.sin(omega * t)
        return BaseMotion((0.0, 0.0, 0.0), (0.0, math.sin(0.5 * angle), 0.0, math.cos(0.5 * angle)),
                          (0.0, 0.0, 0.0), (0.0, rate, 0.0), (0.0, 0.0, 0.0), (0.0, acceleration, 0.0))

    return motion


def clamp_fixture(length: float, clamp_fraction: float) -> Fixture:
    """The world fixture of the distal ``clamp_fraction`` (the straight needle along world x from the origin); the
    default mesh puts its nodes there (:func:`~needle_sim_ros.model.mesh.clamped_element_lengths`)."""
    if not 0.0 < clamp_fraction < 1.0:
        raise ValueError(f"clamp_fraction must lie in (0, 1), got {clamp_fraction!r}")
    return Fixture(interval=((1.0 - clamp_fraction) * length, length), frame="world")


def simulate_pitch(props, build: dict, integrator_kwargs: dict, dt: float, amplitude: float, frequency: float,
                   periods: float, clamp_fraction: float, sample_interval: float, n_samples: int) -> dict:
    """Run the experiment; the JSON-ready result (module docstring)."""
    for name, value in (("dt", dt), ("frequency", frequency), ("periods", periods),
                        ("sample_interval", sample_interval)):
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"pitch scenario: {name} must be > 0, got {value!r}")
    start = time.perf_counter()
    build = {**build, "fixtures": (clamp_fixture(props.length, clamp_fraction),)}
    model = build_model(props, **build)
    integrator = Integrator(model, **integrator_kwargs)
    motion = pitch_motion(amplitude, frequency)
    state = solve_static(model, motion(0.0), [Gravity()]).state
    simulation = NeedleSimulation.prescribed(model, integrator, dt, motion, state)
    n_steps = int(round(periods / frequency / dt))
    every = max(1, int(round(sample_interval / dt)))

    def sample() -> dict:
        state, base = simulation.state, simulation.base
        angle = amplitude * math.sin(2.0 * math.pi * frequency * state.t)
        return {"t_s": state.t, "base_pitch_rad": angle, **shape_json(model, state.q, base, n_samples),
                "centerline_world_m": centerline(model, state.q, n_samples).points.tolist(),
                "base_wrench": wrench_json(reaction_wrench(model, state, base, simulation.forces))}

    summary, samples = run_sampled(simulation, integrator_kwargs, n_steps, every, sample)
    final = samples[-1]
    return {"scenario": "pitch", **summary, "tip_mass_kg": 0.0, "tip_position_m": final["tip_position_m"],
            "base_wrench": final["base_wrench"], "centerline_m": final["centerline_m"], "amplitude_rad": amplitude,
            "frequency_hz": frequency,
            "clamp_fraction": clamp_fraction, "wall_time_s": time.perf_counter() - start, "samples": samples}


def plot_instants(result: dict, path) -> None:
    """World-frame deflection z(x) at eight instants of the last period (seed 000 Fig. 8 style)."""
    fig, (ax,) = figure()
    period = 1.0 / result["frequency_hz"]
    times = np.array([s["t_s"] for s in result["samples"]])
    first = max(times[-1] - period, 0.0)
    for k in range(8):
        target = first + k * period / 8.0
        sample = result["samples"][int(np.argmin(np.abs(times - target)))]
        line = np.asarray(sample["centerline_world_m"]) * 1e3
        ax.plot(line[:, 0], line[:, 2], label=f"t = {abs(sample['t_s'] - first):.2f} s "
                                              f"({np.degrees(sample['base_pitch_rad']):+.1f} deg)")
    clamp = (1.0 - result["clamp_fraction"]) * result["material"]["length_m"] * 1e3
    ax.axvspan(clamp, result["material"]["length_m"] * 1e3, color="0.9", label="clamped")
    ax.set(xlabel="x [mm] (world)", ylabel="z [mm]", title=f"base pitch {np.degrees(result['amplitude_rad']):.0f} "
           f"deg at {result['frequency_hz']:g} Hz, T = {period:g} s")
    ax.grid(True)
    ax.legend(fontsize="small", ncol=2)
    save_figure(fig, path)


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = scenario_parser(subparsers, "pitch", __doc__, "base pitch with the distal part clamped, seed 000 Fig. 8")
    parser.add_argument("--amplitude-deg", type=float, default=5.0, help="pitch amplitude [deg] (range = 2 x)")
    parser.add_argument("--frequency", type=float, default=0.2, help="pitch frequency [Hz]")
    parser.add_argument("--periods", type=float, default=1.0, help="simulated periods")
    parser.add_argument("--clamp-fraction", type=float, default=0.4, help="clamped distal fraction of the needle")
    parser.add_argument("--sample-interval", type=float, default=0.05, help="time between JSON samples [s]")
    return parser


def run(args: argparse.Namespace) -> int:
    props, build, integrator_kwargs, dt = needle_configuration(args)
    result = simulate_pitch(props, build, integrator_kwargs, dt, math.radians(args.amplitude_deg), args.frequency,
                            args.periods, args.clamp_fraction, args.sample_interval, args.centerline_samples)
    write_outputs(args, result, plot_instants)
    print(f"pitch: {result['steps']} steps of {dt * 1e3:g} ms, real-time factor {result['real_time_factor']:.1f}, "
          f"{result['mean_newton_iterations']:.2f} Newton iterations per step")
    return 0
