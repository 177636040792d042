"""Outputs of ``needle_batch identify``: the report (JSON), the fit history (CSV) and a params file the simulator
loads (``--params-file``), each written under a temporary name and renamed."""
from __future__ import annotations

import csv
import io
import json
from dataclasses import asdict
from pathlib import Path

from needle_common.output_files import write_atomically
from needle_common.parameters import params_file_text

from needle_sim_ros.batch.identify import FitParameter, FitResult, fitted_set
from needle_sim_ros.batch.task import TaskSpec, resolved_overrides
from needle_sim_ros.parameters.experiment import load_experiment


def _write(path: Path, text: str) -> None:
    write_atomically(path, lambda temporary: temporary.write_text(text))


def identified_params_text(fits: list[FitParameter], result: FitResult, reference: TaskSpec) -> str:
    """A ROS 2 params file with the estimate; an element ``name[i]`` is written as the whole array (the other
    elements as the reference bag's experiment has them)."""
    overrides = resolved_overrides(load_experiment(reference.experiment), fitted_set(fits, result.estimate))
    header = "".join(f"# {f.label} = {v:.6g} +- {s:.2g} (1 sigma)\n" for f, v, s in
                     zip(fits, result.estimate, result.std))
    return "# Identified by needle_batch identify.\n" + header + params_file_text(overrides)


def write_identification(output_dir: Path, fits: list[FitParameter], result: FitResult,
                         reference: TaskSpec) -> dict[str, Path]:
    output_dir.mkdir(parents=True, exist_ok=True)
    files = {"report": output_dir / "identification.json", "history": output_dir / "fit_history.csv",
             "params": output_dir / "identified_params.yaml"}
    report = {k: v for k, v in asdict(result).items() if k != "history"}
    report["parameters"] = [f.label for f in fits]
    report["initial"] = [f.initial for f in fits]
    report["per_bag"] = [{"bag": b, "rms_initial": i, "rms_final": f}
                         for b, i, f in zip(result.bags, result.bag_rms_initial, result.bag_rms_final)]
    _write(files["report"], json.dumps(report, indent=2) + "\n")
    stream = io.StringIO()
    writer = csv.writer(stream)
    writer.writerow(["evaluation", "kind", *(f.label for f in fits), "cost", *(f"rms:{b}" for b in result.bags)])
    for k, e in enumerate(result.history):
        writer.writerow([k, e.kind, *e.parameters, e.cost, *e.bag_rms])
    _write(files["history"], stream.getvalue())
    _write(files["params"], identified_params_text(fits, result, reference))
    return files
