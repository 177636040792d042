"""Benchmark against MuJoCo's 1D flex rod on the same needle; prints Markdown tables.  Not a test.

    source .venv/needle_env.sh && pip install 'mujoco>=3.17' && python bench/bench_vs_mujoco.py  # repository root

MuJoCo is a benchmark-only dependency (not in requirements.lock): its 1D flex bends since 3.17 (a discrete
elastic rod, ``<elasticity young=...>``), integrated by its ``discrete`` integrator. Both sides model the seed 000
needle (0.27 m, r = 0.635 mm, E = 193 GPa, 8000 kg/m^3) with 10 elements / 10 segments and dt = 1 ms; MuJoCo
clamps the base by pinning the first two vertices (position and slope), its edges are inextensible (edge
equality constraints made as stiff as the time step allows: solref 2 dt, solimp 0.9999; with MuJoCo's default
ones the segments stretch to 3x their length under the 80 g load) and it has no material damping.

* Speed: mean time per 1 ms step over 3 s of motion after a 10 g tip load is released from static equilibrium
  (each side starts from its own equilibrium), per path of the simulator: gravity only, no gravity, the 10 g load
  kept at the tip, 10 g at mid-span, and the general one-step path (``Integrator.step``, the path state-dependent
  forces take, in the same time loop). Ours is ``NeedleSimulation`` as the node drives it (a pose and ``advance``
  per 1 ms, reaction wrench included) and with the poses given first and 50 ms per ``advance_to`` (offline);
  MuJoCo is ``mj_step`` in a loop. Next to the node path, its compiled call alone (the one numba call per pose:
  base motion from the pose fit, step and wrench, its arguments' unboxing included, the Python around it not),
  and after the table the general path against MuJoCo in the same run and the floor of any call from Python
  into numba (one array argument). Time is this process's CPU time (both sides run on one thread): on a shared
  machine the time other processes or the hypervisor take is not charged to either side; each path's runs
  alternate between the two sides, the best run of each is reported. The host gauge (``host_gauge.py``) printed
  first reads the shared host's speed, for comparing runs of different moments.
* Accuracy: tip position under the needle's weight plus an 80 g tip mass against the exact elastica
  (``needle_sim_ros.experiments.elastica``, a shooting solution sharing no code with either model); MuJoCo's
  equilibrium is reached by running it with joint damping until it stops.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from numba import njit

import needle_sim_ros.stepper as stepper_module
from host_gauge import gauge_line
from needle_sim_ros.experiments.elastica import elastica
from needle_sim_ros.model import BaseMotion, Gravity, PointLoad, solve_static, tip_pose
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import NeedleSimulation, compile_kernels, simulation_from_parameters

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
LENGTH, RADIUS = PARAMETERS["needle.length"], PARAMETERS["needle.radius"]
YOUNGS_MODULUS, DENSITY = PARAMETERS["needle.youngs_modulus"], PARAMETERS["needle.density"]
SEGMENTS, DT, G = 10, 1e-3, 9.81
RELEASED_MASS, STATIC_MASS = 0.010, 0.080  # [kg]
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
CHUNK = 0.05  # [s] simulated per advance_to on the offline path (= loop.max_catch_up: nothing skipped)
CLOCK = time.process_time  # CPU time of this process (see the module docstring)


def mujoco_rod(mujoco, gravity: bool):
    """MuJoCo model and data of the needle as a clamped 1D flex along +x from the origin."""
    mass = DENSITY * np.pi * RADIUS ** 2 * LENGTH
    xml = f"""<mujoco>
  <option timestep="{DT}" gravity="0 0 {-G if gravity else 0.0}" integrator="discrete"/>
  <worldbody>
    <flexcomp name="needle" type="grid" dim="1" count="{SEGMENTS + 1} 1 1" spacing="{LENGTH / SEGMENTS} 1 1"
              pos="{LENGTH / 2} 0 0" radius="{RADIUS}" mass="{mass}">
      <edge equality="true" solref="{2 * DT} 1" solimp="0.9999 0.9999 0.001"/>
      <elasticity young="{YOUNGS_MODULUS}" poisson="0.3"/>
      <contact contype="0" conaffinity="0"/>
      <pin id="0 1"/>
    </flexcomp>
  </worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    return model, mujoco.MjData(model)


def mujoco_tip_body(mujoco, model) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"needle_{SEGMENTS}")


def mujoco_settle(mujoco, model, data, tip_load: float, seconds: float = 40.0) -> np.ndarray:
    """Run with joint damping and the tip load until at rest; returns the tip position."""
    tip = mujoco_tip_body(mujoco, model)
    data.xfrc_applied[tip, 2] = -tip_load
    damping = model.dof_damping.copy()
    model.dof_damping[:] = 0.02
    for _ in range(int(seconds / DT)):
        mujoco.mj_step(model, data)
    model.dof_damping[:] = damping
    speed = float(np.abs(data.qvel).max())
    if speed > 1e-6:
        print(f"warning: MuJoCo not at rest after {seconds:g} s (max |qvel| {speed:.1e})", file=sys.stderr)
    return data.xpos[tip].copy()


def mujoco_step_time(mujoco, gravity: bool, kept_load: float, at_mid: bool, seconds: float) -> float:
    """Mean time per mj_step after the 10 g tip load is released (or moved/kept as given)."""
    model, data = mujoco_rod(mujoco, gravity)
    mujoco_settle(mujoco, model, data, RELEASED_MASS * G)
    data.xfrc_applied[:] = 0.0
    if kept_load:
        body = (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"needle_{SEGMENTS // 2}") if at_mid
                else mujoco_tip_body(mujoco, model))
        data.xfrc_applied[body, 2] = -kept_load
    steps = int(seconds / DT)
    start = CLOCK()
    for _ in range(steps):
        mujoco.mj_step(model, data)
    per_step = (CLOCK() - start) / steps
    if not np.isfinite(data.qpos).all():
        raise RuntimeError("MuJoCo diverged")
    return per_step


def released_simulation(gravity: bool) -> NeedleSimulation:
    """The simulator at rest in equilibrium under the 10 g tip load, which is then released."""
    p = {**PARAMETERS, "needle.gravity": [0.0, 0.0, -G if gravity else 0.0],
         "loads.tip_force": [0.0, 0.0, -RELEASED_MASS * G]}
    sim = simulation_from_parameters(p)
    sim.offer_pose(0.0, np.zeros(3), IDENTITY)
    sim.advance(0.0, deterministic=False)
    sim.clear_point_loads()
    return sim


def simulator_step_time(gravity: bool, kept_load: float, at_mid: bool, seconds: float, batched: bool) -> float:
    """Mean time per 1 ms step of NeedleSimulation: one pose + advance per step (node), or the poses given
    first and 50 ms per advance_to (offline)."""
    sim = released_simulation(gravity)
    if kept_load:
        sim.set_point_load("bench", LENGTH / 2 if at_mid else LENGTH, np.array([0.0, 0.0, -kept_load]))
    steps = int(round(seconds / DT))
    start = CLOCK()
    if batched:
        for k in range(1, steps + 1):
            sim.offer_pose(k * DT, np.zeros(3), IDENTITY)
        for t in np.arange(1, int(round(seconds / CHUNK)) + 1) * CHUNK:
            sim.advance_to(float(t))
    else:
        for k in range(1, steps + 1):
            sim.offer_pose(k * DT, np.zeros(3), IDENTITY)
            sim.advance(k * DT, deterministic=True)
    per_step = (CLOCK() - start) / steps
    stats = sim.statistics
    if stats.failed_steps or stats.skipped_time or not np.isfinite(sim.state.q).all():
        raise RuntimeError("the simulator failed or skipped a step")
    if abs(sim.state.t - seconds) > 0.5 * DT:
        raise RuntimeError(f"the simulator reached {sim.state.t} s instead of {seconds} s")
    return per_step


def compiled_call_time(gravity: bool, kept_load: float, at_mid: bool, seconds: float) -> float:
    """Mean CPU time per step of the node path's compiled call alone (``compiled_advance.advance_from_trajectory``:
    the argument unboxing, the base motion from the pose fit and the step with its wrench), in a run as the node
    drives it (:func:`simulator_step_time`), without the Python around it."""
    spent = [0.0]
    inner = stepper_module.compiled_entry

    def timed_entry(*arguments):
        call = inner(*arguments)

        def timed(*arguments):
            start = CLOCK()
            result = call(*arguments)
            spent[0] += CLOCK() - start
            return result
        return timed
    stepper_module.compiled_entry = timed_entry
    try:
        simulator_step_time(gravity, kept_load, at_mid, seconds, False)
    finally:
        stepper_module.compiled_entry = inner
    return spent[0] / round(seconds / DT)


@njit
def _first(values):
    return values[0]


def dispatch_floor(calls: int = 100_000) -> float:
    """Mean CPU time of a numba call with one array argument returning one float: the least a call from Python
    into compiled code costs here (the dispatcher types the argument, unboxes it and boxes the result)."""
    values = np.zeros(3)
    _first(values)
    start = CLOCK()
    for _ in range(calls):
        _first(values)
    return (CLOCK() - start) / calls


def general_step_time(seconds: float) -> float:
    """Mean time per step of the general path (Integrator.step: full Newton, any force; reaction wrench
    included) after the release, the simulator's time loop kept off the compiled sequence."""
    released = released_simulation(True)
    base = BaseMotion(np.zeros(3), IDENTITY)
    sim = NeedleSimulation.prescribed(released.model, released.integrator, DT, lambda t: base, released.state)
    sim.compiled_sequence = False
    steps = int(seconds / DT)
    start = CLOCK()
    sim.advance_to(steps * DT)
    per_step = (CLOCK() - start) / steps
    if sim.statistics.steps != steps:
        raise RuntimeError(f"the general path did {sim.statistics.steps} steps instead of {steps}")
    return per_step


def static_errors(mujoco) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(exact elastica tip (x, z), our tip error (dx, dz), MuJoCo's tip error (dx, dz)) [m] at the 80 g case."""
    sim = simulation_from_parameters(PARAMETERS)
    props = sim.model.props
    exact = elastica(props.EI, LENGTH, props.mass_per_length * G, STATIC_MASS * G)[0]
    base = BaseMotion(np.zeros(3), IDENTITY)
    ours = solve_static(sim.model, base, [Gravity(), PointLoad(LENGTH, (0.0, 0.0, -STATIC_MASS * G))]).state
    ours_tip = tip_pose(sim.model, ours.q)[0]
    model, data = mujoco_rod(mujoco, True)
    theirs = mujoco_settle(mujoco, model, data, STATIC_MASS * G)
    return exact, ours_tip[[0, 2]] - exact, theirs[[0, 2]] - exact


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0, help="simulated time per timing run [s]")
    parser.add_argument("--repeats", type=int, default=3, help="timing runs per path (the best is reported)")
    args = parser.parse_args()
    if not (args.seconds >= 1.0 and args.repeats >= 1):
        parser.error("--seconds must be >= 1 and --repeats >= 1")
    try:
        import mujoco
    except ImportError:
        print("error: MuJoCo is not installed (benchmark-only dependency): pip install 'mujoco>=3.17'",
              file=sys.stderr)
        sys.exit(2)
    if tuple(int(part) for part in mujoco.__version__.split(".")[:2]) < (3, 17):
        print(f"error: MuJoCo {mujoco.__version__} has no bending for 1D flexes (added in 3.17): "
              "pip install -U 'mujoco>=3.17'", file=sys.stderr)
        sys.exit(2)
    print(f"MuJoCo {mujoco.__version__}; {SEGMENTS} elements / segments, dt = {DT * 1e3:g} ms\n{gauge_line()}\n")
    exact, ours, theirs = static_errors(mujoco)
    print(f"| 80 g tip mass + weight, static tip | x [mm] | z [mm] | error [mm] |\n|---|---|---|---|\n"
          f"| exact elastica | {exact[0] * 1e3:.3f} | {exact[1] * 1e3:.3f} | |\n"
          f"| needle_sim (ANCF) | {(exact[0] + ours[0]) * 1e3:.3f} | {(exact[1] + ours[1]) * 1e3:.3f} "
          f"| {np.linalg.norm(ours) * 1e3:.4f} |\n"
          f"| MuJoCo flex rod | {(exact[0] + theirs[0]) * 1e3:.3f} | {(exact[1] + theirs[1]) * 1e3:.3f} "
          f"| {np.linalg.norm(theirs) * 1e3:.4f} |\n"
          f"\nMuJoCo's error / ours: {np.linalg.norm(theirs) / np.linalg.norm(ours):.0f}x\n")

    paths = [("released 10 g, gravity", True, 0.0, False), ("released 10 g, no gravity", False, 0.0, False),
             ("10 g kept at the tip, gravity", True, RELEASED_MASS * G, False),
             ("10 g at mid-span, gravity", True, RELEASED_MASS * G, True)]
    print("| path | MuJoCo [us/step] | node: pose + advance per step [us] | speed vs MuJoCo "
          "| node's compiled call alone [us] | speed vs MuJoCo "
          "| offline: 50 ms per advance_to [us] | speed vs MuJoCo |\n|---|---|---|---|---|---|---|---|")
    compile_kernels(PARAMETERS)
    for name, gravity, load, at_mid in paths:
        runs = [(mujoco_step_time(mujoco, gravity, load, at_mid, args.seconds),
                 simulator_step_time(gravity, load, at_mid, args.seconds, False),
                 compiled_call_time(gravity, load, at_mid, args.seconds),
                 simulator_step_time(gravity, load, at_mid, args.seconds, True)) for _ in range(args.repeats)]
        theirs, node, call, offline = np.min(runs, axis=0)
        print(f"| {name} | {theirs * 1e6:.1f} | {node * 1e6:.1f} | {theirs / node:.2f}x | {call * 1e6:.1f} "
              f"| {theirs / call:.2f}x | {offline * 1e6:.1f} | {theirs / offline:.2f}x |")
    runs = [(mujoco_step_time(mujoco, True, 0.0, False, args.seconds), general_step_time(args.seconds))
            for _ in range(args.repeats)]
    theirs, general = np.min(runs, axis=0)
    print(f"\nGeneral path (Integrator.step, released 10 g, gravity): {general * 1e6:.1f} us/step, "
          f"{theirs / general:.2f}x MuJoCo ({theirs * 1e6:.1f} us/step in this run)")
    print(f"numba call floor (one array argument, one float returned): {dispatch_floor() * 1e6:.2f} us per call")


if __name__ == "__main__":
    main()
