"""Plots of a pipeline run (offline or live): model vs measured centerlines at chosen instants (in the style of
seed 000, Fig. 8), the comparison error over time, and the base wrench over time. Written as PNG (matplotlib Agg).
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from needle_sim_ros.offline.results import PipelineLog
from needle_sim_ros.scenarios.common import pyplot, save_figure


def chosen_measurements(log: PipelineLog, instants: Sequence[float], count: int = 5) -> list[int]:
    """Indices of the compared measurements nearest to ``instants`` [s from the bag start] (without repeats);
    with no instants, ``count`` spread evenly over the run."""
    if not len(log.error_times):
        return []
    times = log.seconds(log.error_times)
    if not instants:
        return sorted(set(np.linspace(0, len(times) - 1, min(count, len(times))).round().astype(int).tolist()))
    return sorted({int(np.argmin(np.abs(times - t))) for t in instants})


def plot_centerlines(log: PipelineLog, instants: Sequence[float], path: Path, title: str = "") -> Path:
    """Side view (world x-z, z up) of the model centerline (line), the measurement (dots) and, for synthetic bags,
    the ground truth (dashed) at the chosen instants."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 5))
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, max(1, len(instants) or 5)))
    for colour, index in zip(colours, chosen_measurements(log, instants)):
        measured_ns, model_ns = int(log.error_times[index]), int(log.model_times[index])
        label = f"t = {log.seconds(measured_ns):.2f} s (RMSE {log.rmse[index] * 1e3:.3f} mm)"
        model = log.model_shapes.get(model_ns)
        if model is not None:
            ax.plot(model[:, 0] * 1e3, model[:, 2] * 1e3, "-", color=colour, lw=1.5, label=f"model, {label}")
        measured = log.measured_shapes.get(measured_ns)
        if measured is not None:
            step = max(1, len(measured) // 40)
            ax.plot(measured[::step, 0] * 1e3, measured[::step, 2] * 1e3, "o", color=colour, ms=3.5, mfc="none")
        truth = log.truth_shapes.get(measured_ns)
        if truth is not None:
            ax.plot(truth[:, 0] * 1e3, truth[:, 2] * 1e3, "--", color="0.4", lw=0.8)
    ax.plot([], [], "o", color="0.3", mfc="none", label="measured (every ~40th sample)")
    if log.truth_shapes:
        ax.plot([], [], "--", color="0.4", lw=0.8, label="ground truth (synthetic bag)")
    ax.set(xlabel="x [mm] (world)", ylabel="z [mm] (world, up)",
           title=title or "needle centerline: model vs measurement")
    ax.grid(True, alpha=0.4)
    ax.legend(fontsize=7, loc="best")
    return save_figure(fig, path)


def plot_errors(log: PipelineLog, path: Path, title: str = "") -> Path:
    """RMSE, largest sample error and tip error of every comparison over time [mm]."""
    fig, ax = pyplot().subplots(figsize=(9, 4))
    t = log.seconds(log.error_times)
    for values, style, label in ((log.rmse, "o-", "RMSE"), (log.max_error, "s--", "largest sample error"),
                                 (log.tip_error, "^:", "tip error")):
        ax.plot(t, values * 1e3, style, ms=3.5, label=label)
    ax.set(xlabel="time [s] from the bag start", ylabel="error [mm]", title=title or "model vs measurement")
    ax.grid(True, alpha=0.4)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_wrench(log: PipelineLog, path: Path, title: str = "") -> Path:
    """Force and torque of the needle on its holder (base frame) over time; the ground truth dashed if known."""
    fig, axes = pyplot().subplots(2, 1, figsize=(9, 6), sharex=True)
    for series, style, prefix in ((log.wrench, "-", "model "), (log.truth_wrench, "--", "ground truth ")):
        if series is None:
            continue
        t = log.seconds(series.times)
        for axis, values, unit in ((axes[0], series.force, "F"), (axes[1], series.torque, "M")):
            for k, (component, colour) in enumerate(zip("xyz", ("C0", "C1", "C2"))):
                axis.plot(t, values[:, k], style, color=colour, lw=1.0 if style == "-" else 0.8,
                          label=f"{prefix}{unit}{component}")
    axes[0].set(ylabel="force [N]", title=title or "wrench of the needle on its holder (base frame)")
    axes[1].set(ylabel="torque [N m]", xlabel="time [s] from the bag start")
    for axis in axes:
        axis.grid(True, alpha=0.4)
        axis.legend(fontsize=7, ncol=2, loc="best")
    return save_figure(fig, path)


def write_plots(log: PipelineLog, directory: Path, instants: Sequence[float] = (), title: str = "") -> list[Path]:
    """All three plots into ``directory``; returns their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    prefix = f"{title}: " if title else ""
    return [plot_centerlines(log, instants, directory / "centerlines.png", f"{prefix}model vs measured centerlines"),
            plot_errors(log, directory / "error_vs_time.png", f"{prefix}model vs measurement error"),
            plot_wrench(log, directory / "wrench_vs_time.png", f"{prefix}wrench on the holder (base frame)")]
