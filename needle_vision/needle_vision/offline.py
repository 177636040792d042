"""``needle_stereo_offline``: measure the needle in recorded stereo frames, headless (seed 000, Sec. III-A).

Input is either a folder with ``left/`` and ``right/`` sub-folders of images paired by file name (stamps from
``--fps``), or a rosbag2 MCAP recording (an ``.mcap`` file or a bag folder) with the stereo_image_proc
topics, read with the ``mcap`` + ``mcap_ros2`` readers. The calibration comes from camera_calibration YAML
files or, for a bag without them, from its ``camera_info`` topics. Settings are the node's parameters, read
from a ROS 2 params file. Output: one CSV row per centerline sample (frame = index of the synchronised pair,
stamp [s], sample, arc length, x, y, z, uncertainty [m], and velocity/acceleration with tracking) in the
configured output frame.

    needle_stereo_offline recording.mcap --params config/needle_stereo.yaml --output needle.csv
"""
from __future__ import annotations

import argparse
import csv
import sys
from collections import Counter
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
from tqdm import tqdm

from needle_vision.calibration import CalibrationError, StereoRig, calibration_from_camera_info, load_camera_calibration
from needle_vision.image_codec import ImageFormatError, image_message_to_gray
from needle_vision.pairing import StampPairer
from needle_vision.parameters import ParameterError, load_params_file, output_from_left, stereo_config, validate_all
from needle_vision.pipeline import FrameResult, FrameStatus, StereoNeedlePipeline

IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".bmp", ".pgm", ".jpg", ".jpeg"}


class InputError(ValueError):
    """The input folder or bag cannot be used (message says why)."""


def folder_pairs(folder: Path, fps: float) -> tuple[int, Iterator[tuple[float, np.ndarray, np.ndarray]]]:
    """(count, iterator of (stamp, left, right)) for ``folder/left/NAME`` + ``folder/right/NAME`` images."""
    names = {side: {p.name for p in (folder / side).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
             for side in ("left", "right") if (folder / side).is_dir()}
    if len(names) < 2:
        raise InputError(f"'{folder}' needs sub-folders left/ and right/ with images")
    common = sorted(names["left"] & names["right"])
    if not common:
        raise InputError(f"'{folder}': no image name is present in both left/ and right/")

    def read(path: Path) -> np.ndarray:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError(f"cannot read image '{path}'")
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image

    return len(common), ((k / fps, read(folder / "left" / n), read(folder / "right" / n)) for k, n in enumerate(common))


def _bag_files(path: Path) -> list[Path]:
    files = [path] if path.is_file() else sorted(path.glob("*.mcap"))
    if not files:
        raise InputError(f"'{path}' is neither an .mcap file nor a folder with .mcap files")
    return files


def _bag_messages(path: Path, topics: list[str]) -> Iterator[tuple[str, object]]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    wanted = {"/" + topic.lstrip("/") for topic in topics}
    for file in _bag_files(path):
        with open(file, "rb") as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _, channel, _, message in reader.iter_decoded_messages(topics=sorted(wanted)):
                yield "/" + channel.topic.lstrip("/"), message


def _bag_count(path: Path, topic: str) -> int | None:
    from mcap.reader import make_reader

    total = 0
    for file in _bag_files(path):
        with open(file, "rb") as stream:
            summary = make_reader(stream).get_summary()
        if summary is None or summary.statistics is None:
            return None
        total += sum(summary.statistics.channel_message_counts.get(cid, 0)
                     for cid, channel in summary.channels.items() if channel.topic.lstrip("/") == topic.lstrip("/"))
    return total


def bag_rig(path: Path, left_info_topic: str, right_info_topic: str) -> StereoRig:
    """The rig from the first camera_info message of each camera in the bag."""
    infos: dict[str, object] = {}
    for topic, message in _bag_messages(path, [left_info_topic, right_info_topic]):
        infos.setdefault(topic, message)
        if len(infos) == 2:
            break
    left, right = ("/" + t.lstrip("/") for t in (left_info_topic, right_info_topic))
    if left not in infos or right not in infos:
        raise InputError(f"the bag has no {left} / {right} messages; give calibration files instead")
    return StereoRig.from_camera_calibrations(calibration_from_camera_info(infos[left], "left"),
                                              calibration_from_camera_info(infos[right], "right"))


def bag_pairs(path: Path, left_topic: str, right_topic: str, tolerance: float, skipped: Counter
              ) -> Iterator[tuple[float, np.ndarray, np.ndarray]]:
    """Synchronised (stamp, left, right) grey images of the bag; unusable frames are counted in ``skipped``."""
    pairer = StampPairer(tolerance)
    left = "/" + left_topic.lstrip("/")
    for topic, message in _bag_messages(path, [left_topic, right_topic]):
        stamp = message.header.stamp.sec + 1e-9 * message.header.stamp.nanosec
        pair = pairer.push("left" if topic == left else "right", stamp, message)
        if pair is None:
            continue
        try:
            yield pair.stamp, image_message_to_gray(pair.left), image_message_to_gray(pair.right)
        except ImageFormatError as error:
            skipped[f"image skipped: {error}"] += 1
    if pairer.dropped:
        skipped[f"frames without a partner within {tolerance} s"] += pairer.dropped


def write_rows(writer: csv.writer, frame: int, stamp: float, result: FrameResult, tracking: bool) -> None:
    """One row per sample; with tracking, the motion cells stay empty until the tracker has its window."""
    m = result.measurement
    columns = [m.arc_length, *m.points.T, m.uncertainty]
    if result.motion is not None:
        columns += [*result.motion.velocity.T, *result.motion.acceleration.T]
    missing = [""] * 6 if tracking and result.motion is None else []
    for sample, values in enumerate(zip(*columns)):
        writer.writerow([frame, f"{stamp:.9f}", sample, *(f"{v:.7g}" for v in values), *missing])


def run(arguments: argparse.Namespace) -> int:
    values = load_params_file(arguments.params) if arguments.params else {}
    if arguments.left_calibration:
        values["left_calibration_file"] = arguments.left_calibration
    if arguments.right_calibration:
        values["right_calibration_file"] = arguments.right_calibration
    values = validate_all(values)
    source = Path(arguments.input)
    if not source.exists():
        raise InputError(f"input '{source}' does not exist")
    is_folder = source.is_dir() and (source / "left").is_dir()
    if values["left_calibration_file"]:
        rig = StereoRig.from_camera_calibrations(load_camera_calibration(values["left_calibration_file"]),
                                                 load_camera_calibration(values["right_calibration_file"]))
    elif is_folder:
        raise InputError("an image folder needs calibration files (--left-calibration/--right-calibration)")
    else:
        rig = bag_rig(source, arguments.left_info_topic, arguments.right_info_topic)
    pipeline = StereoNeedlePipeline(rig, stereo_config(values), output_from_left(values))
    outcomes: Counter = Counter()
    if is_folder:
        total, pairs = folder_pairs(source, arguments.fps)
    else:
        total = _bag_count(source, arguments.left_topic)
        pairs = bag_pairs(source, arguments.left_topic, arguments.right_topic, values["sync_tolerance"], outcomes)
    tracking = values["tracking.enabled"]
    with open(arguments.output, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["frame", "stamp", "sample", "arc_length", "x", "y", "z", "uncertainty"]
                        + (["vx", "vy", "vz", "ax", "ay", "az"] if tracking else []))
        for frame, (stamp, left, right) in enumerate(tqdm(pairs, total=total, unit="pair", disable=arguments.quiet)):
            result = pipeline.process(stamp, left, right)
            outcomes[result.status.value if result.status is not FrameStatus.REJECTED
                     else f"rejected: {result.reason}"] += 1
            if result.status is FrameStatus.MEASURED:
                write_rows(writer, frame, stamp, result, tracking)
    print(f"{sum(outcomes.values())} frames/pairs -> {arguments.output}")
    for outcome, count in outcomes.most_common():
        print(f"  {count:6d}  {outcome}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="needle_stereo_offline", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", help="folder with left/ and right/ images, an .mcap file or a rosbag2 folder")
    parser.add_argument("--params", help="ROS 2 params file with needle_stereo's parameters")
    parser.add_argument("--left-calibration", help="camera_calibration YAML of the left camera")
    parser.add_argument("--right-calibration", help="camera_calibration YAML of the right camera")
    parser.add_argument("--output", default="needle_stereo.csv", help="CSV file written (default: %(default)s)")
    parser.add_argument("--fps", type=float, default=220.0, help="frame rate of an image folder [Hz] (stamps)")
    parser.add_argument("--left-topic", default="left/image_raw")
    parser.add_argument("--right-topic", default="right/image_raw")
    parser.add_argument("--left-info-topic", default="left/camera_info")
    parser.add_argument("--right-info-topic", default="right/camera_info")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    arguments = parser.parse_args(argv)
    if not arguments.fps > 0:
        parser.error("--fps must be positive")
    try:
        return run(arguments)
    except (ParameterError, CalibrationError, InputError) as error:
        print(f"needle_stereo_offline: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
