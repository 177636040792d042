"""Benchmark of needle_vision (issues #6, #16, #39): end-to-end throughput of needle_stereo_offline on image folders
and MCAP bags next to its stages (decoding, measurement, the optional curve fit), time per 1440x1080 stereo pair on
one core, accuracy on clean renders and on needles along the epipolar lines (per-point triangulation against the
curve fitted to both views, with the calibration of their uncertainty), and sensitivity to calibration error.
Prints Markdown tables.

    source .venv/needle_env.sh && PYTHONPATH=needle_vision python bench/bench_vision.py [--quick] [--only-throughput]
    ... bench/bench_vision.py --only-throughput --params fit.yaml  (end to end with a params file, e.g. curve_fit)
    ... bench/bench_vision.py --only-epipolar [--seeds 7,1007,2007]

Times are the minimum and the median over repetitions (the minimum is the machine's speed without
interference from other processes; the median includes it). Targets: >= 220 pairs/s per pair on one core (the
paper's camera rate), >= 200 pairs/s end to end on 2 cores.
"""
from __future__ import annotations

import argparse
import contextlib
from dataclasses import replace
import io
import os
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "needle_vision" / "test"))
from vision_shapes import (EPIPOLAR_SHAPES, ROD_EPIPOLAR_SHAPES, SHAPES, background_models, bright_scene,  # noqa: E402
                           distance_to_curve)

from needle_vision.calibration.rectification import Rectification  # noqa: E402
from needle_vision.calibration.rig import camera_calibration_yaml  # noqa: E402
from needle_vision.detection.background import ContrastThreshold  # noqa: E402
from needle_vision.detection.centerline import extract_centerline  # noqa: E402
from needle_vision.offline import decoded, open_source  # noqa: E402
from needle_vision.streams.image_codec import compress_image, compressed_to_gray  # noqa: E402
from needle_vision.offline import main as offline_main  # noqa: E402
from needle_vision.pipeline import FrameStatus, StereoConfig, StereoNeedlePipeline  # noqa: E402
from needle_vision.matching.correspondence import MatchingConfig  # noqa: E402
from needle_vision.matching.reconstruction import (ReconstructionConfig, order_and_resample,  # noqa: E402
                                                   reconstruct_centerline, triangulate_centerline)
from needle_vision.render import (NEEDLE_RADIUS, Imaging, default_rig, make_scene,  # noqa: E402
                                  render_background_pair, render_stereo_pair)
from board_render import simulate_checkerboard_calibration  # noqa: E402  (the calibration tests' boards)


def timed(function, repetitions: int, clock=time.perf_counter) -> tuple[float, float]:
    """(min, median) time [ms] of ``function()``: wall time, or with ``clock=time.thread_time`` the CPU time on the
    calling thread (independent of other processes' load)."""
    function()
    samples = []
    for _ in range(repetitions):
        start = clock()
        function()
        samples.append(clock() - start)
    return 1e3 * min(samples), 1e3 * float(np.median(samples))


def stage_cpu(pipeline: StereoNeedlePipeline, pairs: list[tuple[np.ndarray, np.ndarray]], repetitions: int) -> str:
    """CPU time per pair [ms] of the measurement's stages on one thread, as a Markdown sentence."""
    config = pipeline.config
    centerlines = [[extract_centerline(image, background, config.centerline)
                    for image, background in zip(pair, pipeline.backgrounds)] for pair in pairs]
    triangulations = [triangulate_centerline(*both, pipeline.rectification, config.matching, config.reconstruction,
                                             pipeline.output_from_left) for both in centerlines]
    stages = {
        "centerlines (2 images)": lambda: [extract_centerline(image, background, config.centerline)
                                           for pair in pairs for image, background in zip(pair, pipeline.backgrounds)],
        "matching + triangulation": lambda: [triangulate_centerline(*both, pipeline.rectification, config.matching,
                                                                    config.reconstruction, pipeline.output_from_left)
                                             for both in centerlines],
        "ordering + resampling": lambda: [order_and_resample(triangulation, pipeline.rectification,
                                                             config.reconstruction, pipeline.output_from_left)
                                          for triangulation in triangulations],
        "whole pair (process)": lambda: [pipeline.process(1.0, *pair) for pair in pairs]}
    times = {name: timed(stage, repetitions, time.thread_time)[1] / len(pairs) for name, stage in stages.items()}
    fit = replace(config.reconstruction, curve_fit=True)
    cost = timed(lambda: [reconstruct_centerline(*both, pipeline.rectification, config.matching, fit,
                                                 pipeline.output_from_left) for both in centerlines], repetitions,
                 time.thread_time)[1] / len(pairs) - times["matching + triangulation"] - times["ordering + resampling"]
    return ", ".join(f"{name} {value:.2f}" for name, value in times.items()) + \
        f"; the curve fit's cost (reconstruction with it less without) {cost:.2f}"


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


def write_inputs(root: Path, rig, pairs: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, list[str]]:
    """The same pairs as image folders (PNG as cv2.imwrite writes it, PNG without compression, BMP) and as MCAP
    bags (raw Image messages, zstd chunks or uncompressed; PNG and JPEG CompressedImage as image_transport's
    compressed plugin writes them, the stereo node's image_transport: compressed); -> offline arguments."""
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ros = rig.with_ros_rectification()
    for side, camera in (("left", ros.left), ("right", ros.right)):
        (root / f"{side}.yaml").write_text(camera_calibration_yaml(camera))
    calibration = ["--left-calibration", str(root / "left.yaml"), "--right-calibration", str(root / "right.yaml")]
    inputs = {}
    for name, suffix, options in (("PNG folder (cv2 default level 1)", ".png", []),
                                  ("PNG folder, uncompressed (level 0)", ".png", [cv2.IMWRITE_PNG_COMPRESSION, 0]),
                                  ("BMP folder", ".bmp", [])):
        folder = root / f"{name.split()[0].lower()}{len(inputs)}"
        for side, index in (("left", 0), ("right", 1)):
            (folder / side).mkdir(parents=True)
            for k, pair in enumerate(pairs):
                cv2.imwrite(str(folder / side / f"{k:05d}{suffix}"), pair[index], options)
        inputs[name] = [str(folder), *calibration]
    store = get_typestore(Stores.ROS2_JAZZY)
    for name, compression, compressed in (("MCAP raw Image, zstd chunks", CompressionType.ZSTD, ""),
                                          ("MCAP raw Image, uncompressed", CompressionType.NONE, ""),
                                          ("MCAP CompressedImage PNG", CompressionType.NONE, "png"),
                                          ("MCAP CompressedImage JPEG q95", CompressionType.NONE, "jpeg")):
        path = root / f"bag{len(inputs)}.mcap"
        type_name = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
        with open(path, "wb") as stream:
            writer = Writer(stream, chunk_size=8 << 20, compression=compression)
            schema = writer.register_msgdef(type_name, store.generate_msgdef(type_name, ros_version=2)[0])
            for k, pair in enumerate(pairs):
                stamp = 1.0 + k / 220.0
                header = {"stamp": {"sec": int(stamp), "nanosec": int(round(stamp % 1 * 1e9))}, "frame_id": "left"}
                for side, image in zip(("left", "right"), pair):
                    message = (dict(zip(("format", "data"), compress_image(image, "mono8", compressed)))
                               if compressed else {"height": image.shape[0], "width": image.shape[1],
                                                   "encoding": "mono8", "is_bigendian": 0, "step": image.shape[1],
                                                   "data": image.tobytes()})
                    writer.write_message(f"/{side}/image_raw", schema, {**message, "header": header},
                                         log_time=int(stamp * 1e9))
            writer.finish()
        inputs[name] = [str(path), *calibration]
    return inputs


def throughput(rig, scene, imaging, quick: bool, only: str = "", worker_counts: tuple[int, ...] = (1, 2, 4),
               params: str | None = None) -> None:
    """needle_stereo_offline end to end (decoding, background, measurement, CSV) on the same pairs per input; with
    --workers >= 2 pairs are also measured concurrently (the CSV is the same). ``only``: inputs whose name
    contains it; ``worker_counts``: the --workers values; ``params``: a ROS 2 params file the command reads."""
    count = 60 if quick else 200
    background = [render_background_pair(rig, np.random.default_rng(2000 + k), scene=scene, imaging=imaging)
                  for k in range(10)]
    needles = [render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(k), scene=scene,
                                  imaging=imaging) for k, name in enumerate(("straight", "planar", "3d", "hook"))]
    pairs = background + [needles[k % 4] for k in range(count - len(background))]
    stage_decode = {}
    with tempfile.TemporaryDirectory() as directory:
        root = Path(directory)
        inputs = write_inputs(root, rig, pairs)
        for name, arguments in inputs.items():
            if "folder" in name:
                files = sorted((Path(arguments[0]) / "left").iterdir())[10:20]
                stage_decode[name] = timed(lambda: [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in files], 3)
        pipeline = ready_pipeline(rig, scene, imaging)
        measure = timed(lambda: [pipeline.process(1.0, *pair) for pair in needles], 5)
        node_decode = {}  # needle_stereo with image_transport: compressed decodes a pair's two images at once
        with ThreadPoolExecutor(2) as pool:
            for codec in ("png", "jpeg"):
                messages = [compress_image(image, "mono8", codec) for image in needles[1]]
                node_decode[codec] = (
                    timed(lambda: [compressed_to_gray(data, form) for form, data in messages], 10)[1],
                    timed(lambda: list(pool.map(lambda m: compressed_to_gray(m[1], m[0]), messages)), 10)[1])
        print(f"## End to end: needle_stereo_offline, {count} pairs of 1440x1080 mono8 ({os.cpu_count()} cores)\n")
        print(f"Measurement alone: {measure[1] / 4:.2f} ms per pair (median; OpenCV threads as installed). Decoding "
              "one image on one thread, median: " + ", ".join(f"{n.split(' (')[0]} {t[1] / 10:.1f} ms"
                                                             for n, t in stage_decode.items()) + ". The node's "
              "decoding of a CompressedImage pair, median, one thread / its two threads: " + ", ".join(
                  f"{codec.upper()} {one:.1f} / {two:.1f} ms" for codec, (one, two) in node_decode.items()) + ".\n")
        print("CPU time per pair on one thread (median; load-independent) [ms]: "
              + stage_cpu(pipeline, needles, 5 if quick else 20) + ".\n")
        print(f"Load average before: {' / '.join(f'{v:.1f}' for v in os.getloadavg())} (1 / 5 / 15 min). "
              "CPU: user + system time of all threads per pair (best run). Decoding only: reading and decoding "
              "the pairs with the same threads, nothing measured (the ceiling of the input), and its CPU per pair. "
              "CPU-bound share: decoding's CPU over the whole run's, the fraction of the ceiling that the cores can "
              "reach when both are busy (decoding and measuring share them).\n")
        options = ["--params", params] if params else []
        print("| input | --workers (decoding and measuring threads) | wall [s] (best / median of 3) "
              "| pairs/s (best / median) | CPU [ms/pair] | decoding only [pairs/s] | decoding CPU [ms/pair] "
              "| best / ceiling | CPU-bound share |")
        print("|---|---|---|---|---|---|---|---|---|")
        for name, arguments in inputs.items():
            if only not in name:
                continue
            for workers in worker_counts:
                walls, cpus = [], []
                for _ in range(3):
                    cpu, start = time.process_time(), time.perf_counter()
                    with contextlib.redirect_stdout(io.StringIO()):  # the command's summary
                        code = offline_main([*arguments, "--quiet", "--workers", str(workers),
                                             "--output", str(root / "out.csv"), *options])
                    walls.append(time.perf_counter() - start)
                    cpus.append(time.process_time() - cpu)
                    assert code == 0, name
                best, median = min(walls), float(np.median(walls))
                ceiling, decoding_cpu = min(timed_decoding(arguments[0], workers) for _ in range(3))
                run_cpu = cpus[walls.index(best)]
                print(f"| {name} | {workers} | {best:.2f} / {median:.2f} | {count / best:.0f} / {count / median:.0f} "
                      f"| {1e3 * run_cpu / count:.1f} | {count / ceiling:.0f} | {1e3 * decoding_cpu / count:.1f} "
                      f"| {100 * ceiling / best:.0f} % | {100 * decoding_cpu / run_cpu:.0f} % |", flush=True)
        print(f"\nLoad average after: {' / '.join(f'{v:.1f}' for v in os.getloadavg())}.")


def epipolar_cases(rig, scene, seeds: tuple[int, ...]) -> None:
    """Needles along the epipolar lines (issue 39) and the earlier shapes, dark and bright, per noise seed: the
    per-point triangulation (default) against the curve fitted to both views (max_uncertainty 0.3 mm); then the fit
    at the default max_uncertainty, on the stretches the per-point path flags and over the whole needle."""
    rectification = Rectification.from_rig(rig)
    bright = bright_scene(scene)
    polarities = {}
    for name, polarity_scene, polarity in (("dark", scene, 1), ("bright", bright, -1)):
        threshold = ContrastThreshold(polarity=polarity)
        polarities[name] = (polarity_scene, background_models(rig, polarity_scene, threshold))
    methods = {"per-point": ReconstructionConfig(),
               "curve fit": ReconstructionConfig(curve_fit=True, max_uncertainty=0.3e-3),
               "curve fit, default max_uncertainty": ReconstructionConfig(curve_fit=True)}
    flagged_rows, summary = [], {}
    print("## Needles along the epipolar lines (issue 39)\n")
    print("Per case: RMS and max distance of the measured samples to the true curve, tip error, coverage (measured "
          "samples over the true length), measured samples within 3 sigma, worst distance over sigma; "
          "per-point -> curve fit.\n")
    print("| case | polarity | seed | RMS [mm] | max [mm] | tip [mm] | coverage | within 3σ | worst d/σ |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, truth in {**EPIPOLAR_SHAPES, **ROD_EPIPOLAR_SHAPES, **SHAPES}.items():
        length = np.linalg.norm(np.diff(truth, axis=0), axis=1).sum()
        for polarity, (polarity_scene, backgrounds) in polarities.items():
            for seed in seeds:
                images = render_stereo_pair(rig, truth, NEEDLE_RADIUS, np.random.default_rng(seed),
                                            scene=polarity_scene)
                centerlines = [extract_centerline(image, background) for image, background in zip(images, backgrounds)]
                cells, arcs = [], []
                for config in methods.values():
                    measurement = reconstruct_centerline(*centerlines, rectification, MatchingConfig(), config,
                                                         rig.world_from_left)
                    distance, arc = distance_to_curve(measurement.points, truth)
                    arcs.append((arc, measurement, distance))
                    measured = measurement.measured
                    ratio = distance[measured] / measurement.uncertainty[measured]
                    cells.append((1e3 * np.sqrt(np.mean(distance[measured] ** 2)), 1e3 * distance[measured].max(),
                                  1e3 * np.linalg.norm(measurement.points[-1] - truth[-1]),
                                  np.count_nonzero(measured) * config.sample_spacing / length,
                                  100 * np.mean(ratio <= 3), ratio.max(), np.sqrt(np.mean(ratio ** 2))))
                formats = ("{:.3f}", "{:.3f}", "{:.3f}", "{:.2f}", "{:.1f} %", "{:.1f}")
                print(f"| {name} | {polarity} | {seed} | " + " | ".join(
                    f"{form.format(before)} → {form.format(after)}" for form, before, after
                    in zip(formats, *cells[:2])) + " |", flush=True)
                summary.setdefault((name, polarity), []).append(cells[:2])
                flagged_rows.append(f"| {name} | {polarity} | {seed} | " + flagged_stretch(arcs[0], arcs[2])
                                    + f" | {cells[2][3]:.2f} | {cells[2][0]:.3f} | {cells[2][4]:.1f} % "
                                    f"| {cells[2][5]:.1f} | {cells[2][6]:.2f} |")
    print("\nThe curve fit at the default max_uncertainty (1 mm): on the stretch the per-point path flags (fitted "
          "samples within 1 mm of arc length of a flagged per-point sample: their count, those measured, their RMS "
          "and max distance to the true curve, median sigma, RMS of distance over sigma), and over the whole "
          "needle (coverage, RMS, within 3σ, worst and RMS distance over sigma: ~1-1.4 when sigma is calibrated, "
          "below when it is overstated).\n")
    print("| case | polarity | seed | flagged: samples | measured | RMS [mm] | max [mm] | median σ [mm] | RMS d/σ "
          "| coverage | RMS [mm] | within 3σ | worst d/σ | RMS d/σ |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(flagged_rows))
    print_case_summary(summary)


def print_case_summary(summary: dict) -> None:
    """The per-seed table's ranges over the seeds per case kind and polarity (the README's table): RMS, tip and
    coverage per point and fitted; the smallest share within 3 sigma and the largest distance over sigma."""
    def spread(values, form: str = "{:.3f}") -> str:
        low, high = form.format(min(values)), form.format(max(values))
        return low if low == high else f"{low}–{high}"

    print("\nPer case kind, over the seeds (per-point | curve fit at max_uncertainty 0.3 mm):\n")
    print("| case | polarity | per-point RMS [mm] | per-point tip [mm] | per-point coverage | fit RMS [mm] "
          "| fit tip [mm] | fit coverage | within 3σ (min, point / fit) | worst d/σ (max, point / fit) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for (name, polarity), runs in summary.items():
        point, fit = ([run[k] for run in runs] for k in (0, 1))
        cells = [spread([c[i] for c in method], form) for method in (point, fit)
                 for i, form in ((0, "{:.3f}"), (2, "{:.3f}"), (3, "{:.2f}"))]
        print(f"| {name} | {polarity} | " + " | ".join(cells)
              + f" | {min(c[4] for c in point):.1f} / {min(c[4] for c in fit):.1f} % "
              f"| {max(c[5] for c in point):.1f} / {max(c[5] for c in fit):.1f} |")


def flagged_stretch(per_point: tuple, fit: tuple) -> str:
    """Table cells of the ``fit`` (true arc lengths, measurement, distances) on the samples within 1 mm of arc
    length of one that the ``per_point`` measurement flags unmeasured."""
    arc, measurement, _ = per_point
    flagged = np.sort(arc[~measurement.measured])
    arc, measurement, distance = fit
    if not len(flagged):
        return "0 | 0 | | | | "
    index = np.clip(np.searchsorted(flagged, arc), 1, len(flagged) - 1)
    near = np.minimum(np.abs(flagged[index] - arc), np.abs(flagged[index - 1] - arc)) <= 1e-3
    chosen = near & measurement.measured
    if not chosen.any():
        return f"{np.count_nonzero(near)} | 0 | | | | "
    d, sigma = distance[chosen], measurement.uncertainty[chosen]
    return (f"{np.count_nonzero(near)} | {np.count_nonzero(chosen)} | {1e3 * np.sqrt(np.mean(d ** 2)):.3f} "
            f"| {1e3 * d.max():.3f} | {1e3 * np.median(sigma):.3f} | {np.sqrt(np.mean((d / sigma) ** 2)):.2f}")


def timed_decoding(path: str, workers: int) -> tuple[float, float]:
    """Wall and CPU time [s] of reading and decoding every pair of an input as needle_stereo_offline does."""
    source = open_source(Path(path), 220.0, "left/image_raw", "right/image_raw", 0.002)
    cpu, start = time.process_time(), time.perf_counter()
    with contextlib.closing(decoded(source.jobs(), workers, 4 * workers + 4)) as loaded:
        for _, _, future, _ in loaded:
            future.result()
    return time.perf_counter() - start, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions and calibration seeds")
    parser.add_argument("--only-throughput", action="store_true", help="only the end-to-end table")
    parser.add_argument("--inputs", default="", help="end to end: only the inputs whose name contains this")
    parser.add_argument("--workers", default="1,2,4", help="end to end: comma-separated --workers values")
    parser.add_argument("--params", help="end to end: ROS 2 params file of needle_stereo passed to the command "
                        "(e.g. reconstruction.curve_fit)")
    parser.add_argument("--only-epipolar", action="store_true", help="only the table of needles along the epipolar "
                        "lines (issue 39)")
    parser.add_argument("--seeds", default="7", help="that table: comma-separated sensor-noise seeds")
    arguments = parser.parse_args()
    try:
        worker_counts = tuple(int(value) for value in arguments.workers.split(","))
        noise_seeds = tuple(int(value) for value in arguments.seeds.split(","))
    except ValueError:
        parser.exit(2, "bench_vision.py: error: --workers and --seeds must be integers separated by commas\n")
    repetitions, seeds = (50, 2) if arguments.quick else (300, 6)
    rig = default_rig()
    scene = make_scene(rig, np.random.default_rng(0))
    imaging = Imaging()
    if arguments.only_epipolar:
        epipolar_cases(rig, scene, noise_seeds)
        return
    throughput(rig, scene, imaging, arguments.quick, arguments.inputs, worker_counts, arguments.params)
    if arguments.only_throughput:
        return
    cv2.setNumThreads(1)  # one core
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
