"""Ground truth of the sample bags: a converged run of the ANCF model (seed 000, eqs. 1-20) with its own damping.

The "real needle" is the ANCF model discretized far beyond the simulator's settings (:class:`TruthModel`), checked
against the exact elastica at rest (:func:`static_check`), driven by the protocol's exact base motion (not the
recorded poses) and, for insertions, the default tissue. It is advanced by the simulator's one time loop
(:class:`needle_sim_ros.simulation.NeedleSimulation`, the general step throughout), so fixtures and the tissue's
per-step hooks behave as in the node; unlike the node it starts from static equilibrium when the protocol says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from needle_sim_ros.base_input import BaseInput
from needle_sim_ros.experiments.protocols import Experiment
from needle_sim_ros.experiments.elastica import elastica
from needle_sim_ros.model import (BaseMotion, Centerline, Fixture, Gravity, Integrator, ModelShape, NeedleProperties,
                                  PointLoad, StepFailed, build_model, solve_static)
from needle_sim_ros.simulation import NeedleSimulation
from needle_sim_ros.stepper import Stepper

TIP_WEIGHT = "tip_weight"


@dataclass(frozen=True)
class TruthModel:
    """How the ground truth differs from the pipeline's model (config/needle_simulator.yaml: 10 elements, Rayleigh
    alpha = 0, beta = 1e-4 s, dt = 1 ms, rho_inf = 0.8): 8x the elements, a 10x smaller step (converged: see
    ``static_check`` and bags/README.md), other (mass-proportional) damping, less numerical damping."""

    props: NeedleProperties = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)
    n_elements: int = 80
    rayleigh_alpha: float = 1.0  # [1/s]
    dt: float = 1e-4  # [s]
    rho_inf: float = 0.9
    tissue: tuple[tuple[str, object], ...] = ()  # tissue parameter overrides (simulator names), e.g. for identification


def static_check(truth: TruthModel, tip_masses=(0.0, 0.04, 0.08)) -> dict[str, float]:
    """Largest distance [m] of the truth model's tip at rest (own weight and tip masses [kg]) from the exact
    inextensible elastica (``experiments.elastica``, no ANCF code)."""
    props = truth.props
    model = build_model(props, n_elements=truth.n_elements)
    base = BaseMotion(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    g = -props.gravity[2]
    errors, previous = [], None
    for mass in tip_masses:
        forces = [Gravity(), PointLoad(props.length, (0.0, 0.0, -g * mass))]
        previous = solve_static(model, base, forces, initial=previous).state
        exact = elastica(props.EI, props.length, props.mass_per_length * g, g * mass)[0]
        errors.append(float(np.linalg.norm(previous.q[[-6, -4]] - exact)))
    return {"tip_masses_kg": list(tip_masses), "tip_error_m": errors}


@dataclass
class TruthSamples:
    """Samples of the ground-truth run: centerlines and tip poses at ``shape_times``, the base wrench (eq. 20,
    the needle on its holder, base frame) at ``wrench_times`` [s]."""

    shape_times: np.ndarray
    shapes: list[Centerline] = field(default_factory=list)
    tips: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    wrench_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    force_base: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    torque_base: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def truth_simulation(experiment: Experiment, truth: TruthModel) -> NeedleSimulation:
    """The truth's simulator, reset at the protocol's start pose (clamped there if the protocol clamps)."""
    def tissue_builder(model) -> list:
        from needle_sim_ros.tissue import build_tissue_model
        return [build_tissue_model({"tissue.enable": True, **dict(truth.tissue)}, model)]

    clamp = () if experiment.clamp_interval is None else (Fixture(interval=experiment.clamp_interval, frame="start"),)
    model = build_model(truth.props, n_elements=truth.n_elements, rayleigh_alpha=truth.rayleigh_alpha, fixtures=clamp)
    integrator = Integrator(model, method="generalized_alpha", rho_inf=truth.rho_inf)
    stepper = Stepper(model, integrator, truth.dt, tissue_builder if experiment.tissue else None,
                      restart_on_failure=False)
    simulation = NeedleSimulation(stepper, BaseInput(base_at=experiment.base), max_catch_up=math.inf)
    simulation.compiled_sequence = False  # full Newton every step: the bags' truth is reproduced bit for bit
    base = experiment.base(0.0)
    simulation.reset(base, 0.0)
    if experiment.start_in_equilibrium:
        force = experiment.tip_force(0.0)
        if np.any(force):
            simulation.set_point_load(TIP_WEIGHT, truth.props.length, force)
        simulation.start_from(solve_static(simulation.model, base, simulation.forces).state)
    return simulation


def run_ground_truth(experiment: Experiment, truth: TruthModel, shape_times, wrench_rate: float,
                     shape_samples: int = 541, progress: Callable[[float], None] | None = None) -> TruthSamples:
    """Integrate the protocol for its whole duration; sample shapes at ``shape_times`` (rounded to steps) and the
    wrench at ``wrench_rate`` [Hz]. ``progress(t)`` is called about every simulated 0.1 s."""
    dt = truth.dt
    n_steps = int(round(experiment.duration / dt))
    shape_steps = {int(round(t / dt)): i for i, t in enumerate(shape_times)}
    wrench_every = max(1, int(round(1.0 / (wrench_rate * dt))))
    simulation = truth_simulation(experiment, truth)
    shapes: dict[int, ModelShape] = {}
    wrench_times, forces, torques = [], [], []
    loaded = np.any([np.any(experiment.tip_force(t)) for t in np.linspace(0.0, experiment.duration, 50)])

    progress_every = max(1, int(round(0.1 / dt)))
    if loaded:  # the tip load changes every step: set it before each step
        events = range(1, n_steps + 1)
    else:
        events = sorted({*(k for k in shape_steps if 0 < k <= n_steps), n_steps,
                         *range(wrench_every, n_steps + 1, wrench_every),
                         *range(progress_every, n_steps + 1, progress_every)})
    if 0 in shape_steps:
        shapes[shape_steps[0]] = simulation.shape(shape_samples)
    for k in events:
        t = k * dt
        if loaded:
            simulation.set_point_load(TIP_WEIGHT, truth.props.length, experiment.tip_force(t))
        try:
            records = simulation.advance_to(t)
        except StepFailed as error:
            raise RuntimeError(f"ground truth of '{experiment.name}': step at t = "
                               f"{simulation.state.t + dt:.4f} s failed") from error
        for record in records:
            if round(record.t / dt) % wrench_every == 0:
                wrench_times.append(record.t)
                forces.append(record.wrench.force_base)
                torques.append(record.wrench.torque_base)
        if k in shape_steps:
            shapes[shape_steps[k]] = simulation.shape(shape_samples)
        if progress is not None and k % progress_every == 0:
            progress(t)
    ordered = [shapes[i] for i in range(len(shape_times))]
    return TruthSamples(np.asarray(shape_times, dtype=float), [shape.line for shape in ordered],
                        [(shape.tip_position, shape.tip_orientation) for shape in ordered], np.array(wrench_times),
                        np.array(forces).reshape(-1, 3), np.array(torques).reshape(-1, 3))
