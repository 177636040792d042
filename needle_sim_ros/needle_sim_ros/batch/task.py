"""One batch task on a worker: the offline pipeline (as ``needle_offline`` runs it) over one bag with one parameter
set, reduced to a table row or a residual vector. Only paths and parameters travel through the scheduler; a failing
task returns a row with ``status = failed`` and a one-line message, so one bad bag never aborts a batch.
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from needle_common.cli_types import one_line

from needle_sim_ros.batch.grid import SPECS, ParameterSet, canonical, split_index
from needle_sim_ros.comparison.centerline_distance import closest_points_on_polyline
from needle_sim_ros.parameters.experiment import ExperimentConfig, load_experiment
from needle_sim_ros.offline.pipeline import OfflinePipeline
from needle_sim_ros.offline.results import PipelineLog, wrench_differences, wrench_versus_reference

METRICS = ("rmse_mean_m", "rmse_max_m", "tip_error_mean_m", "wrench_force_rms_n", "wrench_moment_rms_nm",
           "compared")


@dataclass(frozen=True)
class TaskSpec:
    """What a worker needs: the bag and experiment paths, the overrides and the bag slice."""

    bag: str
    bag_hash: str
    experiment: str
    parameters: ParameterSet
    duration: float | None = None
    parameter_set: int = 0  # index in the grid (a table column, not part of the key)

    @property
    def key(self) -> str:
        """Resume key: bag content hash + parameter set (+ experiment file and slice)."""
        text = f"{self.bag_hash}|{canonical(self.parameters)}|{self.experiment}|{self.duration}"
        return hashlib.sha256(text.encode()).hexdigest()[:24]


def resolved_overrides(experiment: ExperimentConfig, parameters: ParameterSet) -> dict[str, dict[str, Any]]:
    """Per-node overrides with ``name[i]`` entries written into a copy of the experiment's array."""
    result: dict[str, dict[str, Any]] = {}
    for node, values in parameters.items():
        plain = {n: v for n, v in values.items() if split_index(n)[1] is None}
        base = experiment.values(node, plain)
        for name, value in values.items():
            array_name, index = split_index(name)
            if index is None:
                continue
            array = list(plain.get(array_name, base.get(array_name, SPECS[node][array_name].default)))
            if index >= len(array):
                raise ValueError(f"{node}: '{name}' is out of range: '{array_name}' has {len(array)} element(s)")
            array[index] = value
            plain[array_name] = array
        result[node] = plain
    return result


def run_pipeline(spec: TaskSpec) -> tuple[dict[str, Any], PipelineLog, OfflinePipeline]:
    """The offline pipeline over the task's bag (no MCAP written); returns its summary, its log and the pipeline."""
    if not Path(spec.bag).exists():
        raise FileNotFoundError(f"bag '{spec.bag}' does not exist")
    experiment = load_experiment(spec.experiment)
    pipeline = OfflinePipeline(experiment, resolved_overrides(experiment, spec.parameters))
    run = pipeline.run(Path(spec.bag), None, 0.0, spec.duration)
    return run.summary, run.log, pipeline


def error_line(_: Any, error: BaseException) -> str:
    """``Type: message`` of a task's error on one line (also of a task whose worker died: ``map_ordered``'s
    ``on_error``)."""
    return f"{type(error).__name__}: {one_line(error)}"


def failed_row(spec: TaskSpec, error: BaseException, wall_s: float = 0.0) -> dict[str, Any]:
    return {"bag": spec.bag, "key": spec.key, **dict.fromkeys(METRICS), "status": "failed",
            "error": error_line(spec, error), "wall_s": wall_s}


def run_row(spec: TaskSpec) -> dict[str, Any]:
    """The table row of a task: metrics (None where unavailable), wall time, status and error message."""
    start = time.perf_counter()
    try:
        summary, log, _ = run_pipeline(spec)
        c, wrench = summary["comparison"], wrench_versus_reference(log)
        return {"bag": spec.bag, "key": spec.key, "rmse_mean_m": c["rmse_mean_m"], "rmse_max_m": c["rmse_max_m"],
                "tip_error_mean_m": c["tip_error_mean_m"], "wrench_force_rms_n": wrench["wrench_force_rms_n"],
                "wrench_moment_rms_nm": wrench["wrench_torque_rms_nm"], "compared": int(c["compared"]),
                "status": "ok", "error": "", "wall_s": time.perf_counter() - start}
    except Exception as error:  # noqa: BLE001 - any failure of one task becomes its row
        return failed_row(spec, error, time.perf_counter() - start)


@dataclass(frozen=True)
class ResidualScales:
    """Scales that make the residuals dimensionless: shape [m], force [N], moment [N m]."""

    shape: float = 1e-4
    force: float = 1e-2
    moment: float = 1e-3


def run_residuals(spec: TaskSpec, scales: ResidualScales) -> np.ndarray:
    """Signed residual vector of a bag: per compared measurement, each measured sample (in the model frame) minus
    its closest point on the paired model centerline / ``scales.shape``; then model minus reference force and
    moment at the reference stamps / their scales (if the bag has a reference wrench)."""
    _, log, pipeline = run_pipeline(spec)
    model_from_camera = pipeline.comparison.session.model_from_camera
    parts = []
    for measured_ns, model_ns in zip(log.error_times, log.model_times):
        measured = model_from_camera.apply(log.measured_shapes[int(measured_ns)])
        closest = closest_points_on_polyline(measured, log.model_shapes[int(model_ns)])
        parts.append((measured - closest.point).ravel() / scales.shape)
    differences = wrench_differences(log)
    if differences is not None:
        parts += [differences[0].ravel() / scales.force, differences[1].ravel() / scales.moment]
    if not parts:
        raise ValueError(f"bag '{spec.bag}': nothing compared and no reference wrench: no residuals")
    return np.concatenate(parts)
