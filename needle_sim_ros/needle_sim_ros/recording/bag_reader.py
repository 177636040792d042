"""Reading a rosbag2 MCAP recording (single .mcap file or bag directory) for playback: topics, QoS, messages.

A bag directory's files are taken from metadata.yaml (``relative_file_paths``) when present, else all its .mcap
files in split order. Messages come in log-time order within each file and files in order, as serialized bytes.
A chunk that cannot be read (bit flip: CRC or decompression error) is skipped and counted in
``corrupt_chunks``, or stops the reading with :class:`BagReadError` if asked. :data:`EXPECTED_TYPES` are the types
the suite's nodes subscribe to on the recorded topic names (:meth:`BagReader.type_mismatches`).
"""
from __future__ import annotations

import heapq
import queue
import re
import struct
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, TypeVar

import yaml
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from zstandard import ZstdError

from needle_sim_ros.recording.qos import OfferedQos, parse_offered_qos_profiles


class BagReadError(RuntimeError):
    """The recording cannot be read; the message names the file."""


# Types the nodes of the suite expect on the topics of a recording (absolute names as recorded).
EXPECTED_TYPES = {
    "/base_pose": "geometry_msgs/msg/PoseStamped", "/base_twist": "geometry_msgs/msg/TwistStamped",
    "/tip_load": "geometry_msgs/msg/WrenchStamped", "/wrench": "geometry_msgs/msg/WrenchStamped",
    "/left/image_raw": "sensor_msgs/msg/Image", "/right/image_raw": "sensor_msgs/msg/Image",
    "/left/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/right/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/left/camera_info": "sensor_msgs/msg/CameraInfo", "/right/camera_info": "sensor_msgs/msg/CameraInfo",
    "/needle/shape": "needle_interfaces/msg/NeedleShape", "/needle/measured_shape": "needle_interfaces/msg/NeedleShape",
    "/shape_error": "needle_interfaces/msg/ShapeError", "/clock": "rosgraph_msgs/msg/Clock",
}
# What a cut or damaged record raises while being parsed or decompressed (CRC mismatch is a ValueError; the lz4
# and zstd decoders raise RuntimeError / ZstdError).
CHUNK_ERRORS = (McapError, ValueError, struct.error, RuntimeError, ZstdError, UnicodeDecodeError, EOFError, KeyError)


def mcap_files(source: Path) -> list[Path]:
    """The .mcap file itself, or a bag directory's .mcap files in split order (``name_0``, ``name_1`` ...)."""
    if source.is_dir():
        def index(path: Path) -> tuple[int, str]:
            match = re.search(r"_(\d+)$", path.stem)
            return (int(match.group(1)) if match else -1, path.name)
        files = sorted(source.glob("*.mcap"), key=index)
        if not files:
            raise BagReadError(f"no .mcap files in '{source}'")
        return files
    if not source.is_file():
        raise BagReadError(f"input '{source}' does not exist")
    return [source]


@dataclass(frozen=True)
class RecordedTopic:
    name: str
    type_name: str
    offered_qos: tuple[OfferedQos, ...]
    message_count: int


@dataclass(frozen=True)
class RecordedMessage:
    topic: str
    log_time_ns: int
    data: bytes


class BagReader:
    """Topics and time range from the summaries; :meth:`messages` streams the messages."""

    def __init__(self, path: str | Path, stop_on_corrupt: bool = False) -> None:
        self.path = Path(path)
        self.stop_on_corrupt = stop_on_corrupt
        self.corrupt_chunks = 0
        self.files = self._storage_files()
        self.topics: dict[str, RecordedTopic] = {}
        self.start_time_ns: int | None = None
        self.end_time_ns: int | None = None
        for file in self.files:
            self._read_summary(file)
        if self.start_time_ns is None:
            self.start_time_ns = self.end_time_ns = 0

    def check_start_offset(self, offset: float) -> None:
        """ValueError if a run that skips the first ``offset`` [s] would find no message (0 s: always fine)."""
        length = (self.end_time_ns - self.start_time_ns) / 1e9
        if offset > length:
            raise ValueError(f"--start-offset {offset:g} s: '{self.path}' spans only {length:.3f} s")

    def _storage_files(self) -> list[Path]:
        metadata = self.path / "metadata.yaml"
        try:
            if self.path.is_dir() and metadata.is_file():
                info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
                return [self.path / Path(name).name for name in info["relative_file_paths"]]
        except (OSError, KeyError, TypeError, yaml.YAMLError) as error:
            raise BagReadError(f"cannot read recording '{self.path}': {error}") from error
        return mcap_files(self.path)

    def _read_summary(self, file: Path) -> None:
        if file.is_file() and file.stat().st_size == 0:
            raise BagReadError(f"cannot read '{file}': the file is empty (0 bytes)")
        try:
            with open(file, "rb") as stream:
                summary = make_reader(stream).get_summary()
        except FileNotFoundError as error:
            raise BagReadError(f"cannot read '{file}': listed in the bag's metadata.yaml but missing") from error
        except (OSError, *CHUNK_ERRORS) as error:
            raise BagReadError(f"cannot read '{file}': not a complete MCAP file (truncated or corrupt: "
                               f"{str(error) or type(error).__name__}); needle_mcap_recover may save its data"
                               ) from error
        if summary is None or summary.statistics is None:
            raise BagReadError(f"'{file}' has no summary (the recording was cut short): "
                               f"run needle_mcap_recover on it first")
        statistics = summary.statistics
        for channel_id, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            try:
                qos = tuple(parse_offered_qos_profiles(channel.metadata.get("offered_qos_profiles", "")))
            except ValueError:
                qos = ()
            count = statistics.channel_message_counts.get(channel_id, 0)
            known = self.topics.get(channel.topic)
            self.topics[channel.topic] = RecordedTopic(
                channel.topic, schema.name if schema else "", qos or (known.offered_qos if known else ()),
                count + (known.message_count if known else 0))
        if statistics.message_count:
            start, end = statistics.message_start_time, statistics.message_end_time
            self.start_time_ns = start if self.start_time_ns is None else min(self.start_time_ns, start)
            self.end_time_ns = end if self.end_time_ns is None else max(self.end_time_ns, end)

    def messages(self, topics: Iterable[str] | None = None, start_time_ns: int | None = None
                 ) -> Iterator[RecordedMessage]:
        """Messages of ``topics`` (all if None) logged at or after ``start_time_ns``, in log-time order
        (wrap in :func:`read_ahead` to read and decompress on another thread)."""
        selected = None if topics is None else set(topics)
        for file in self.files:
            with open(file, "rb") as stream:
                yield from self._file_messages(file, stream, selected, start_time_ns or 0)

    def _file_messages(self, file: Path, stream, topics: set[str] | None, start: int) -> Iterator[RecordedMessage]:
        """One file's messages in log-time order, chunk by chunk (a heap merges overlapping chunks); a chunk that
        fails its CRC or does not decompress is skipped and counted (or raises, with ``stop_on_corrupt``)."""
        reader = make_reader(stream)
        summary = reader.get_summary()
        if not summary.chunk_indexes:  # an unchunked file: read linearly
            for _, channel, message in reader.iter_messages(topics=topics, starting_at=start, log_time_order=True):
                yield RecordedMessage(channel.topic, message.log_time, message.data)
            return
        channels = {cid: c.topic for cid, c in summary.channels.items() if topics is None or c.topic in topics}
        heap: list = []
        for order, index in enumerate(summary.chunk_indexes):
            if index.message_end_time >= start and (topics is None or channels.keys() & index.message_index_offsets):
                heapq.heappush(heap, (index.message_start_time, 0, order, index))
        while heap:
            log_time, kind, order, item = heapq.heappop(heap)
            if kind == 1:
                yield item
                continue
            try:
                stream.seek(item.chunk_start_offset + 1 + 8)
                records = list(breakup_chunk(Chunk.read(ReadDataStream(stream)), validate_crc=True))
            except CHUNK_ERRORS as error:
                self.corrupt_chunks += 1
                if self.stop_on_corrupt:
                    raise BagReadError(f"'{file}': corrupt chunk at byte {item.chunk_start_offset} "
                                       f"({str(error) or type(error).__name__})") from error
                continue
            for position, record in enumerate(records):
                if isinstance(record, Message) and record.channel_id in channels and record.log_time >= start:
                    message = RecordedMessage(channels[record.channel_id], record.log_time, record.data)
                    heapq.heappush(heap, (record.log_time, 1, (order, position), message))

    def type_mismatches(self, expected: dict[str, str] = EXPECTED_TYPES) -> dict[str, tuple[str, str]]:
        """{topic: (recorded type, expected type)} of the recorded topics whose type is not the expected one."""
        return {topic: (recorded.type_name, expected[topic]) for topic, recorded in self.topics.items()
                if topic in expected and recorded.type_name != expected[topic]}


Item = TypeVar("Item")
_END = object()


def read_ahead(items: Iterator[Item], batch: int = 64, depth: int = 32) -> Iterator[Item]:
    """The items of ``items``, produced on a background thread up to ``depth`` batches ahead, so that reading
    and decompressing (zstd and file reads release the GIL) overlap the consumer's work. Exceptions of the
    producer are raised in the consumer; closing the generator stops the producer."""
    buffer: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                buffer.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        chunk: list = []
        try:
            for item in items:
                chunk.append(item)
                if len(chunk) >= batch:
                    if not put(chunk):
                        return
                    chunk = []
            put(chunk)
            put(_END)
        except BaseException as error:  # noqa: BLE001 - handed to the consumer
            put(error)

    thread = threading.Thread(target=produce, name="bag-read-ahead", daemon=True)
    thread.start()
    try:
        while True:
            chunk = buffer.get()
            if chunk is _END:
                return
            if isinstance(chunk, BaseException):
                raise chunk
            yield from chunk
    finally:
        stop.set()
        thread.join(timeout=1.0)
