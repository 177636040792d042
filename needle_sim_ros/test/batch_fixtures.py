"""Small synthetic insertion bags with known tissue parameters for the needle_batch tests (the bag generator of
:mod:`needle_sim_ros.experiments` with a truth model discretized like the pipeline's, so that only the tissue
parameters differ), and their experiment params files."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import yaml

from needle_sim_ros.experiments.ground_truth import TruthModel
from needle_sim_ros.experiments.make_bags import write_bag
from needle_sim_ros.experiments.protocols import Experiment, LinearInsertion

ENTRY_POINT = [0.272, 0.0, 0.0]  # 2 mm in front of the tip: the tip cuts early in a short bag
TRUE_TISSUE = {"tissue.layers.tip_stiffness": [1.2e4], "tissue.layers.friction_coulomb": [8.0]}
# The pipeline's model (config/needle_simulator.yaml: 10 elements, generalized-alpha rho_inf 0.8, dt 1 ms) with
# the experiment file's damping (alpha 10/s, beta 0). Both start at rest in static equilibrium (the simulator's
# default start), so the tip enters the tissue at rest: released straight, the needle would still swing by
# millimetres when it enters, and the response would jump with sub-percent parameter changes.
RAYLEIGH_ALPHA = 10.0
MATCHED_TRUTH = TruthModel(n_elements=10, rayleigh_alpha=RAYLEIGH_ALPHA, dt=1e-3, rho_inf=0.8)


def insertion_experiment(name: str, speed: float, distance: float) -> Experiment:
    motion = LinearInsertion(speed=speed, distance=distance, start=0.1, ramp=0.1)
    return Experiment(name=name, description=f"short insertion at {speed * 1e3:g} mm/s", duration=round(motion.end, 6),
                      base=motion, tissue=True, start_in_equilibrium=True, shape_sensor_rate=20.0)


def write_identification_bags(folder: Path) -> list[tuple[Path, Path]]:
    """Two short insertions (different speeds) into tissue with TRUE_TISSUE; returns (bag, experiment file)."""
    folder.mkdir(parents=True, exist_ok=True)
    truth = replace(MATCHED_TRUTH, tissue=tuple({"tissue.entry_point": ENTRY_POINT, **TRUE_TISSUE}.items()))
    pairs = []
    for name, speed, distance in (("slow", 0.01, 0.006), ("fast", 0.02, 0.010)):
        bag = folder / f"{name}.mcap"
        write_bag(insertion_experiment(name, speed, distance), bag, truth, log=lambda _: None)
        experiment = folder / f"{name}.yaml"
        experiment.write_text(yaml.safe_dump({
            "needle_simulator": {"ros__parameters": {
                "tissue.enable": True, "tissue.entry_point": ENTRY_POINT, "damping.rayleigh_alpha": RAYLEIGH_ALPHA,
                "damping.rayleigh_beta": 0.0, "rates.shape_hz": 50.0}},
            "needle_compare": {"ros__parameters": {"tolerance": 0.015, "model_frame": "world",
                                                   "measured_frame": "world"}},
            "needle_pipeline": {"ros__parameters": {"bag": str(bag), "stereo": False}}}))
        pairs.append((bag, experiment))
    return pairs
