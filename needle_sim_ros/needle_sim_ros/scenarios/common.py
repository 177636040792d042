"""Shared pieces of the ``needle_scenario`` sub-commands: needle set-up from a params file and the command line,
JSON fragments of results, and the matplotlib (Agg) figure helpers."""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from needle_common.output_files import write_atomically
from needle_common.parameters import ParamSpec, load_params_file

from needle_sim_ros.model import (BaseMotion, BaseWrench, NeedleModel, NeedleProperties, centerline,
                                  load_needle_config, needle_parameters)
from needle_sim_ros.model.config import DEFAULTS, GROUPS
from needle_sim_ros.simulation import NeedleSimulation

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def scenario_parser(subparsers, name: str, doc: str, summary: str, dt: bool = True) -> argparse.ArgumentParser:
    """The sub-command ``name`` (``doc``: its description) with the needle set-up options, and ``--dt`` if ``dt``."""
    parser = subparsers.add_parser(name, help=summary, description=doc,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", type=Path, action="append", default=[], metavar="FILE",
                        help="ROS 2 params file (e.g. the simulator's) with needle.*, damping.*, integrator.* "
                             "(repeatable, applied in order; default: built-in defaults, the seed 000 needle)")
    parser.add_argument("--elements", type=int, default=None, help="number of ANCF elements (overrides config)")
    parser.add_argument("--axial-gauss", type=int, default=None,
                        help="Gauss points of the axial integral, eq. 12 (overrides config; seed 000: 5)")
    parser.add_argument("--centerline-samples", type=int, default=41, help="centerline points written to JSON")
    parser.add_argument("--json", type=Path, default=None, help="write the result JSON here")
    parser.add_argument("--plot", type=Path, default=None, help="write a PNG figure here")
    if dt:
        parser.add_argument("--dt", type=float, default=None, help="time step [s] (default: integrator.dt of config)")
    return parser


# Model keys the node does not declare (a scenario's mesh and fixtures); empty lists stand for "none".
MODEL_ONLY_PARAMETERS = [
    ParamSpec("needle.element_lengths", [], "Lengths of the elements from A to the tip [m]; []: uniform.", 0.0, 10.0),
    ParamSpec("fixtures.intervals", [], "Arc-length pairs [s_start, s_end, ...] [m] held in a fixture; []: none.",
              0.0, 10.0),
    ParamSpec("fixtures.frame", "world", "Frame of the fixtures: world or base."),
    ParamSpec("fixtures.needle_position", [0.0, 0.0, 0.0], "Needle base position of the fixture frame [m].", length=3),
    ParamSpec("fixtures.needle_orientation", [0.0, 0.0, 0.0, 1.0], "Needle base orientation of the fixture frame "
              "(quaternion x, y, z, w).", length=4),
]


def checked_params_file(path: Path, prefixes: tuple[str, ...]) -> dict:
    """The ``needle_simulator`` (or ``/**``) values of a params file, checked by the shared loader against the
    simulator's declarations (ParameterError, a ValueError, naming the file and parameter); only names starting
    with ``prefixes`` are kept, and empty model lists become None (the model's "none")."""
    from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
    values = load_params_file(path, "needle_simulator", [*SIMULATOR_PARAMETERS, *MODEL_ONLY_PARAMETERS])
    return {name: (None if value == [] and name in DEFAULTS else value)
            for name, value in values.items() if name.startswith(prefixes)}


def needle_configuration(args: argparse.Namespace) -> tuple[NeedleProperties, dict, dict, float]:
    """(props, build_model kwargs, Integrator kwargs, time step [s]) from --params files (applied in order, each
    checked by the shared loader) and the command line (``--dt`` if given)."""
    source: dict = {}
    for path in args.params:
        source.update(checked_params_file(path, tuple(g + "." for g in GROUPS)))
    props, build, integrator = load_needle_config(source)
    if args.elements is not None:
        build["n_elements"] = args.elements
        build.pop("element_lengths", None)
    if args.axial_gauss is not None:
        build["axial_gauss"] = args.axial_gauss
    dt = getattr(args, "dt", None)
    return props, build, integrator, float(needle_parameters(source)["integrator.dt"]) if dt is None else dt


def material(props: NeedleProperties) -> dict:
    return {"youngs_modulus_pa": props.youngs_modulus, "density_kg_m3": props.density, "radius_m": props.radius,
            "inner_radius_m": props.inner_radius, "length_m": props.length, "gravity_m_s2": list(props.gravity)}


def wrench_json(wrench: BaseWrench) -> dict:
    """The wrench on the holder, base frame, about the clamp point A."""
    return {"force_n": wrench.force_base.tolist(), "torque_nm": wrench.torque_base.tolist()}


def in_base_frame(base: BaseMotion, points: np.ndarray) -> np.ndarray:
    return (np.asarray(points) - base.position) @ base.rotation


def shape_json(model: NeedleModel, q: np.ndarray, base: BaseMotion, n_samples: int) -> dict:
    """Tip position and centerline in the base frame (x along the undeformed needle)."""
    line = centerline(model, q, n_samples)
    return {"tip_position_m": in_base_frame(base, q[-6:-3]).tolist(),
            "centerline_m": in_base_frame(base, line.points).tolist()}


def write_outputs(args: argparse.Namespace, result: dict, plot: Callable[[dict, Path], None]) -> None:
    """The result as JSON (``--json``) and ``plot(result, path)`` (``--plot``), where asked."""
    if args.json is not None:
        write_atomically(args.json, lambda temporary: temporary.write_text(json.dumps(result, indent=1)))
    if args.plot is not None:
        plot(result, args.plot)


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed): the scenarios', offline and batch plots."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def figure(n_axes: int = 1, size=(7.0, 4.5)):
    """A figure of ``n_axes`` axes in a column."""
    fig, axes = pyplot().subplots(n_axes, 1, figsize=size, squeeze=False)
    return fig, axes[:, 0]


def save_figure(fig, path: Path, dpi: int = 120) -> Path:
    """Write the figure (tight layout) atomically, close it and return ``path``."""
    fig.tight_layout()
    write_atomically(path, lambda temporary: fig.savefig(temporary, dpi=dpi))
    pyplot().close(fig)
    return path


def run_sampled(simulation: NeedleSimulation, integrator_kwargs: dict, n_steps: int, every: int,
                sample: Callable[[], dict]) -> tuple[dict, list[dict]]:
    """Advance the simulation (:meth:`NeedleSimulation.advance_to`, the simulator's one time loop) by n_steps
    steps of its dt, taking ``sample()`` at the start, every ``every`` steps and at the end. Returns the fields every
    scenario result has (mesh, material, integrator, damping and the integration's effort: its wall time [s]
    without the sampling, Newton iterations) and the samples."""
    samples = [sample()]
    origin, dt, model = simulation.state.t, simulation.dt, simulation.model
    integration_wall, iterations = 0.0, 0
    for k in [*range(every, n_steps, every), n_steps] if n_steps > 0 else []:
        tick = time.perf_counter()
        records = simulation.advance_to(origin + k * dt)
        integration_wall += time.perf_counter() - tick
        iterations += sum(step.newton_iterations for step in records)
        samples.append(sample())
    return {"elements": model.n_elements, "material": material(model.props),
            "axial_gauss_points": model.axial_gauss, "bending_gauss_points": model.bending_gauss,
            "integrator": {**integrator_kwargs},
            "rayleigh": {"alpha": model.rayleigh_alpha, "beta": model.rayleigh_beta},
            "dt_s": dt, "steps": n_steps, "simulated_time_s": n_steps * dt,
            "integration_wall_time_s": integration_wall, "real_time_factor": n_steps * dt / integration_wall,
            "mean_newton_iterations": iterations / max(n_steps, 1)}, samples
