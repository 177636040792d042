"""``needle_stereo_offline``: measure the needle in recorded stereo frames, headless (seed 000, Sec. III-A).

Inputs, options, the CSV and the exit status: README, "needle_stereo_offline". Images are decoded on a thread pool
ahead of the measurement (OpenCV releases the GIL); with ``--workers`` >= 2, pairs are also measured concurrently once
the background and polarity are settled (the compiled kernels release the GIL too), their order-dependent part
(base/tip by continuity, tracking, CSV) completed in input order: the same CSV. OpenCV's own thread pool is off
during a run (``--workers`` is the parallelism).

    needle_stereo_offline recording.mcap --params config/needle_stereo.yaml --output needle.csv
"""
from __future__ import annotations

import argparse
import csv
import os
import queue
import re
import sys
import threading
from collections import Counter, deque
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, TextIO

import cv2
import numpy as np
from tqdm import tqdm

from needle_vision.detection.background import BackgroundModel
from needle_common.bag_reader import BagReader, BagReadError, absolute_topic
from needle_vision.calibration.rig import CalibrationError, StereoRig, rig_from_camera_infos
from needle_vision.streams.image_codec import ImageFormatError, decoded_to_gray, deserialize_image, read_gray_bmp
from needle_vision.streams.pairing import StampPairer
from needle_common.cdr import CameraInfo, PoseStamped, camera_info, pose_stamped
from needle_common.cli_types import command_status, positive, positive_int
from needle_common.output_files import check_output_file
from needle_common.parameters import ParameterError, load_params_file, valid_topic_name
from needle_vision.front_end import StereoFrontEnd
from needle_vision.parameters import SPECS, validate_all
from needle_vision.pipeline import FrameResult, FrameStatus, PairMeasurement, StereoNeedlePipeline

IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".bmp", ".pgm", ".jpg", ".jpeg"}
IMAGE_TYPES = {"sensor_msgs/msg/Image": False, "sensor_msgs/msg/CompressedImage": True}  # -> compressed
MEDIAN_PAIRS = 25  # pairs spread over the sequence for --background median
BACKGROUND_PAIRS = 200  # most pairs averaged from a separate background input


class InputError(ValueError):
    """The input folder or bag cannot be used (message says why)."""


#: (pair index, stamp [s], loader of the (left, right) grey images run on a worker thread, base poses read since
#: the previous pair)
PairJob = tuple[int, float, Callable[[], tuple[np.ndarray, np.ndarray]], list[PoseStamped]]
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"


@dataclass
class PairSource:
    """The synchronised pairs of one input: their count (an estimate for a bag, None if unknown), the jobs in
    order, the bag's reader (None: an image folder), the left frame_id, a counter of frames that could not be used
    and one of base poses that could not be read."""

    count: int | None
    jobs: Callable[[], Iterator[PairJob]]
    reader: BagReader | None
    frame_id: str = ""
    skipped: Counter = field(default_factory=Counter)
    poses_skipped: Counter = field(default_factory=Counter)


def _read_image(path: Path) -> np.ndarray:
    if path.suffix.lower() == ".bmp" and path.is_file():  # a grey BMP's rows as they are (no decoding, ~8x faster)
        image = read_gray_bmp(path.read_bytes())
        if image is not None:
            return image
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if image is None:
        raise InputError(f"cannot read image '{path}' (missing, not an image, or corrupt)")
    return decoded_to_gray(image)


def folder_source(folder: Path, fps: float) -> PairSource:
    """Pairs ``folder/left/NAME`` + ``folder/right/NAME`` in name order, stamps ``index / fps``."""
    sides = [folder / side for side in ("left", "right")]
    if not all(side.is_dir() for side in sides):
        raise InputError(f"'{folder}' needs sub-folders left/ and right/ with images")
    names = [{p.name for p in side.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES} for side in sides]
    common = sorted(names[0] & names[1])
    if not common:
        raise InputError(f"'{folder}': no image name is present in both left/ and right/"
                         + ("" if any(names) else " (no images at all)"))

    def jobs() -> Iterator[PairJob]:
        for k, name in enumerate(common):
            yield k, k / fps, lambda name=name: (_read_image(sides[0] / name), _read_image(sides[1] / name)), []
    return PairSource(len(common), jobs, None, "left_optical")


def _bag_topic(reader: BagReader, topic: str) -> tuple[int, str] | None:
    """Message count and schema name of ``topic`` in the bag's summaries ((0, ""): none; None: a file lacks one)."""
    recorded = reader.topics.get(absolute_topic(topic))
    if not reader.summarized:
        return None
    return (recorded.message_count, recorded.type_name) if recorded and recorded.message_count else (0, "")


def bag_rig(reader: BagReader, left_info_topic: str, right_info_topic: str) -> StereoRig:
    """The rig from the first camera_info message of each camera in the bag."""
    topics = {absolute_topic(t): side for t, side in ((left_info_topic, "left"), (right_info_topic, "right"))}
    infos: dict[str, CameraInfo] = {}
    with closing(reader.messages(sorted(topics))) as records:
        for topic, schema, _, data in records:
            if schema != CAMERA_INFO_TYPE:
                raise InputError(f"topic {topic} of '{reader.path}' has type '{schema}', not {CAMERA_INFO_TYPE}")
            try:
                infos.setdefault(topics[topic], camera_info(data))
            except ValueError as error:
                raise InputError(f"{topic} of '{reader.path}': {error}") from error
            if len(infos) == 2:
                break
    if len(infos) < 2:
        raise InputError(f"the bag has no {' / '.join(topics)} messages; give calibration files instead")
    return rig_from_camera_infos(infos["left"], infos["right"])


def bag_source(reader: BagReader, left_topic: str, right_topic: str, tolerance: float, base_topic: str = "",
               queue_size: int = 8) -> PairSource:
    """Synchronised pairs of the bag's image topics (raw or compressed) with the ``base_topic`` poses read
    before each (paired as the node pairs them: ``tolerance``, ``queue_size`` frames per camera waiting); images of
    an unusable encoding and frames without a partner are counted in ``skipped``."""
    left, base = absolute_topic(left_topic), absolute_topic(base_topic) if base_topic else ""
    path = reader.path
    recorded = _bag_topic(reader, left_topic)
    source = PairSource(recorded and recorded[0], lambda: iter(()), reader)

    def gray(image) -> np.ndarray:
        try:
            return image.gray()
        except ImageFormatError as error:
            raise SkippedPair(str(error)) from error

    def jobs() -> Iterator[PairJob]:
        source.skipped.clear()  # counted again on each pass (the background may take a pass of its own)
        source.poses_skipped.clear()
        pairer = StampPairer(tolerance, queue_size)
        index, poses = 0, []
        for topic, schema, _, data in reader.messages([left_topic, right_topic] + ([base] if base else [])):
            if topic == base:
                if schema != POSE_TYPE:
                    raise InputError(f"base pose topic {topic} of '{path}' has type '{schema}', not {POSE_TYPE}")
                try:
                    poses.append(pose_stamped(data))
                except ValueError as error:
                    source.poses_skipped[f"base pose ignored: {error}"] += 1
                continue
            if schema not in IMAGE_TYPES:
                raise InputError(f"topic {topic} of '{path}' has type '{schema}', not an Image or CompressedImage")
            try:
                image = deserialize_image(data, IMAGE_TYPES[schema])
            except ImageFormatError as error:
                source.skipped[f"image skipped: {error}"] += 1
                continue
            pair = pairer.push("left" if topic == left else "right", image.stamp, image)
            if pair is not None:
                source.frame_id = source.frame_id or pair.left.frame_id
                yield index, pair.stamp, lambda pair=pair: (gray(pair.left), gray(pair.right)), poses
                index, poses = index + 1, []
        if pairer.dropped:
            source.skipped[f"frames without a partner within {tolerance} s"] += pairer.dropped
    source.jobs = jobs
    return source


class SkippedPair(Exception):
    """A pair whose images cannot be used (counted, not fatal)."""


def open_source(path: Path, fps: float, left_topic: str, right_topic: str, tolerance: float,
                base_topic: str = "", queue_size: int = 8) -> PairSource:
    """The pairs of an image folder (stamps from ``fps``) or of a bag's image topics (with the poses of
    ``base_topic``; an image folder has none: InputError)."""
    if not path.exists():
        raise InputError(f"input '{path}' does not exist")
    if path.is_dir() and ((path / "left").is_dir() or (path / "right").is_dir()):
        if base_topic:
            raise InputError(f"--base-pose-topic needs an MCAP input; '{path}' is an image folder")
        return folder_source(path, fps)
    if path.is_dir() and not any(path.glob("*.mcap")) and not (path / "metadata.yaml").is_file():
        raise InputError(f"'{path}' is neither an .mcap file, a rosbag2 folder nor a folder with left/ and right/")
    reader = BagReader(path, require_summary=False)  # files without a summary too: their counts stay unknown
    recorded = _bag_topic(reader, base_topic) if base_topic else None
    if recorded is not None and not recorded[0]:
        raise InputError(f"'{path}' has no messages on the base pose topic '{base_topic}'")
    if recorded and recorded[1] != POSE_TYPE:
        raise InputError(f"base pose topic '{base_topic}' of '{path}' has type '{recorded[1]}', not {POSE_TYPE}")
    return bag_source(reader, left_topic, right_topic, tolerance, base_topic, queue_size)


def decoded(jobs: Iterator[PairJob], workers: int, depth: int
            ) -> Iterator[tuple[int, float, Future, list[PoseStamped]]]:
    """The jobs with their loaders running on ``workers`` threads up to ``depth`` pairs ahead; the jobs themselves
    (reading a bag: parsing, with chunks decompressed on threads of the reader) are iterated on one more thread."""
    ahead: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="decode") as pool:
        def offer(item) -> bool:
            while not stop.is_set():
                try:
                    ahead.put(item, timeout=0.05)
                    return True
                except queue.Full:
                    pass
            return False

        def produce() -> None:
            try:
                for index, stamp, load, poses in jobs:
                    if not offer((index, stamp, pool.submit(load), poses)):
                        return
                offer(end)
            except BaseException as error:  # noqa: BLE001 - raised again in the consumer
                offer(error)

        feeder = threading.Thread(target=produce, name="pair-reader", daemon=True)
        feeder.start()
        try:
            while (item := ahead.get()) is not end:
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            stop.set()
            while not ahead.empty():
                item = ahead.get_nowait()
                if isinstance(item, tuple):
                    item[2].cancel()
            feeder.join()


def _frames(text: str) -> slice:
    match = re.fullmatch(r"\s*(\d*)\s*:\s*(\d*)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"'{text}' is not A:B (pair indices, either may be empty)")
    start, stop = (int(v) if v else None for v in match.groups())
    if start is not None and stop is not None and stop <= start:
        raise argparse.ArgumentTypeError(f"'{text}': B must be greater than A")
    return slice(start, stop)


def load_pairs(source: PairSource, wanted: Callable[[int], bool], workers: int, limit: int) -> list:
    """Decoded pairs whose index is ``wanted`` (at most ``limit``), stopping early when possible."""
    jobs = (job for job in source.jobs() if wanted(job[0]))
    pairs = []
    with closing(decoded(jobs, workers, 2 * workers + 2)) as loaded:
        for _, _, future, _ in loaded:
            try:
                pairs.append(future.result())
            except SkippedPair:
                continue
            if len(pairs) >= limit:
                break
    return pairs


def build_backgrounds(mode: str, source: PairSource, pipeline: StereoNeedlePipeline, frames: slice,
                      arguments: argparse.Namespace, tolerance: float) -> int:
    """Set the pipeline's background models for ``mode`` (median, none or a needle-free input); returns how many
    leading pairs of ``source`` are background: for ``first``, they are read in the same pass as the pairs
    measured (:func:`run` sets the models from them with :func:`set_backgrounds`), nothing is set here."""
    first = pipeline.config.background_frames
    if mode == "none" or (mode == "first" and first == 0):
        return 0  # per frame (see run) or bootstrapped by the pipeline from the first pair
    if mode == "first":
        if source.count is not None and source.count <= first:
            raise NothingMeasured(f"nothing measured: the input has {source.count} pair(s), not more than "
                                  f"background.frames = {first} (the needle-free pairs at its start); use "
                                  "--background median, none or a needle-free FOLDER|BAG")
        return first
    if mode == "median":
        start = frames.start or 0
        stop = min(frames.stop or source.count or start + MEDIAN_PAIRS, source.count or 1 << 62)
        picks = set(np.linspace(start, max(stop - 1, start), MEDIAN_PAIRS).round().astype(int).tolist())
        pairs = load_pairs(source, picks.__contains__, arguments.workers, len(picks))
    else:
        path = Path(mode)
        if not path.exists():
            raise InputError(f"background '{mode}' is neither first, median, none nor an existing folder or bag")
        separate = open_source(path, arguments.fps, arguments.left_topic, arguments.right_topic, tolerance)
        pairs = load_pairs(separate, lambda k: True, arguments.workers, BACKGROUND_PAIRS)
    set_backgrounds(pipeline, mode, pairs)
    return 0


def set_backgrounds(pipeline: StereoNeedlePipeline, mode: str, pairs: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """The pipeline's background models from the needle-free ``pairs`` of ``mode``: their mean, or their per-pixel
    median for ``median``; no pair or unusable ones: InputError."""
    if not pairs:
        raise InputError(f"background ({mode}): no usable pair")
    try:
        make = BackgroundModel.from_median if mode == "median" else BackgroundModel.from_frames
        pipeline.backgrounds = tuple(make([pair[k] for pair in pairs], pipeline.config.threshold) for k in range(2))
    except ValueError as error:
        raise InputError(f"background ({mode}): {error}") from error


class NothingMeasured(RuntimeError):
    """The run measured nothing (exit status 1); the message says why."""


def csv_header(frame_id: str, tracking: bool) -> tuple[str, list[str]]:
    """The comment line (frame and units) and the column names."""
    comment = (f"# needle_stereo_offline: points in frame '{frame_id}'; units SI: stamp [s], arc_length, x, y, z, "
               "uncertainty (1 sigma) [m]" + (", vx..vz [m/s], ax..az [m/s^2]" if tracking else ""))
    return comment, (["frame", "stamp", "sample", "arc_length", "x", "y", "z", "uncertainty"]
                     + (["vx", "vy", "vz", "ax", "ay", "az"] if tracking else []))


def write_rows(stream: TextIO, frame: int, stamp: float, result: FrameResult, tracking: bool) -> None:
    """One CSV row per sample (as csv.writer writes them; one formatting for the pair's rows, ~5x faster than per
    value); with tracking, the motion cells stay empty until the tracker has its window."""
    m = result.measurement
    columns = [np.arange(len(m.points)), m.arc_length, *m.points.T, m.uncertainty]
    if result.motion is not None:
        columns += [*result.motion.velocity.T, *result.motion.acceleration.T]
    missing = ",,,,,," if tracking and result.motion is None else ""
    row = f"{frame},{stamp:.9f},%d," + ",".join(["%.7g"] * (len(columns) - 1)) + missing + "\r\n"
    stream.write((row * len(m.points)) % tuple(np.column_stack(columns).ravel().tolist()))


def add_base_poses(front: StereoFrontEnd, poses: list[PoseStamped], source: PairSource) -> None:
    """Store the base poses read with a pair (in the output frame); unusable ones are counted in the source."""
    front.image_frame = source.frame_id
    for pose in poses:
        try:
            front.add_base_pose(pose)
        except ValueError as error:
            source.poses_skipped[f"base pose ignored: {error}"] += 1


def _measured(pipeline: StereoNeedlePipeline, images: Future) -> PairMeasurement | None:
    """The settled ``pipeline``'s measurement of a decoded pair (None when it is skipped), on a measuring thread."""
    try:
        return pipeline.measure(*images.result())
    except SkippedPair:
        return None


def _settings(arguments: argparse.Namespace) -> dict:
    values = load_params_file(arguments.params, "needle_stereo", SPECS) if arguments.params else {}
    for name, value in (("left_calibration_file", arguments.left_calibration),
                        ("right_calibration_file", arguments.right_calibration),
                        ("needle_polarity", arguments.polarity)):
        if value is not None:
            values[name] = value
    if arguments.output_frame is not None:
        values["output_frame"] = "" if arguments.output_frame in ("camera", "") else arguments.output_frame
    return validate_all(values)


def run(arguments: argparse.Namespace) -> int:
    values = _settings(arguments)
    suffix = "/compressed" if values["image_transport"] == "compressed" else ""  # image_transport's topic names
    arguments.left_topic = arguments.left_topic or f"left/image_raw{suffix}"
    arguments.right_topic = arguments.right_topic or f"right/image_raw{suffix}"
    source_path = Path(arguments.input)
    output = Path(arguments.output)
    try:  # before any work: a directory, a file in the way of its folder, an unwritable folder (its folder is made)
        check_output_file(output, "--output")
    except ValueError as error:
        raise InputError(str(error)) from error
    base_topic = arguments.base_pose_topic or ""
    if arguments.base_pose_topic is not None and not valid_topic_name(base_topic):
        raise InputError(f"--base-pose-topic '{base_topic}' is not a valid ROS 2 topic name")
    if base_topic and absolute_topic(base_topic) in {absolute_topic(arguments.left_topic),
                                                     absolute_topic(arguments.right_topic)}:
        raise InputError(f"--base-pose-topic '{base_topic}' is also an image topic")
    source = open_source(source_path, arguments.fps, arguments.left_topic, arguments.right_topic,
                         values["sync_tolerance"], base_topic, values["sync_queue_size"])
    front = StereoFrontEnd(values)
    if front.pipeline is None:
        if source.reader is None:
            raise InputError("an image folder needs calibration files (--left-calibration/--right-calibration)")
        front.use_rig(bag_rig(source.reader, arguments.left_info_topic, arguments.right_info_topic))
    pipeline = front.pipeline
    mode = arguments.background or "first"
    frames = arguments.frames
    background_pairs = build_backgrounds(mode, source, pipeline, frames, arguments, values["sync_tolerance"])
    outcomes: Counter = Counter({FrameStatus.BACKGROUND.value: background_pairs} if background_pairs else {})
    tracking = values["tracking.enabled"]
    per_frame = mode == "none"
    half_width = pipeline.config.centerline.profile_half_width
    # The leading background pairs of mode "first" are read in the same pass (the models are set before the first
    # pair after them).
    selected = range(frames.start or 0, sys.maxsize if frames.stop is None else frames.stop)
    jobs = (job for job in source.jobs() if job[0] < background_pairs or job[0] in selected)
    background: list[tuple[np.ndarray, np.ndarray]] = []
    total = None if source.count is None else len(range(*slice(max(frames.start or 0, background_pairs),
                                                               frames.stop).indices(source.count))) + background_pairs
    partial = output.with_name(output.name + ".part")
    measured = 0
    ordering: Counter = Counter()
    opencv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # the --workers threads run the pairs; OpenCV's own pool would only spin on the same cores
    try:
        with open(partial, "w", newline="") as stream, \
                closing(decoded(jobs, arguments.workers, 4 * arguments.workers + 4)) as loaded, \
                ThreadPoolExecutor(max_workers=1, thread_name_prefix="csv") as csv_thread, \
                ThreadPoolExecutor(max_workers=arguments.workers, thread_name_prefix="measure") as measuring:
            written: deque[Future] = deque()  # CSV rows formatted and written on a thread of their own
            # Pairs measured ahead on the measuring threads once the pipeline is settled (their order-dependent
            # part, base/tip ordering, state and tracking, is completed here in input order).
            ahead: deque[tuple[int, float, Future, Future | None, list[PoseStamped]]] = deque()

            def complete(frame: int, stamp: float, images: Future, measurement: Future | None,
                         poses: list[PoseStamped]) -> None:
                nonlocal measured
                add_base_poses(front, poses, source)
                try:
                    left, right = images.result()
                except SkippedPair as error:
                    outcomes[f"image skipped: {error}"] += 1
                    return
                if measurement is not None:
                    result = pipeline.complete(stamp, left, right, measurement.result())
                else:
                    if per_frame and left.ndim == 2 and right.ndim == 2:
                        pipeline.backgrounds = tuple(BackgroundModel.from_needle_frame(
                            image, pipeline.config.threshold, half_width) for image in (left, right))
                    result = pipeline.process(stamp, left, right)
                outcomes[result.status.value if result.status is not FrameStatus.REJECTED
                         else f"rejected: {result.reason}"] += 1
                if result.status is FrameStatus.MEASURED:
                    if not measured:  # the frame of a bag's images is known once its first pair is read
                        comment, columns = csv_header(values["output_frame"] or source.frame_id or "left_optical",
                                                      tracking)
                        stream.write(comment + "\n")
                        csv.writer(stream).writerow(columns)
                    measured += 1
                    ordering[result.ordering] += 1
                    written.append(csv_thread.submit(write_rows, stream, frame, stamp, result, tracking))
                    while written and (written[0].done() or len(written) > 64):
                        written.popleft().result()  # raises what writing raised (e.g. a full disk)

            for frame, stamp, future, poses in tqdm(loaded, total=total, unit="pair", disable=arguments.quiet):
                if frame < background_pairs:
                    try:
                        background.append(future.result())
                    except SkippedPair:
                        pass
                    continue
                if background_pairs and pipeline.backgrounds is None:
                    set_backgrounds(pipeline, mode, background)
                    background.clear()
                concurrent = arguments.workers > 1 and not per_frame and pipeline.settled
                ahead.append((frame, stamp, future, measuring.submit(_measured, pipeline, future) if concurrent
                              else None, poses))
                while len(ahead) > (2 * arguments.workers if concurrent else 0):
                    complete(*ahead.popleft())
            while ahead:
                complete(*ahead.popleft())
            if background_pairs and pipeline.backgrounds is None:  # nothing after the background pairs
                set_backgrounds(pipeline, mode, background)
            for future in written:
                future.result()
        outcomes.update(source.skipped or {})
        print(f"{sum(outcomes.values())} frames/pairs of '{source_path}'")
        for outcome, count in outcomes.most_common():
            print(f"  {count:6d}  {outcome}")
        if base_topic:
            print("base and tip of the measured pairs told by: "
                  + ", ".join(f"{kind} {count}" for kind, count in ordering.most_common()))
            for note, count in source.poses_skipped.most_common():
                print(f"  {count:6d}  {note}")
        if not measured:
            why = ""
            if not sum(outcomes.values()):
                why = " (the input has no pair in --frames)"
            elif background_pairs:
                why = (f" (its first {background_pairs} pairs were taken as the needle-free background, "
                       "background.frames: set it in a --params file, such as a shipped bag's experiment file, or use "
                       "--background median)")
            raise NothingMeasured(f"no pair was measured{why}; no CSV written")
        partial.replace(output)
    finally:
        partial.unlink(missing_ok=True)
        cv2.setNumThreads(opencv_threads)
    print(f"{measured} measured pairs -> {output}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="needle_stereo_offline", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", help="folder with left/ and right/ images, an .mcap file or a rosbag2 folder")
    parser.add_argument("--params", help="ROS 2 params file with needle_stereo's parameters")
    parser.add_argument("--left-calibration", help="camera_calibration YAML of the left camera")
    parser.add_argument("--right-calibration", help="camera_calibration YAML of the right camera")
    parser.add_argument("--output", default="needle_stereo.csv", help="CSV file written (default: %(default)s)")
    parser.add_argument("--polarity", help="needle darker (dark) or brighter (bright) than the background "
                        "(overrides needle_polarity)")
    parser.add_argument("--background", help="first: the first background.frames pairs are needle-free (default); "
                        "median: per-pixel median over the sequence (a moving needle); none: estimated in each "
                        "pair; or a folder/bag of needle-free pairs")
    parser.add_argument("--frames", type=_frames, default=slice(None), metavar="A:B",
                        help="measure pairs A (included) to B (excluded) only; either may be empty")
    parser.add_argument("--output-frame", help="'camera': the raw left optical frame (output_transform unused); "
                        "another name (e.g. world): output_frame, with output_transform from the params file")
    parser.add_argument("--fps", type=positive, default=220.0, help="frame rate of an image folder [Hz] (stamps)")
    parser.add_argument("--workers", type=positive_int, default=min(4, os.cpu_count() or 1),
                        help="image decoding threads, and threads measuring pairs concurrently (1: one pair after the "
                        "other; the output is the same) (default: %(default)s)")
    parser.add_argument("--left-topic", help="Image or CompressedImage topic (default: left/image_raw, with "
                        "image_transport 'compressed' in the params file left/image_raw/compressed)")
    parser.add_argument("--right-topic", help="Image or CompressedImage topic (default: right/image_raw or "
                        "right/image_raw/compressed)")
    parser.add_argument("--base-pose-topic", metavar="TOPIC", help="geometry_msgs/PoseStamped of the needle base "
                        "in the bag (e.g. base_pose): base and tip are told by it (base_pose.max_age, "
                        "base_pose.offset of the params file)")
    parser.add_argument("--left-info-topic", default="left/camera_info", help="CameraInfo topic: the calibration "
                        "of a bag without --left/right-calibration or calibration files in --params")
    parser.add_argument("--right-info-topic", default="right/camera_info", help="as --left-info-topic")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    arguments = parser.parse_args(argv)
    return command_status("needle_stereo_offline", run, arguments, (ParameterError, CalibrationError, InputError,
                                                                    BagReadError, OSError), (NothingMeasured,))


if __name__ == "__main__":
    sys.exit(main())
