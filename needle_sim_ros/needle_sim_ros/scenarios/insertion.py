"""Scenario ``insertion``: insert the needle into a configured tissue (ROS-free).

The base (clamp point A) starts at the origin, the needle along world x in static equilibrium, its tip ``gap``
before the entry surface (the entry point moved along its normal, which must be world +x, to x = L + gap), then
follows an ``InsertionMotion``. Written (SI): time, insertion depth, the tip's lateral deflection from the entry axis,
tip position, offset (y, z) and unit tangent, base roll, base force and torque (eq. 20, base frame), the tissue
readout, the parameters used, and a deflection-versus-depth plot (seed 001 Fig. 4 style).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from needle_common.package_files import share_file

from needle_sim_ros.model import (Gravity, Integrator, NeedleProperties, State, build_model, load_needle_config,
                                  reaction_wrench, solve_static)
from needle_sim_ros.tissue.factory import TissueConfig, build_tissue_model

from needle_sim_ros.simulation import NeedleSimulation

from .common import (checked_params_file, figure, material, needle_configuration, run_sampled, save_figure,
                     scenario_parser, shape_json, write_outputs)
from .insertion_motion import InsertionMotion


def shipped_tissue_config() -> Path:
    """The tissue params file needle_sim_ros installs (``share/needle_sim_ros/config/tissue.yaml``)."""
    return share_file("needle_sim_ros", "config/tissue.yaml")


def _json_value(value):
    """Config value for strict JSON: arrays as lists, non-finite numbers (an unbounded layer) as strings."""
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json_value(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else str(float(value))
    return value


def simulate_insertion(props: NeedleProperties, tissue_config, motion: InsertionMotion, dt: float = 1e-3,
                       sample_every: int = 10, build: dict | None = None, integrator_kwargs: dict | None = None,
                       centerline_samples: int = 41) -> dict:
    """Run the insertion and return the JSON-ready result (module docstring). build / integrator_kwargs:
    ``build_model`` / ``Integrator`` keyword arguments; None: the node's defaults (10 elements, Rayleigh beta
    1e-4 s, generalized-alpha)."""
    if not (np.isfinite(dt) and dt > 0.0) or sample_every < 1:
        raise ValueError(f"insertion scenario: dt must be > 0 and sample_every >= 1, got {dt!r}, {sample_every!r}")
    config = dict(TissueConfig.from_any(tissue_config).values)
    normal = np.asarray(config["tissue.entry_normal"], dtype=float)
    if np.linalg.norm(np.cross(normal, [1.0, 0.0, 0.0])) > 1e-9 * np.linalg.norm(normal) or normal[0] <= 0:
        raise ValueError("insertion scenario: tissue.entry_normal must be world +x (the insertion direction)")
    config["tissue.entry_point"] = [props.length + motion.gap, 0.0, 0.0]
    config["tissue.enable"] = True
    if build is None or integrator_kwargs is None:
        _, default_build, default_integrator = load_needle_config({})
        build = default_build if build is None else build
        integrator_kwargs = default_integrator if integrator_kwargs is None else integrator_kwargs

    model = build_model(props, **build)
    integrator = Integrator(model, **integrator_kwargs)
    base = motion.base_at(0.0)
    moving = model.straight_state(base, 0.0)       # rigid translation with the base: the needle's velocities
    sagged = solve_static(model, base, forces=[Gravity()]).state
    state = State(sagged.q, moving.qd, np.zeros(model.n_dof), 0.0)     # start in equilibrium under gravity
    simulation = NeedleSimulation.prescribed(model, integrator, dt, motion.base_at, state,
                                             [build_tissue_model(config, model)], motion.motions_at)
    n_steps = int(np.ceil(motion.duration / dt))

    def sample() -> dict:
        state, base = simulation.state, simulation.base
        tip, tip_gradient = state.q[-6:-3], state.q[-3:]
        wrench = reaction_wrench(model, state, base, simulation.forces)
        readout = simulation.tissue_readout()
        return {"time_s": state.t,
                "insertion_depth_m": readout.insertion_depth,
                "tip_lateral_deflection_m": float(np.hypot(tip[1], tip[2])),
                "tip_position_m": tip.tolist(),
                "tip_offset_m": [float(tip[1]), float(tip[2])],
                "tip_tangent": (tip_gradient / np.linalg.norm(tip_gradient)).tolist(),
                "roll_rad": float(motion.roll_at(state.t)[0]),
                "inserted_length_m": readout.inserted_length,
                "base_force_n": wrench.force_base.tolist(),
                "base_torque_nm": wrench.torque_base.tolist(),
                "tissue_tip_force_n": readout.tip_force.tolist(),
                "tissue_axial_force_n": readout.axial_force}

    start = time.perf_counter()
    summary, samples = run_sampled(simulation, integrator_kwargs, n_steps, sample_every, sample)
    state = simulation.state
    wall = time.perf_counter() - start
    winkler = np.asarray(config["tissue.layers.lateral_stiffness"], dtype=float)
    return {
        "scenario": "insertion", **summary,
        "wall_time_s": wall,
        "motion": {"depths_m": list(motion.waypoints), "speed_m_s": motion.speed, "gap_m": motion.gap,
                   "roll_rad": motion.roll, "spin_rate_rad_s": motion.spin_rate, "duty_cycle": motion.duty_cycle},
        "parameters": {"needle": {**material(props), "elements": model.n_elements,
                                  "axial_gauss_points": model.axial_gauss, "bending_gauss_points": model.bending_gauss},
                       "tissue": {k: _json_value(v) for k, v in config.items()},
                       "winkler_modulus_n_m2": _json_value(winkler)},
        **{key: [s[key] for s in samples] for key in samples[0]},  # one series per sampled quantity
        "final": shape_json(model, state.q, motion.base_at(state.t), centerline_samples)}


def bevel_side_world(result: dict, t: float) -> np.ndarray:
    """The configured bevel side (base frame) in the world at time t of a result."""
    side = np.asarray(result["parameters"]["tissue"]["tissue.bevel_tip.side"], dtype=float)
    roll = float(np.interp(t, result["time_s"], result["roll_rad"]))
    c, s = np.cos(roll), np.sin(roll)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]) @ side


def plot_deflection(result: dict, path: Path, reference: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Tip deflection toward the initial bevel side and perpendicular to it [mm] versus insertion depth [mm] while
    the tip is in the tissue (seed 001 Fig. 4 style); ``reference``: (depth [m], deflection [m]) of another
    solution, drawn for comparison."""
    depth = np.asarray(result["insertion_depth_m"])
    inside = depth > 0.0
    offset = np.asarray(result["tip_offset_m"])[inside] * 1e3
    side = bevel_side_world(result, 0.0)[1:]
    side = side / np.linalg.norm(side)
    fig, (ax,) = figure(1, size=(6.0, 4.0))
    ax.plot(depth[inside] * 1e3, offset @ side, label="ANCF + tissue, toward the bevel side")
    ax.plot(depth[inside] * 1e3, offset @ np.array([-side[1], side[0]]), "--",
            label="ANCF + tissue, perpendicular (gravity sag if vertical)")
    if reference is not None:
        ax.plot(np.asarray(reference[0]) * 1e3, np.asarray(reference[1]) * 1e3, ":", color="k", lw=2,
                label="reference: Euler-Bernoulli beam on Winkler foundation")
    motion = result["motion"]
    ax.set(xlabel="insertion depth [mm]", ylabel="tip deflection from the insertion axis [mm]",
           title=f"insertion at {motion['speed_m_s'] * 1e3:.1f} mm/s, roll {np.degrees(motion['roll_rad']):.0f} deg"
           + (f", duty cycle {motion['duty_cycle']:.2f}" if motion["duty_cycle"] else ""))
    ax.grid(True)
    ax.legend(fontsize=8)
    save_figure(fig, path)


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = scenario_parser(subparsers, "insertion", __doc__, "insert the needle into a configured tissue")
    parser.add_argument("--speed", type=float, default=0.006, help="insertion speed [m/s] (seed 001: 6 mm/s)")
    parser.add_argument("--depth", type=float, default=0.09, help="final insertion depth [m] (seed 001: 90 mm)")
    parser.add_argument("--retract-to", type=float, default=None,
                        help="after reaching --depth, retract the tip to this depth [m]")
    parser.add_argument("--gap", type=float, default=2e-3, help="initial tip distance to the surface [m]")
    parser.add_argument("--roll-deg", type=float, default=0.0, help="axial rotation of the base [deg]")
    parser.add_argument("--spin-rate", type=float, default=0.0, help="duty-cycled spinning rate [rad/s]")
    parser.add_argument("--duty-cycle", type=float, default=0.0,
                        help="fraction of each period spent spinning one turn at --spin-rate [0, 1]")
    parser.add_argument("--sample-every", type=int, default=10, help="record every n-th step")
    return parser


def run(args: argparse.Namespace) -> int:
    props, build, integrator_kwargs, dt = needle_configuration(args)
    files = [shipped_tissue_config(), *args.params]
    tissue = {}
    for path in files:
        tissue.update(checked_params_file(path, ("tissue.",)))
    depths = (args.depth,) if args.retract_to is None else (args.depth, args.retract_to)
    motion = InsertionMotion(depths, args.speed, args.gap, np.radians(args.roll_deg), args.spin_rate,
                             args.duty_cycle)
    result = simulate_insertion(props, tissue, motion, dt, args.sample_every, build, integrator_kwargs,
                                args.centerline_samples)
    result["params_files"] = [str(path.resolve()) for path in files]
    write_outputs(args, result, plot_deflection)
    print(f"insertion: {result['steps']} steps of {dt * 1e3:g} ms, depth {result['insertion_depth_m'][-1] * 1e3:.1f} "
          f"mm, tip lateral deflection {result['tip_lateral_deflection_m'][-1] * 1e3:.3f} mm (y, z: "
          f"{result['tip_offset_m'][-1][0] * 1e3:.3f}, {result['tip_offset_m'][-1][1] * 1e3:.3f} mm), "
          f"real-time factor {result['real_time_factor']:.2f}")
    return 0
