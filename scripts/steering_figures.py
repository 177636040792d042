#!/usr/bin/env python3
"""Figures and tables of the README's steering validation (issue #13), from the same runs as the tests:

* tip deflection against depth, dynamic ANCF against the independent Winkler reference (seed 001 Fig. 4 style),
  with a 180 deg base roll at 45 mm as a second case;
* path curvature against the duty cycle of duty-cycled spinning, against (1 - d) (Minhas et al. 2007).

    python scripts/steering_figures.py [--output-dir docs/figures]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "needle_sim_ros" / "test"))

from reference_winkler import plot_tip_deflection, reference_insertion  # noqa: E402
from test_tissue_reference_insertion import CASE, ancf_insertion  # noqa: E402
from test_tissue_steering import curvature, run  # noqa: E402

from needle_sim_ros.scenarios.common import figure, save_figure  # noqa: E402


def deflection_figure(output: Path) -> None:
    reference = reference_insertion(CASE)
    rolled_reference = reference_insertion(CASE, roll_depth=0.045)
    ancf = ancf_insertion()
    roll_time = (0.045 + 2e-3) / CASE.insertion_speed             # the tip starts 2 mm before the surface
    rolled = ancf_insertion(roll_changes=((roll_time, 0.05, np.pi),))
    print("depth [mm] | ANCF [mm] | reference [mm] | error | rolled 180 deg at 45 mm: ANCF | reference")
    for depth in (0.03, 0.06, 0.09):
        values = [np.interp(depth, result["insertion_depth_m"], np.asarray(result["tip_offset_m"])[:, 0])
                  for result in (ancf, rolled)]
        truths = [np.interp(depth, r.depth, r.tip_deflection[:, 0]) for r in (reference, rolled_reference)]
        print(f"{depth * 1e3:.0f} | {values[0] * 1e3:.4f} | {truths[0] * 1e3:.4f} | "
              f"{(values[0] / truths[0] - 1) * 100:+.2f} % | {values[1] * 1e3:.4f} | {truths[1] * 1e3:.4f}")
    plot_tip_deflection(str(output), reference.depth, reference.tip_deflection[:, 0],
                        label="Winkler reference (quasi-static)", overlays=(
                            (np.asarray(ancf["insertion_depth_m"]), np.asarray(ancf["tip_offset_m"])[:, 0],
                             "ANCF, dynamic, 10 elements"),
                            (rolled_reference.depth, rolled_reference.tip_deflection[:, 0],
                             "Winkler reference, rolled 180 deg at 45 mm"),
                            (np.asarray(rolled["insertion_depth_m"]), np.asarray(rolled["tip_offset_m"])[:, 0],
                             "ANCF, rolled 180 deg at 45 mm")))


def duty_cycle_figure(output: Path) -> None:
    duty_cycles = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
    kappa = np.array([curvature(run(spin_rate=4 * np.pi, duty_cycle=d) if d else run()) for d in duty_cycles])
    print("duty cycle | curvature [1/m] | kappa(d) / kappa(0) | 1 - d")
    for d, k in zip(duty_cycles, kappa):
        print(f"{d:.2f} | {k:.4f} | {k / kappa[0]:.3f} | {1 - d:.2f}")
    fig, (ax,) = figure(1, size=(5.0, 3.6))
    ax.plot(duty_cycles, kappa / kappa[0], "o-", label="ANCF + path-memory tissue")
    ax.plot(duty_cycles, 1 - duty_cycles, "k:", label="1 - d (Minhas et al. 2007)")
    ax.set_xlabel("duty cycle d")
    ax.set_ylabel("path curvature / curvature without spinning")
    ax.grid(True)
    ax.legend(fontsize=8)
    save_figure(fig, output)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output-dir", type=Path, default=REPO / "docs" / "figures")
    args = parser.parse_args()
    args.output_dir.mkdir(parents=True, exist_ok=True)
    deflection_figure(args.output_dir / "insertion_vs_reference.png")
    duty_cycle_figure(args.output_dir / "duty_cycle.png")
    print(f"figures in {args.output_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
