"""Real-time factor of the needle simulation with the tissue models enabled (issue 5 benchmark).

Runs the ``insertion`` scenario core (10 ANCF elements, dt = 1 ms, 90 mm at 6 mm/s, config/tissue.yaml) once per
tissue configuration and prints a table: simulated time / wall time of the simulator's time loop
(``NeedleSimulation.advance_to``: the tissue's compiled run of steps -- Newton with the tissue forces, the tissue
advanced, each step's reaction wrench -- and the insertion scenario's samples; > 1 is faster than real time), mean
step time, and the final tip position off the
insertion axis (y, z; z includes the gravity sag of about -2.8 mm).
A baseline without tissue (gravity only, same base motion) shows the tissue's cost. The host gauge printed first
(``host_gauge.py``) reads the shared host's speed: compare runs of different moments by it first.

Usage (the installed package: source .venv/needle_env.sh first):
    python bench/bench_tissue.py [--depth 0.09] [--speed 0.006] [--elements 10] [--dt 0.001]
"""
from __future__ import annotations

import argparse
import sys

from host_gauge import gauge_line
from needle_sim_ros.model import load_needle_config
from needle_sim_ros.scenarios.insertion import InsertionMotion, shipped_tissue_config, simulate_insertion
from needle_sim_ros.tissue.factory import flatten_tissue_config

NEEDLE, BUILD, INTEGRATOR = load_needle_config({})        # the simulator node's defaults (seed 000 needle)

CASES = {
    "karnopp + lateral + bevel": {},
    "lateral + bevel, no axial law": {"tissue.shaft.axial_model": "none"},
    "insertion profile (seed 002)": {"tissue.shaft.axial_model": "insertion_profile",
                                     "tissue.insertion_profile.enable": True, "tissue.bevel_tip.enable": False},
    "LuGre (seed 003) + lateral": {"tissue.shaft.axial_model": "lugre", "tissue.bevel_tip.enable": False},
}


def baseline_real_time_factor(n_elements: int, dt: float, speed: float, duration: float) -> float:
    """The same needle and insertion motion without tissue (gravity only), its base motions given for a run of steps
    at once as in the tissue runs (``InsertionMotion.motions_at``), advanced by the simulator's time loop (which
    takes the compiled step sequence here): simulated / integration wall time."""
    import time

    from needle_sim_ros.model import Integrator, build_model
    from needle_sim_ros.simulation import NeedleSimulation

    model = build_model(NEEDLE, **{**BUILD, "n_elements": n_elements})
    motion = InsertionMotion((speed * duration,), speed)
    simulation = NeedleSimulation.prescribed(model, Integrator(model, **INTEGRATOR), dt, motion.base_at,
                                             model.straight_state(motion.base_at(0.0)), motions_at=motion.motions_at)
    steps = int(round(duration / dt))
    start = time.perf_counter()
    simulation.advance_to(steps * dt)
    return steps * dt / (time.perf_counter() - start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--depth", type=float, default=0.09)
    parser.add_argument("--speed", type=float, default=0.006)
    parser.add_argument("--elements", type=int, default=10)
    parser.add_argument("--dt", type=float, default=1e-3)
    args = parser.parse_args()

    tissue = flatten_tissue_config(shipped_tissue_config())
    print(f"{args.elements} elements, dt = {args.dt * 1e3:g} ms, {args.depth * 1e3:g} mm at {args.speed * 1e3:g} mm/s")
    print(gauge_line())
    print(f"{'case':34s} {'sim time':>9s} {'wall':>8s} {'RT factor':>10s} {'mean step':>10s} {'tip y, z [mm]':>16s}")
    # load the compiled kernels from the numba cache first (once per process, 0.3-0.5 s: bench_cold_start.py's),
    # for every case: each set of tissue parts is its own composition (``model.step.compose``)
    for overrides in CASES.values():
        simulate_insertion(NEEDLE, {**tissue, **overrides}, InsertionMotion((0.001,), args.speed), dt=args.dt,
                           sample_every=100, build={**BUILD, "n_elements": args.elements}, integrator_kwargs=INTEGRATOR)
    baseline_real_time_factor(args.elements, args.dt, args.speed, 0.01)  # its kernels loaded before it is timed
    baseline = baseline_real_time_factor(args.elements, args.dt, args.speed, 3.0)
    print(f"{'no tissue (gravity only, 3 s)':34s} {3.0:8.2f}s {3.0 / baseline:7.2f}s {baseline:10.2f} "
          f"{args.dt / baseline * 1e3:8.3f}ms {'':>10s}")
    for name, overrides in CASES.items():
        result = simulate_insertion(NEEDLE, {**tissue, **overrides}, InsertionMotion((args.depth,), args.speed),
                                    dt=args.dt, sample_every=100, build={**BUILD, "n_elements": args.elements},
                                    integrator_kwargs=INTEGRATOR)
        steps = result["simulated_time_s"] / args.dt
        y, z = (1e3 * x for x in result["tip_offset_m"][-1])
        print(f"{name:34s} {result['simulated_time_s']:8.2f}s {result['integration_wall_time_s']:7.2f}s "
              f"{result['real_time_factor']:10.2f} {result['integration_wall_time_s'] / steps * 1e3:8.3f}ms "
              f"{y:7.3f}, {z:7.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
