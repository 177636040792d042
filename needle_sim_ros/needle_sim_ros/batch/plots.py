"""Plots of a sweep: each error metric against each swept parameter, per bag and pooled over the bags."""
from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

from needle_sim_ros.batch.table import numeric_axis

PLOTTED = {"rmse_mean_m": ("shape RMSE mean [mm]", 1e3), "tip_error_mean_m": ("tip error mean [mm]", 1e3),
           "wrench_force_rms_n": ("wrench force error RMS [N]", 1.0)}


def write_sweep_plots(table: pd.DataFrame, columns: list[str], folder: Path) -> tuple[list[Path], list[str]]:
    """One PNG per swept parameter (a row of metrics; per bag: lines, averaged over the other parameters' values;
    pooled: mean over bags with min-max band); returns the files and notes on parameters that could not be plotted."""
    from needle_sim_ros.scenarios.common import pyplot, save_figure
    folder.mkdir(parents=True, exist_ok=True)
    ok = table[table["status"] == "ok"]
    files, notes = [], []
    metrics = [m for m in PLOTTED if ok[m].notna().any()]
    for name in columns:
        rows = ok[ok[name].notna()]  # the sets that give this parameter
        axis = numeric_axis(rows[name]) if len(rows) else None
        if axis is None or not metrics:
            notes.append(f"'{name}': not plotted (no finished rows, or values are not numbers)")
            continue
        figure, axes = pyplot().subplots(2, len(metrics), figsize=(4.5 * len(metrics), 6.5), squeeze=False)
        data = rows.assign(_x=axis)
        for j, metric in enumerate(metrics):
            label, scale = PLOTTED[metric]
            for bag, rows in data.groupby("bag", sort=True):
                mean = rows.groupby("_x")[metric].mean().dropna()
                axes[0, j].plot(mean.index, mean.to_numpy(dtype=float) * scale, "o-", label=Path(bag).stem)
            pooled = data.groupby("_x")[metric].agg(["mean", "min", "max"]).dropna()
            axes[1, j].plot(pooled.index, pooled["mean"] * scale, "ko-", label="mean over bags")
            axes[1, j].fill_between(pooled.index, pooled["min"] * scale, pooled["max"] * scale, alpha=0.2,
                                    color="k", label="min-max")
            for row, title in ((0, "per bag"), (1, "pooled")):
                axes[row, j].set(xlabel=name, ylabel=label, title=title)
                axes[row, j].grid(True, alpha=0.3)
        axes[0, 0].legend(fontsize=7)
        axes[1, 0].legend(fontsize=7)
        files.append(save_figure(figure, folder / f"{re.sub(r'[^A-Za-z0-9_.-]+', '_', name)}.png", dpi=90))
    return files, notes
