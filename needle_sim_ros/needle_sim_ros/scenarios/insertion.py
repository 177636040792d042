"""Scenario ``insertion``: insert the needle at constant speed into a configured tissue (ROS-free).

The base (clamp point A) starts at the world origin with the needle along world x, rolled by ``roll`` about its
axis, with the needle in static equilibrium under gravity and its tip ``gap`` in front of the entry surface (the
configured entry point is moved along its normal to x = L + gap; the normal must be world +x), and moves along x
at ``speed`` until the tip is ``depth`` below the surface.  Written: tip trajectory, base force and torque
(eq. 20, the needle on its holder, base frame), the tissue readout versus depth, and a plot of the tip deflection
toward the bevel side versus insertion depth in the style of seed 001 Fig. 4; ``final`` holds the final tip and
centerline in the base frame.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from needle_vision.package_files import share_file

from needle_sim_ros.model import (BaseMotion, Gravity, Integrator, NeedleProperties, State, build_model,
                                  load_needle_config, reaction_wrench, solve_static, tip_pose)
from needle_sim_ros.tissue.factory import TissueConfig, build_tissue_forces, tissue_readout

from .common import (add_needle_arguments, figure, material, needle_configuration, save_figure, shape_json,
                     write_json)



def default_tissue_config() -> Path:
    """The tissue params file needle_sim_ros installs (``share/needle_sim_ros/config/tissue.yaml``)."""
    return share_file("needle_sim_ros", "config/tissue.yaml")


def roll_quaternion(roll: float) -> np.ndarray:
    """Rotation by ``roll`` [rad] about world x, (x, y, z, w)."""
    return np.array([np.sin(0.5 * roll), 0.0, 0.0, np.cos(0.5 * roll)])


def _json_value(value):
    """Config value for strict JSON: arrays as lists, non-finite numbers (an unbounded layer) as strings."""
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json_value(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else str(float(value))
    return value


def simulate_insertion(props: NeedleProperties, tissue_config, speed: float, depth: float, gap: float = 2e-3,
                       roll: float = 0.0, dt: float = 1e-3, sample_every: int = 10, build: dict | None = None,
                       integrator_kwargs: dict | None = None, centerline_samples: int = 41) -> dict:
    """Run the insertion and return the JSON-ready result (see module docstring).

    build / integrator_kwargs: ``build_model`` / ``Integrator`` keyword arguments; None = the simulator node's
    defaults (10 elements, Rayleigh beta 1e-4 s, generalized-alpha).
    """
    for name, value in (("speed", speed), ("depth", depth), ("dt", dt)):
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"insertion scenario: {name} must be > 0, got {value!r}")
    if gap < 0.0 or sample_every < 1:
        raise ValueError("insertion scenario: gap must be >= 0 and sample_every >= 1")
    config = dict(TissueConfig.from_any(tissue_config).values)
    normal = np.asarray(config["tissue.entry_normal"], dtype=float)
    if np.linalg.norm(np.cross(normal, [1.0, 0.0, 0.0])) > 1e-9 * np.linalg.norm(normal) or normal[0] <= 0:
        raise ValueError("insertion scenario: tissue.entry_normal must be world +x (the insertion direction)")
    config["tissue.entry_point"] = [props.length + gap, 0.0, 0.0]
    config["tissue.enable"] = True
    if build is None or integrator_kwargs is None:
        _, default_build, default_integrator = load_needle_config({})
        build = default_build if build is None else build
        integrator_kwargs = default_integrator if integrator_kwargs is None else integrator_kwargs

    model = build_model(props, **build)
    integrator = Integrator(model, **integrator_kwargs)
    tissue = build_tissue_forces(config, model)
    forces = [Gravity(), *tissue]
    orientation = roll_quaternion(roll)
    velocity = np.array([speed, 0.0, 0.0])

    def base_at(t: float) -> BaseMotion:
        return BaseMotion(velocity * t, orientation, linear_velocity=velocity)

    base = base_at(0.0)
    moving = model.straight_state(base, 0.0)       # rigid translation with the base: the needle's velocities
    sagged = solve_static(model, base, forces=[Gravity()]).state
    state = State(sagged.q, moving.qd, np.zeros(model.n_dof), 0.0)     # start in equilibrium under gravity
    n_steps = int(np.ceil((gap + depth) / speed / dt))
    samples = []
    integration_wall = 0.0
    start = time.perf_counter()
    for k in range(1, n_steps + 1):
        base = base_at(k * dt)
        tick = time.perf_counter()
        state = integrator.step(state, dt, base, forces).state
        for force in forces:
            advance = getattr(force, "advance", None)
            if advance is not None:
                advance(model, state, base)
        integration_wall += time.perf_counter() - tick
        if k % sample_every == 0 or k == n_steps:
            tip_position, _ = tip_pose(model, state.q)
            wrench = reaction_wrench(model, state, base, forces)
            readout = tissue_readout(tissue, model, state, base)
            samples.append({
                "t_s": state.t,
                "insertion_depth_m": readout.insertion_depth,
                "inserted_length_m": readout.inserted_length,
                "tip_position_m": tip_position.tolist(),
                "tip_deflection_m": [float(tip_position[1]), float(tip_position[2])],
                "base_force_n": np.asarray(wrench.force_base).tolist(),
                "base_torque_nm": np.asarray(wrench.torque_base).tolist(),
                "tissue_tip_force_n": readout.tip_force.tolist(),
                "tissue_axial_force_n": readout.axial_force,
            })
    wall = time.perf_counter() - start
    return {
        "scenario": "insertion",
        "elements": model.n_elements,
        "material": material(props),
        "dt_s": dt,
        "steps": n_steps,
        "simulated_time_s": n_steps * dt,
        "integration_wall_time_s": integration_wall,
        "wall_time_s": wall,
        "real_time_factor": n_steps * dt / integration_wall,
        "speed_m_s": speed,
        "target_depth_m": depth,
        "gap_m": gap,
        "roll_rad": roll,
        "tissue": {k: _json_value(v) for k, v in config.items()},
        "final": shape_json(model, state.q, base, centerline_samples),
        "samples": samples,
    }


def plot_deflection(result: dict, path: Path, bevel_side_world: np.ndarray) -> None:
    """Tip deflection toward the bevel side (and perpendicular to it) [mm] versus insertion depth [mm] while the
    tip is in the tissue (seed 001 Fig. 4 style)."""
    inside = [s for s in result["samples"] if s["insertion_depth_m"] > 0.0]
    depth = np.array([s["insertion_depth_m"] for s in inside]) * 1e3
    lateral = np.array([s["tip_deflection_m"] for s in inside]).reshape(-1, 2) * 1e3
    side = np.asarray(bevel_side_world, dtype=float)[1:]
    side = side / np.linalg.norm(side)
    fig, (ax,) = figure(1, size=(6.0, 4.0))
    ax.plot(depth, lateral @ side, label="toward the bevel side (ANCF + tissue)")
    ax.plot(depth, lateral @ np.array([-side[1], side[0]]), "--", label="perpendicular (gravity sag if vertical)")
    ax.set_xlabel("insertion depth [mm]")
    ax.set_ylabel("tip deflection from the insertion axis [mm]")
    ax.set_title(f"needle insertion at {result['speed_m_s'] * 1e3:.1f} mm/s, "
                 f"roll {np.degrees(result['roll_rad']):.0f} deg")
    ax.grid(True)
    ax.legend(fontsize=8)
    save_figure(fig, path)


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("insertion", help="insert the needle into a configured tissue",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_needle_arguments(parser)
    parser.add_argument("--tissue-config", type=Path, default=None,
                        help="ROS 2 params file with tissue.* (default: share/needle_sim_ros/config/tissue.yaml)")
    parser.add_argument("--speed", type=float, default=0.006, help="insertion speed [m/s] (seed 001: 6 mm/s)")
    parser.add_argument("--depth", type=float, default=0.09, help="final insertion depth [m] (seed 001: 90 mm)")
    parser.add_argument("--gap", type=float, default=2e-3, help="initial tip distance to the surface [m]")
    parser.add_argument("--roll-deg", type=float, default=0.0, help="axial rotation of the base [deg]")
    parser.add_argument("--dt", type=float, default=None, help="time step [s] (default: integrator.dt of config)")
    parser.add_argument("--sample-every", type=int, default=10, help="record every n-th step")
    return parser


def run(args: argparse.Namespace) -> int:
    props, build, integrator_kwargs, parameters = needle_configuration(args)
    dt = args.dt if args.dt is not None else float(parameters["integrator.dt"])
    tissue_config = args.tissue_config or default_tissue_config()
    if not tissue_config.is_file():
        raise FileNotFoundError(f"--tissue-config '{tissue_config}' does not exist")
    roll = np.radians(args.roll_deg)
    result = simulate_insertion(props, tissue_config, args.speed, args.depth, args.gap, roll, dt, args.sample_every,
                                build, integrator_kwargs, args.centerline_samples)
    result["tissue_config"] = str(tissue_config.resolve())
    write_json(args.json, result)
    if args.plot is not None:
        side_base = np.asarray(result["tissue"]["tissue.bevel_tip.side"], dtype=float)
        plot_deflection(result, args.plot, BaseMotion(np.zeros(3), roll_quaternion(roll)).rotation @ side_base)
    last = result["samples"][-1]
    print(f"insertion: {result['steps']} steps of {dt * 1e3:g} ms, depth {last['insertion_depth_m'] * 1e3:.1f} mm, "
          f"tip off-axis (y, z) ({last['tip_deflection_m'][0] * 1e3:.3f}, {last['tip_deflection_m'][1] * 1e3:.3f}) mm, "
          f"real-time factor {result['real_time_factor']:.2f}")
    return 0
