"""``needle_make_bags``: write the synthetic sample bags (rosbag2 MCAP) of :mod:`.protocols`, reproducibly.

For each experiment the ground truth (:class:`.ground_truth.TruthModel`, exact base motion) is integrated once and
its bag written; the topics, rates and frames are listed in bags/README.md. Stamps are the log times, starting at
1 700 000 000 s. Everything is seeded: the same command writes the same bags.

    needle_make_bags [--output-dir bags] [--experiments static_tip_load dynamic_pitch insertion]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from needle_common.cdr import needle_shape
from needle_common.cli_types import command_status
from needle_common.output_files import check_output_file, write_atomically

from needle_sim_ros.experiments.ground_truth import TruthModel, TruthSamples, run_ground_truth, static_check
from needle_sim_ros.experiments.protocols import EXPERIMENTS, Experiment
from needle_sim_ros.model import BaseMotion
from needle_common.qos import OfferedQos
from needle_sim_ros.recording import McapBagWriter, RecordingError, WriterOptions

START_NS = 1_700_000_000 * 10**9  # bag start (log time of t = 0)
WORLD, BASE = "world", "needle_base"
WRENCH_RATE = 100.0  # [Hz] /ground_truth/wrench
FBG_SPACING = 0.01  # [m] between the shape sensor's samples
FBG_NOISE = 1e-4  # [m] 1-sigma white noise per coordinate of the shape sensor
TRUTH_SHAPE_SAMPLES = 55  # every 5 mm in /ground_truth/shape
RELIABLE = (OfferedQos(depth=10),)
SENSOR = (OfferedQos(depth=10, reliability="best_effort"),)


@dataclass(frozen=True)
class Rendering:
    """How the images are made: background texture contrast of ``make_scene`` (a matte, nearly plain backdrop) and
    the sensor model of ``needle_vision.render.Imaging`` (blur [px], read noise [DN], shot-noise gain [DN/DN])."""

    texture_contrast: float = 0.03
    blur_sigma_px: float = 0.5
    read_noise: float = 1.0
    shot_gain: float = 0.02


def log_time(t: float) -> int:
    return START_NS + int(round(t * 1e9))


def stamp(t: float) -> Time:
    sec, nanosec = divmod(log_time(t), 10**9)
    return Time(sec=int(sec), nanosec=int(nanosec))


def rate_times(duration: float, rate: float) -> list[float]:
    """Sample times [s] at ``rate`` [Hz] from 0 up to ``duration`` (both ends included)."""
    return [k / rate for k in range(int(np.floor(duration * rate + 1e-9)) + 1)]


def pose_msg(t: float, base: BaseMotion) -> PoseStamped:
    msg = PoseStamped(header=Header(stamp=stamp(t), frame_id=WORLD))
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in base.position)
    q.x, q.y, q.z, q.w = (float(v) for v in base.orientation)
    return msg


def wrench_msg(t: float, force, torque, frame: str) -> WrenchStamped:
    msg = WrenchStamped(header=Header(stamp=stamp(t), frame_id=frame))
    w = msg.wrench
    w.force.x, w.force.y, w.force.z = (float(v) for v in force)
    w.torque.x, w.torque.y, w.torque.z = (float(v) for v in torque)
    return msg


def resampled_shape(shape, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, unit tangents, arc length) at ``count`` equal steps of deformed arc length."""
    arc = np.linspace(0.0, shape.arc_length[-1], count)
    points = np.column_stack([np.interp(arc, shape.arc_length, shape.points[:, i]) for i in range(3)])
    tangents = np.column_stack([np.interp(arc, shape.arc_length, shape.tangents[:, i]) for i in range(3)])
    return points, tangents / np.linalg.norm(tangents, axis=1, keepdims=True), arc


def shape_cdr(t: float, source: str, points, tangents, arc, tip, uncertainty=None) -> bytes:
    """A serialized NeedleShape in the world frame."""
    return needle_shape(*divmod(log_time(t), 10**9), WORLD, source, points, tangents, arc, *tip, uncertainty)


class BagContent:
    """The messages of one experiment's bag as (time [s], topic, message factory), built from the ground truth."""

    def __init__(self, experiment: Experiment, truth: TruthSamples, rendering: Rendering, seed: int) -> None:
        self.experiment = experiment
        self.truth = truth
        self.rendering = rendering
        self.rng = np.random.default_rng(seed)
        self._rig = self._scene = None

    # --- topics ---------------------------------------------------------------------------------------------
    def topics(self) -> dict[str, tuple[str, tuple[OfferedQos, ...]]]:
        e = self.experiment
        topics = {"/base_pose": ("geometry_msgs/msg/PoseStamped", RELIABLE),
                  "/ground_truth/shape": ("needle_interfaces/msg/NeedleShape", RELIABLE),
                  "/ground_truth/wrench": ("geometry_msgs/msg/WrenchStamped", RELIABLE)}
        if e.tip_load_rate:
            topics["/tip_load"] = ("geometry_msgs/msg/WrenchStamped", RELIABLE)
        if e.has_images:
            for side in ("left", "right"):
                topics[f"/{side}/image_raw"] = ("sensor_msgs/msg/Image", RELIABLE)
                topics[f"/{side}/camera_info"] = ("sensor_msgs/msg/CameraInfo", RELIABLE)
        if e.shape_sensor_rate:
            topics["/needle/measured_shape"] = ("needle_interfaces/msg/NeedleShape", SENSOR)
        return topics

    def events(self) -> list[tuple[float, int, str, Callable[[], object]]]:
        """(time, order within a time, topic, factory) of every message, sorted by time."""
        e, truth = self.experiment, self.truth
        events: list = []
        for t in rate_times(e.duration, e.pose_rate):
            events.append((t, 1, "/base_pose", lambda t=t: pose_msg(t, e.base(t))))
        for t in rate_times(e.duration, e.tip_load_rate) if e.tip_load_rate else ():
            events.append((t, 2, "/tip_load", lambda t=t: wrench_msg(t, e.tip_force(t), np.zeros(3), WORLD)))
        for t, force, torque in zip(truth.wrench_times, truth.force_base, truth.torque_base):
            events.append((t, 3, "/ground_truth/wrench", lambda t=t, f=force, m=torque: wrench_msg(t, f, m, BASE)))
        for i, t in enumerate(truth.shape_times):
            events.append((t, 4, "/ground_truth/shape", lambda i=i, t=t: shape_cdr(
                t, "ground_truth", *resampled_shape(truth.shapes[i], TRUTH_SHAPE_SAMPLES), truth.tips[i])))
        if e.has_images:
            events.append((e.background_time, 0, "images", lambda: self.render(None)))
            for i, t in enumerate(e.frame_times):
                events.append((t, 0, "images", lambda i=i: self.render(i)))
        if e.shape_sensor_rate:
            for i, t in enumerate(truth.shape_times):
                events.append((t, 5, "/needle/measured_shape", lambda i=i, t=t: self.fbg_shape(i, t)))
        events.sort(key=lambda event: (event[0], event[1]))
        return events

    # --- sensors --------------------------------------------------------------------------------------------
    def fbg_shape(self, index: int, t: float) -> bytes:
        shape = self.truth.shapes[index]
        count = int(round(shape.arc_length[-1] / FBG_SPACING)) + 1
        points, tangents, arc = resampled_shape(shape, count)
        points = points + self.rng.normal(0.0, FBG_NOISE, points.shape)
        tip = (points[-1], self.truth.tips[index][1])
        return shape_cdr(t, "fbg", points, tangents, arc, tip, np.full(count, FBG_NOISE))

    def render(self, index: int | None) -> list[tuple[str, object]]:
        """Camera infos and images of one stereo pair: needle-free (index None) or the truth at frame ``index``."""
        from needle_vision.calibration.rig import camera_info_fields
        from needle_vision.streams.image_codec import image_fields
        from needle_vision.render import (NEEDLE_RADIUS, Imaging, default_rig, make_scene, render_background_pair,
                                          render_stereo_pair)
        r = self.rendering
        if self._rig is None:
            self._rig = default_rig().with_ros_rectification()
            self._scene = make_scene(self._rig, self.rng, texture_contrast=r.texture_contrast)
        imaging = Imaging(r.blur_sigma_px, r.read_noise, r.shot_gain)
        if index is None:
            t = self.experiment.background_time
            images = render_background_pair(self._rig, self.rng, scene=self._scene, imaging=imaging)
        else:
            t = self.experiment.frame_times[index]
            images = render_stereo_pair(self._rig, self.truth.shapes[index].points, NEEDLE_RADIUS, self.rng,
                                        scene=self._scene, imaging=imaging)
        messages = []
        for side, camera, image in zip(("left", "right"), (self._rig.left, self._rig.right), images):
            header = Header(stamp=stamp(t), frame_id=f"{side}_camera_optical_frame")
            messages.append((f"/{side}/camera_info", CameraInfo(header=header, **camera_info_fields(camera))))
            messages.append((f"/{side}/image_raw", Image(header=header, **image_fields(image, "mono8"))))
        return messages


def shape_times(experiment: Experiment) -> tuple[float, ...]:
    """When the ground truth's centerline is needed: the stereo frames, or the shape sensor's samples."""
    if experiment.shape_sensor_rate:
        return tuple(rate_times(experiment.duration, experiment.shape_sensor_rate))
    return experiment.frame_times


def write_bag(experiment: Experiment, path: Path, truth_model: TruthModel = TruthModel(),
              rendering: Rendering = Rendering(), log: Callable[[str], None] = print) -> dict:
    """Integrate the ground truth and write the bag; returns a summary (message counts, size, times)."""
    start = time.perf_counter()
    truth = run_ground_truth(experiment, truth_model, shape_times(experiment), WRENCH_RATE)
    truth_wall = time.perf_counter() - start
    log(f"  ground truth: {experiment.duration:g} s simulated in {truth_wall:.1f} s")
    seed = zlib.crc32(experiment.name.encode())
    content = BagContent(experiment, truth, rendering, seed)
    counts: dict[str, int] = {}

    def write(target: Path) -> None:
        with McapBagWriter(target, WriterOptions(compression="zstd", overwrite=True)) as writer:
            writer.add_metadata("needle_sim/experiment", {
                "name": experiment.name, "description": experiment.description, "synthetic": "true",
                "ground_truth": ", ".join(f"{k}={v}" for k, v in asdict(truth_model).items()),
                "ground_truth_static_check": json.dumps(static_check(truth_model)),
                "rendering": ", ".join(f"{k}={v}" for k, v in asdict(rendering).items()) if experiment.has_images
                else "",
                "generator": "needle_make_bags (needle_sim_ros.experiments)", "seed": str(seed)})
            for topic, (type_name, qos) in content.topics().items():
                writer.add_topic(topic, type_name, qos)
            for t, _, topic, factory in content.events():
                produced = factory()
                for name, msg in (produced if topic == "images" else [(topic, produced)]):
                    writer.write(name, msg if isinstance(msg, bytes) else serialize_message(msg), log_time(t))
                    counts[name] = counts.get(name, 0) + 1

    write_atomically(path, write)  # an interrupted run leaves no half-written bag
    size = path.stat().st_size
    log(f"  wrote {path} ({size / 1e6:.1f} MB): " + ", ".join(f"{t} {n}" for t, n in sorted(counts.items())))
    return {"path": str(path), "size_bytes": size, "counts": counts, "truth_wall_s": truth_wall,
            "wall_s": time.perf_counter() - start}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="needle_make_bags", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output-dir", type=Path, default=Path("bags"), help="directory of the bags (default: bags)")
    parser.add_argument("--experiments", nargs="+", choices=sorted(EXPERIMENTS), default=list(EXPERIMENTS),
                        help="which bags to write (default: all)")
    return command_status("needle_make_bags", run, parser.parse_args(argv), (ValueError,), (RecordingError, OSError))


def run(args: argparse.Namespace) -> int:
    """Write the bags, every bag's file checked before the first ground truth is integrated."""
    paths = {name: check_output_file(args.output_dir / f"{name}.mcap", "bag") for name in args.experiments}
    total = 0
    for name, path in paths.items():
        experiment = EXPERIMENTS[name]()
        print(f"[needle_make_bags] {name}: {experiment.description}", flush=True)
        total += write_bag(experiment, path, log=lambda m: print(m, flush=True))["size_bytes"]
    print(f"[needle_make_bags] {len(paths)} bag(s), {total / 1e6:.1f} MB in total")
    return 0


if __name__ == "__main__":
    sys.exit(main())
