"""``needle_batch sweep``: every bag x every parameter set of a grid, one offline pipeline run each, on the cluster."""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from needle_sim_ros.batch.bags import BagEntry, content_hash
from needle_sim_ros.batch.cluster import map_ordered
from needle_sim_ros.batch.grid import Grid, ParameterSet
from needle_sim_ros.batch.table import build_table, finished_rows, write_table
from needle_sim_ros.batch.task import TaskSpec, failed_row, run_row
from needle_sim_ros.parameters.experiment import experiments_dir

SAVE_EVERY_S = 10.0  # the partial table is rewritten at most this often while tasks finish (for --resume)


def experiment_path(entry: BagEntry, experiment: Path | None) -> str:
    """The bag's experiment file: the manifest's, else ``--experiment``, else ``<stem>.yaml`` of the installed
    experiments (:func:`experiments_dir`)."""
    if entry.experiment:
        return str(Path(entry.experiment).resolve())
    return str((experiment or experiments_dir() / f"{Path(entry.path).stem}.yaml").resolve())


def plan(client: Any, entries: list[BagEntry], parameter_sets: list[ParameterSet], experiment: Path | None,
         duration: float | None, quiet: bool = True) -> list[TaskSpec]:
    """Task specs, bag-major; the bags' content hashes are computed on the workers (they read the bags)."""
    hashes = map_ordered(client, content_hash, [e.path for e in entries], desc="hashing bags", quiet=quiet)
    return [TaskSpec(str(Path(e.path).resolve()) if Path(e.path).exists() else e.path, h,
                     experiment_path(e, experiment), p, duration, i)
            for e, h in zip(entries, hashes) for i, p in enumerate(parameter_sets)]


@dataclass
class SweepResult:
    table: pd.DataFrame
    ran: int
    reused: int


def run_sweep(client: Any, tasks: list[TaskSpec], grid: Grid, output_dir: Path, resume: bool = False,
              quiet: bool = False) -> SweepResult:
    """Run the tasks not finished before (``resume``: rows with status ok under the same key are reused) and write
    ``results.parquet``/``results.csv`` (also while running, at most every SAVE_EVERY_S)."""
    previous = finished_rows(output_dir) if resume else {}
    rows: list[dict[str, Any] | None] = [{**previous[task.key], "bag": task.bag} if task.key in previous else None
                                         for task in tasks]
    pending = [i for i, row in enumerate(rows) if row is None]
    last_save = time.monotonic()

    def save() -> None:
        done = [dict(r, parameter_set=tasks[i].parameter_set) for i, r in enumerate(rows) if r is not None]
        write_table(build_table(done, grid.parameter_sets, grid.columns), output_dir)

    def finished(index: int, row: dict[str, Any]) -> None:
        nonlocal last_save
        rows[pending[index]] = row
        if time.monotonic() - last_save > SAVE_EVERY_S:
            save()
            last_save = time.monotonic()

    map_ordered(client, run_row, [tasks[i] for i in pending], desc="needle_batch sweep", quiet=quiet,
                on_result=finished, on_error=failed_row)
    save()
    table = pd.read_parquet(output_dir / "results.parquet")
    return SweepResult(table, len(pending), len(tasks) - len(pending))
