"""Reading a rosbag2 MCAP recording (single .mcap file or bag directory) for playback: topics, QoS, messages.

A bag directory's files are taken from metadata.yaml (``relative_file_paths``) when present, else all its .mcap
files in split order. Messages come in log-time order within each file and files in order, as serialized bytes.
"""
from __future__ import annotations

import queue
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, TypeVar

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader

from needle_sim_ros.recording.qos import OfferedQos, parse_offered_qos_profiles


class BagReadError(RuntimeError):
    """The recording cannot be read; the message names the file."""


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

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.files = self._storage_files()
        self.topics: dict[str, RecordedTopic] = {}
        self.start_time_ns: int | None = None
        self.end_time_ns: int | None = None
        for file in self.files:
            self._read_summary(file)
        if self.start_time_ns is None:
            self.start_time_ns = self.end_time_ns = 0

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
        try:
            with open(file, "rb") as stream:
                summary = make_reader(stream).get_summary()
        except (OSError, McapError, ValueError) as error:
            raise BagReadError(f"cannot read '{file}': {error}") from error
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
        selected = None if topics is None else list(topics)
        for file in self.files:
            with open(file, "rb") as stream:
                for _, channel, message in make_reader(stream).iter_messages(
                        topics=selected, starting_at=start_time_ns, log_time_order=True):
                    yield RecordedMessage(channel.topic, message.log_time, message.data)


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
