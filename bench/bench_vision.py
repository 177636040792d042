"""Benchmark of needle_vision (issue #6): time per 1440x1080 stereo pair on one core, accuracy on clean
renders, and sensitivity to calibration error. Prints Markdown tables.

    source .venv/needle_env.sh && PYTHONPATH=needle_vision python bench/bench_vision.py [--quick]

Times are the minimum and the median over repetitions (the minimum is the machine's speed without
interference from other processes; the median includes it). Target: >= 220 pairs/s (the paper's camera rate).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "needle_vision" / "test"))
from conftest import SHAPES, distance_to_curve  # noqa: E402  (the tests' known needle shapes)

from needle_vision.centerline import extract_centerline  # noqa: E402
from needle_vision.pipeline import FrameStatus, StereoConfig, StereoNeedlePipeline  # noqa: E402
from needle_vision.reconstruction import reconstruct_centerline  # noqa: E402
from needle_vision.render import (NEEDLE_RADIUS, Imaging, default_rig, make_scene, render_background_pair,  # noqa: E402
                                  render_stereo_pair)
from needle_vision.sensitivity import simulate_checkerboard_calibration  # noqa: E402


def timed(function, repetitions: int) -> tuple[float, float]:
    """(min, median) wall time [ms] of ``function()``."""
    function()
    samples = []
    for _ in range(repetitions):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return 1e3 * min(samples), 1e3 * float(np.median(samples))


def ready_pipeline(rig, scene, imaging, frames: int = 10, measured_rig=None) -> StereoNeedlePipeline:
    pipeline = StereoNeedlePipeline(measured_rig or rig, StereoConfig(background_frames=frames), rig.world_from_left)
    for k in range(frames):
        frames_k = render_background_pair(rig, np.random.default_rng(1000 + k), scene=scene, imaging=imaging)
        pipeline.process(0.0, *frames_k)
    return pipeline


def rigid_residual(measured: np.ndarray, truth: np.ndarray) -> float:
    """RMS distance to the truth after the best rigid motion (Kabsch on closest points, iterated): the error a
    registration of the cameras to the world (e.g. hand-eye) would leave."""
    for _ in range(5):
        _, arc = distance_to_curve(measured, truth)
        cumulative = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(truth, axis=0), axis=1))])
        target = np.column_stack([np.interp(arc, cumulative, truth[:, k]) for k in range(3)])
        mu_m, mu_t = measured.mean(axis=0), target.mean(axis=0)
        u, _, vt = np.linalg.svd((measured - mu_m).T @ (target - mu_t))
        rotation = (u @ np.diag([1, 1, np.sign(np.linalg.det(u @ vt))]) @ vt).T
        measured = (measured - mu_m) @ rotation.T + mu_t
    return float(np.sqrt(np.mean(distance_to_curve(measured, truth)[0] ** 2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions and calibration seeds")
    arguments = parser.parse_args()
    repetitions, seeds = (50, 2) if arguments.quick else (300, 6)
    cv2.setNumThreads(1)  # one core
    rig = default_rig()
    scene = make_scene(rig, np.random.default_rng(0))
    imaging = Imaging()
    pipeline = ready_pipeline(rig, scene, imaging)
    renders = {name: render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(7), scene=scene)
               for name in ("straight", "planar", "3d", "hook")}

    print("## Time per 1440x1080 stereo pair (one core)\n")
    print("| shape | centerline, left image [ms] | correspondence + triangulation [ms] | whole pair [ms] "
          "| pairs/s (min / median) |")
    print("|---|---|---|---|---|")
    for name, (left, right) in renders.items():
        config = pipeline.config
        extract = timed(lambda: extract_centerline(left, pipeline.backgrounds[0], config.centerline), repetitions)
        centerlines = [extract_centerline(image, background, config.centerline)
                       for image, background in zip((left, right), pipeline.backgrounds)]
        triangulate = timed(lambda: reconstruct_centerline(*centerlines, pipeline.rectification, config.matching,
                                                           config.reconstruction, pipeline.output_from_left),
                            repetitions)
        whole = timed(lambda: pipeline.process(1.0, left, right), repetitions)
        print(f"| {name} | {extract[0]:.2f} / {extract[1]:.2f} | {triangulate[0]:.2f} / {triangulate[1]:.2f} "
              f"| {whole[0]:.2f} / {whole[1]:.2f} | {1e3 / whole[0]:.0f} / {1e3 / whole[1]:.0f} |")

    print("\n## Accuracy on clean renders (RMS / max distance to the true centerline, coverage of its length)\n")
    print("| shape | lens blur 0.5 px: RMS [mm] | max [mm] | coverage | no lens blur: RMS [mm] | max [mm] | coverage |")
    print("|---|---|---|---|---|---|---|")
    sharp = Imaging(blur_sigma_px=0.0)
    sharp_pipeline = ready_pipeline(rig, scene, sharp)
    cells = {}
    for name in renders:
        row = []
        sharp_images = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(7), scene=scene,
                                          imaging=sharp)
        for pipe, images in ((pipeline, renders[name]), (sharp_pipeline, sharp_images)):
            result = pipe.process(2.0, *images)
            if result.status is not FrameStatus.MEASURED:
                row += ["failed", result.reason, ""]
                continue
            distance, arc = distance_to_curve(result.measurement.points, SHAPES[name])
            length = np.linalg.norm(np.diff(SHAPES[name], axis=0), axis=1).sum()
            row += [f"{1e3 * np.sqrt(np.mean(distance ** 2)):.3f}", f"{1e3 * distance.max():.3f}",
                    f"{100 * (arc[-1] - arc[0]) / length:.1f} %"]
        cells[name] = row
        print(f"| {name} | " + " | ".join(row) + " |")

    print("\n## Sensitivity to calibration error (simulated checkerboard calibration, 25 views)\n")
    print("RMS distance [mm] to the true centerline in the world frame (absolute) and after the best rigid motion "
          "(what registering the cameras to the world would leave); true calibration for reference.\n")
    shapes = ("straight", "planar", "3d")
    print("| calibration | reprojection RMS [px] | " + " | ".join(f"{n} abs / rigid" for n in shapes) + " |")
    print("|---|---|---|---|---|")
    truth_rows = []
    for name in ("straight", "planar", "3d"):
        result = pipeline.process(3.0, *renders[name])
        truth_rows.append(f"{cells[name][0]} / {1e3 * rigid_residual(result.measurement.points, SHAPES[name]):.3f}")
    print("| true | 0 | " + " | ".join(truth_rows) + " |")
    for rms in (0.05, 0.14, 0.3):
        for seed in range(seeds if rms == 0.14 else 1):
            simulated = simulate_checkerboard_calibration(rig, np.random.default_rng(seed), reprojection_rms_px=rms)
            estimated = ready_pipeline(rig, scene, imaging, measured_rig=simulated.rig)
            row = []
            for name in ("straight", "planar", "3d"):
                result = estimated.process(3.0, *renders[name])
                if result.status is not FrameStatus.MEASURED:
                    row.append("failed")
                    continue
                points = result.measurement.points
                absolute = np.sqrt(np.mean(distance_to_curve(points, SHAPES[name])[0] ** 2))
                row.append(f"{1e3 * absolute:.3f} / {1e3 * rigid_residual(points, SHAPES[name]):.3f}")
            print(f"| simulated #{seed} | {simulated.rms_stereo:.3f} | " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
