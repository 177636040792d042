"""The results table of a sweep: one row per (bag, parameter set), written as Parquet and CSV (atomically)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from needle_common.output_files import write_atomically

from needle_sim_ros.batch.grid import ParameterSet, column
from needle_sim_ros.batch.task import METRICS

TAIL = ("wall_s", "status", "error")


def cell(value: Any) -> Any:
    """A parameter value as a table cell: numbers and strings as they are, arrays as JSON text."""
    return json.dumps(value) if isinstance(value, (list, tuple, dict)) else value


def build_table(rows: list[dict[str, Any]], parameter_sets: list[ParameterSet], columns: list[str]) -> pd.DataFrame:
    """Rows (``parameter_set`` index added by the caller) with one column per swept parameter, in a fixed order."""
    records = []
    for row in rows:
        parameters = parameter_sets[row["parameter_set"]]
        values = {column(node, name): cell(v) for node, items in parameters.items() for name, v in items.items()}
        records.append({"bag": row["bag"], "parameter_set": row["parameter_set"],
                        **{c: values.get(c) for c in columns}, **{m: row.get(m) for m in METRICS},
                        **{t: row.get(t) for t in TAIL}, "key": row["key"]})
    table = pd.DataFrame.from_records(records, columns=["bag", "parameter_set", *columns, *METRICS, *TAIL, "key"])
    table["compared"] = table["compared"].astype("Int64")
    return table


def write_table(table: pd.DataFrame, output_dir: Path) -> tuple[Path, Path]:
    """``results.parquet`` and ``results.csv`` (unavailable values: null / empty cells)."""
    output_dir.mkdir(parents=True, exist_ok=True)
    parquet, csv = output_dir / "results.parquet", output_dir / "results.csv"
    write_atomically(parquet, lambda p: table.to_parquet(p, index=False))
    write_atomically(csv, lambda p: table.to_csv(p, index=False, na_rep=""))
    return parquet, csv


def finished_rows(output_dir: Path) -> dict[str, dict[str, Any]]:
    """Rows with status ok of a previous run in ``output_dir``, by task key (for ``--resume``)."""
    path = output_dir / "results.parquet"
    if not path.is_file():
        return {}
    previous = pd.read_parquet(path)
    previous = previous[previous["status"] == "ok"].astype(object).where(previous.notna(), None)
    return {row["key"]: row for row in previous.to_dict("records")}


def numeric_axis(series: pd.Series) -> pd.Series | None:
    """A swept column as numbers for plots: scalars, or the single element of one-element arrays; else None."""
    def number(value: Any) -> float | None:
        if isinstance(value, str):
            try:
                value = json.loads(value)
            except ValueError:
                return None
            value = value[0] if isinstance(value, list) and len(value) == 1 else value
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None
    values = series.map(number)
    return None if values.isna().all() or values.isna().any() else values.astype(float)

