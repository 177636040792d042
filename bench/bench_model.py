"""Benchmark of the ANCF needle model (needle_sim_ros.model); prints Markdown tables.  Not a test.

    cd /work/main && source .venv/needle_env.sh && PYTHONPATH=needle_sim_ros python bench/bench_model.py [--quick]

* start-up: numba compilation with an empty cache (first run after install) and loading from the cache;
* integration step at dt = 1 ms for 5/10/20/40 elements through the simulator's one time loop
  (NeedleSimulation.advance_to, reaction wrench included): the base moves (5 mm/s insertion, 5 deg pitch at
  0.2 Hz), gravity, Rayleigh beta = 1e-4, generalized-alpha (rho_inf = 0.8); real-time factor = dt / step time;
  the general step path (full Newton) and the compiled step sequence (the simulator's path without tissue);
  again with a 20-point MaterialPointForce (a tissue-like lateral spring-damper on the distal half, the path tissue
  models take); plus reaction wrench (eq. 20), a 50-point centerline and BaseMotion.from_flange;
* the node's outputs besides the wrench: shape output, NeedleShape and Path messages, RViz tube;
* static equilibrium under weight + 80 g tip mass from the straight needle (10 elements).
Times are the best of several repeats (the machine may be shared); the base motion is evaluated per step, as the
simulator does.
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from needle_sim_ros.model import (BaseMotion, Gravity, Integrator, MaterialPointForce, NeedleProperties,
                                  PointForces, PointLoad, build_model, centerline, reaction_wrench, solve_static)
from needle_sim_ros.simulation import NeedleSimulation

NEEDLE = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)
DT = 1e-3

STARTUP_SCRIPT = """
import time
start = time.perf_counter()
import numpy as np
from needle_sim_ros.model import *
from needle_sim_ros.simulation import NeedleSimulation
props = NeedleProperties(0.27, 0.635e-3, 193e9, 8000.0)
model = build_model(props, 10, rayleigh_beta=1e-4)
base = BaseMotion.from_flange((0, 0, 0), (0, 0, 0, 1), (0, 0, 0.1), (0, 0, 0, 1))
law = lambda r, rx, v, t, b: PointForces(-r, -np.broadcast_to(np.eye(3), (r.shape[0], 3, 3)))
forces = [Gravity(), PointLoad(0.27, (0, 0, -0.1)), MaterialPointForce([0.2, 0.25], [0.01, 0.01], law)]
state = model.straight_state(base)
integrator = Integrator(model)
simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, lambda t: base, state, forces[1:2])
simulation.advance_to(0.003)  # the compiled sequence
simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, lambda t: base, simulation.state, forces[1:])
simulation.advance_to(0.006)  # the general step path
state = simulation.state
static = solve_static(model, base, forces[:2]).state
reaction_wrench(model, state, base, forces)
centerline(model, state.q, 50)
tip_pose(model, state.q)
print(time.perf_counter() - start)
"""


def startup_times() -> tuple[float, float]:
    """(seconds with an empty numba cache, seconds with the cache filled), each in a fresh interpreter."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        run = lambda: float(subprocess.run([sys.executable, "-c", STARTUP_SCRIPT], env=env, check=True,
                                           capture_output=True, text=True).stdout.split()[-1])
        return run(), min(run() for _ in range(2))


def base_motion(t: float) -> BaseMotion:
    """Insertion at 5 mm/s with a 5 deg pitch at 0.2 Hz."""
    amplitude, omega = math.radians(5.0), 2 * math.pi * 0.2
    angle = amplitude * math.sin(omega * t)
    return BaseMotion((0.005 * t, 0.0, 0.0), (0.0, math.sin(angle / 2), 0.0, math.cos(angle / 2)),
                      (0.005, 0.0, 0.0), (0.0, amplitude * omega * math.cos(omega * t), 0.0), 0.0,
                      (0.0, -amplitude * omega**2 * math.sin(omega * t), 0.0))


def tissue_like_force(n_points: int = 20) -> MaterialPointForce:
    """Lateral spring (5e4 N/m^2) and damper (5 N s/m^2) towards the world x axis on the distal half."""
    s = np.linspace(0.5 * NEEDLE.length, NEEDLE.length, n_points)
    lateral = np.diag([0.0, 1.0, 1.0])

    def law(r, r_x, v, t, base):
        k = r.shape[0]
        return PointForces(-5e4 * r @ lateral - 5.0 * v @ lateral, np.broadcast_to(-5e4 * lateral, (k, 3, 3)),
                           None, np.broadcast_to(-5.0 * lateral, (k, 3, 3)))

    return MaterialPointForce(s, np.full(n_points, 0.5 * NEEDLE.length / n_points), law)


def best_time(function, calls: int, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        best = min(best, (time.perf_counter() - start) / calls)
    return best


def step_benchmark(n_elements: int, extra_forces: list, steps: int, repeats: int,
                   compiled: bool) -> tuple[float, float]:
    """(best mean wall time per step [s], mean Newton iterations per step) of the simulator's one time loop,
    ``NeedleSimulation.advance_to``, on the prescribed base motion with gravity and ``extra_forces``, reaction wrench
    included: the compiled step sequence where it applies (``compiled``) or the general step path."""
    model = build_model(NEEDLE, n_elements, rayleigh_beta=1e-4)
    simulation = NeedleSimulation.prescribed(model, Integrator(model), DT, base_motion,
                                             model.straight_state(base_motion(0.0)), extra_forces)
    simulation.compiled_sequence = compiled
    simulation.advance_to(steps * DT)  # warm-up, leaves the start transient behind
    best, iterations = np.inf, 0.0
    for r in range(repeats):
        start = time.perf_counter()
        records = simulation.advance_to((r + 2) * steps * DT)
        best = min(best, (time.perf_counter() - start) / len(records))
        iterations = sum(record.newton_iterations for record in records) / len(records)
    return best, iterations


def output_times(n_elements: int, repeats: int) -> tuple[float, float]:
    model = build_model(NEEDLE, n_elements, rayleigh_beta=1e-4)
    base, forces = base_motion(0.1), [Gravity()]
    state = Integrator(model).step(model.straight_state(base_motion(0.0)), 0.1, base, forces).state
    return (best_time(lambda: reaction_wrench(model, state, base, forces), 200, repeats),
            best_time(lambda: centerline(model, state.q, 50), 200, repeats))


def output_message_times(repeats: int) -> list[tuple[str, float]]:
    """(output, best time per call [s]) of what the simulator node publishes besides the wrench (10 elements,
    50 samples): the shape output and its message at rates.shape_hz, the RViz path and tube at
    rates.visualization_hz."""
    from needle_sim_ros.messages import cdr
    from needle_common.transforms import quaternions_from_x_axes
    from needle_sim_ros.messages.geometry import tube_triangles
    from needle_sim_ros.messages.shape import model_shape_cdr
    from needle_sim_ros.model import model_shape

    model = build_model(NEEDLE, 10, rayleigh_beta=1e-4)
    base, forces = base_motion(0.1), [Gravity()]
    state = Integrator(model).step(model.straight_state(base_motion(0.0)), 0.1, base, forces).state
    shape = model_shape(model, state.q, 0.1, 50, base.orientation)
    line = shape.line
    quaternions = quaternions_from_x_axes(line.tangents)
    outputs = {
        "shape: 50-sample centerline and tip frame (model_shape)": lambda: model_shape(model, state.q, 0.1, 50,
                                                                                      base.orientation),
        "NeedleShape message (CDR)": lambda: model_shape_cdr(shape, "world"),
        "path orientations (quaternions_from_x_axes)": lambda: quaternions_from_x_axes(line.tangents),
        "nav_msgs/Path message (CDR)": lambda: cdr.path(0, 0, "world", line.points, quaternions),
        "RViz tube, 8 sides (tube_triangles)": lambda: tube_triangles(line.points, line.tangents, NEEDLE.radius),
    }
    return [(name, best_time(function, 200, repeats)) for name, function in outputs.items()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer steps and repeats, no start-up measurement")
    args = parser.parse_args()
    steps, repeats = (300, 2) if args.quick else (1000, 5)

    if not args.quick:
        cold, warm = startup_times()
        print("| start-up (import, build, steps, static solve, outputs) | seconds |\n|---|---|")
        print(f"| empty numba cache (compilation) | {cold:.1f} |\n| numba cache filled (cache=True) | {warm:.2f} |\n")

    print("| elements | general step + wrench [us] | real-time factor | compiled sequence, step + wrench [us] "
          "| real-time factor | general step + 20-pt MaterialPointForce [us] | real-time factor "
          "| Newton its/step (plain / with force) | reaction wrench [us] | centerline 50 pts [us] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n_elements in (5, 10, 20, 40):
        plain, plain_its = step_benchmark(n_elements, [], steps, repeats, compiled=False)
        sequence, _ = step_benchmark(n_elements, [], steps, repeats, compiled=True)
        tissue, tissue_its = step_benchmark(n_elements, [tissue_like_force()], steps, repeats, compiled=False)
        wrench, line = output_times(n_elements, repeats)
        print(f"| {n_elements} | {plain * 1e6:.0f} | {DT / plain:.1f} | {sequence * 1e6:.0f} | {DT / sequence:.1f} "
              f"| {tissue * 1e6:.0f} | {DT / tissue:.1f} "
              f"| {plain_its:.2f} / {tissue_its:.2f} | {wrench * 1e6:.0f} | {line * 1e6:.0f} |")

    flange = best_time(lambda: BaseMotion.from_flange((0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.1),
                                                      (0.0, 0.0, 0.0, 1.0), (0.005, 0, 0), (0, 0.1, 0)),
                       2000, repeats)
    print(f"\nBaseMotion.from_flange: {flange * 1e6:.0f} us per call")
    print("\n| node output (10 elements, 50 samples) | us per call |\n|---|---|")
    for name, seconds in output_message_times(repeats):
        print(f"| {name} | {seconds * 1e6:.0f} |")

    model = build_model(NEEDLE, 10)
    base = BaseMotion((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    forces = [Gravity(), PointLoad(NEEDLE.length, (0.0, 0.0, -9.81 * 0.08))]
    solution = solve_static(model, base, forces)
    static = best_time(lambda: solve_static(model, base, forces), 20, repeats)
    print(f"\n| static 80 g tip mass, 10 elements, from straight | value |\n|---|---|\n"
          f"| wall time | {static * 1e3:.1f} ms |\n| Newton iterations | {solution.newton_iterations} |\n"
          f"| load increments | {solution.load_steps} |")


if __name__ == "__main__":
    main()
