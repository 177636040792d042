"""Per-step cost of the compiled runs as the node and the offline stage drive them: one ``advance_to`` per 1 or 5
steps of 1 ms (so the Python -> numba call is made per pose), CPU time of this process, best of 5 runs of 1500
steps; prints a Markdown table. Cases: a pitching base under gravity (the step sequence) and an insertion into
the shipped tissue defaults (the tissue's run; the entry 6 mm before the tip, 10 mm/s).

numba 0.59 (Ubuntu 24.04's, requirements-noble.lock) types a tuple argument in Python on every call; run this on
both locks to see that no tuple crosses the boundary (issue 38).

Usage (the installed package: source .venv/needle_env.sh first):
    python bench/bench_run_calls.py
"""
from __future__ import annotations

import math
import time

import numba

from needle_sim_ros.model import BaseMotion, Gravity
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import NeedleSimulation, model_builder_from_parameters
from needle_sim_ros.tissue.factory import build_tissue_model

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
STEPS, REPEATS, DT = 1500, 5, 1e-3


def inserting(t: float) -> BaseMotion:
    return BaseMotion((0.01 * t, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), linear_velocity=(0.01, 0.0, 0.0))


def pitching(t: float) -> BaseMotion:
    angle = math.radians(5.0) * math.sin(math.pi * t)
    return BaseMotion((0.0, 0.0, 0.0), (0.0, math.sin(0.5 * angle), 0.0, math.cos(0.5 * angle)))


def cpu_per_step(tissue: bool, steps_per_call: int) -> float:
    """CPU time [us] per step of STEPS steps, ``steps_per_call`` per advance_to, after 10 warm-up steps."""
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    base = inserting if tissue else pitching
    config = {**{n: v for n, v in PARAMETERS.items() if n.startswith("tissue.")}, "tissue.enable": True,
              "tissue.entry_point": [0.272, 0.0, 0.0]}
    forces = [build_tissue_model(config, model)] if tissue else [Gravity()]
    simulation = NeedleSimulation.prescribed(model, integrator, DT, base, model.straight_state(base(0.0)), forces)
    simulation.advance_to(10 * DT)
    start = time.process_time()
    for k in range(STEPS // steps_per_call):
        simulation.advance_to((10 + steps_per_call * (k + 1)) * DT)
    return (time.process_time() - start) / STEPS * 1e6


def main() -> None:
    print(f"numba {numba.__version__}; 10 elements, dt = 1 ms; CPU time, best of {REPEATS}\n")
    print("| run | steps per advance_to | us per step |\n|---|---|---|")
    for tissue in (False, True):
        for per_call in (1, 5):
            best = min(cpu_per_step(tissue, per_call) for _ in range(REPEATS))
            name = "tissue insertion (the tissue's run)" if tissue else "pitching base, gravity (step sequence)"
            print(f"| {name} | {per_call} | {best:.1f} |")


if __name__ == "__main__":
    main()
