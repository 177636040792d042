"""Ground truth of the sample bags: a finer, differently damped run of the same ANCF model (seed 000, eqs. 1-20).

The "real needle" of the synthetic experiments is the simulator's own model with other discretization and damping
settings (:class:`TruthModel`), driven by the exact base motion of the protocol (analytic pose, velocity and
acceleration, not the recorded poses) and, for the insertion, by the tissue models with their default parameters.
It is stepped by :class:`needle_sim_ros.simulation.NeedleSimulation`, like the simulator node, so fixtures and the
tissue models' per-step hooks behave the same. Unlike the node, it starts from static equilibrium (the real needle
hangs at rest when the recording starts) when the protocol says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from needle_sim_ros.base_trajectory import BaseTrajectory
from needle_sim_ros.experiments.protocols import Experiment
from needle_sim_ros.model import Centerline, Integrator, NeedleProperties, build_model, solve_static
from needle_sim_ros.simulation import NeedleSimulation

TIP_WEIGHT = "tip_weight"


@dataclass(frozen=True)
class TruthModel:
    """How the ground truth differs from the pipeline's model (config/needle_simulator.yaml: 10 elements, Rayleigh
    alpha = 0, beta = 1e-4 s, dt = 1 ms, rho_inf = 0.8): twice the elements, other (mass-proportional) damping,
    half the step, less numerical damping."""

    props: NeedleProperties = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)
    n_elements: int = 20
    rayleigh_alpha: float = 1.0  # [1/s]
    dt: float = 5e-4  # [s]
    rho_inf: float = 0.9
    tissue: tuple[tuple[str, object], ...] = ()  # tissue parameter overrides (simulator names), e.g. for identification


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
    def model_builder(fixtures: tuple) -> tuple:
        model = build_model(truth.props, n_elements=truth.n_elements, rayleigh_alpha=truth.rayleigh_alpha,
                            fixtures=fixtures)
        return model, Integrator(model, method="generalized_alpha", rho_inf=truth.rho_inf)

    def tissue_builder(model) -> list:
        from needle_sim_ros.tissue import build_tissue_forces
        return build_tissue_forces({"tissue.enable": True, **dict(truth.tissue)}, model)

    model, integrator = model_builder(())
    simulation = NeedleSimulation(model, integrator, truth.dt, BaseTrajectory(),
                                  extra_forces_builder=tissue_builder if experiment.tissue else None,
                                  max_catch_up=math.inf, clamp_interval=experiment.clamp_interval,
                                  model_builder=model_builder)
    base = experiment.base(0.0)
    simulation.reset(base, 0.0)
    if experiment.start_in_equilibrium:
        force = experiment.tip_force(0.0)
        if np.any(force):
            simulation.set_point_load(TIP_WEIGHT, truth.props.length, force)
        simulation.state = solve_static(simulation.model, base, simulation.forces).state
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
    samples = TruthSamples(np.asarray(shape_times, dtype=float))
    shapes: dict[int, tuple] = {}
    wrench_times, forces, torques = [], [], []
    loaded = np.any([np.any(experiment.tip_force(t)) for t in np.linspace(0.0, experiment.duration, 50)])

    def sample_shape(index: int) -> None:
        shapes[index] = (simulation.shape(shape_samples), simulation.tip())

    if 0 in shape_steps:
        sample_shape(shape_steps[0])
    for k in range(1, n_steps + 1):
        t = k * dt
        if loaded:
            simulation.set_point_load(TIP_WEIGHT, truth.props.length, experiment.tip_force(t))
        record = simulation.step(experiment.base(t), t)
        if simulation.statistics.failed_steps:
            raise RuntimeError(f"ground truth of '{experiment.name}': step at t = {t:.4f} s failed")
        if k % wrench_every == 0:
            wrench_times.append(t)
            forces.append(record.wrench.force_base)
            torques.append(record.wrench.torque_base)
        if k in shape_steps:
            sample_shape(shape_steps[k])
        if progress is not None and k % max(1, int(round(0.1 / dt))) == 0:
            progress(t)
    samples.shapes = [shapes[i][0] for i in range(len(shape_times))]
    samples.tips = [shapes[i][1] for i in range(len(shape_times))]
    samples.wrench_times = np.array(wrench_times)
    samples.force_base, samples.torque_base = np.array(forces).reshape(-1, 3), np.array(torques).reshape(-1, 3)
    return samples
