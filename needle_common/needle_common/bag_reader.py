"""Reading a rosbag2 MCAP recording (an .mcap file or a bag directory): topics, QoS, time range and messages.

A bag directory's files are taken from metadata.yaml (``relative_file_paths``) when present, else all its .mcap
files in split order (``name_0``, ``name_1`` ... ``name_10``). Messages come in log-time order within each file and
files in that order, as serialized bytes. An indexed file (summary with chunk indexes, as rosbag2 and the mcap
writers leave it) is memory-mapped; the chunks holding the wanted topics are checked (CRC) and decompressed (zstd,
lz4) on worker threads a few chunks ahead of the reader (zstandard, lz4 and zlib release the GIL) and their records
parsed there; message payloads are views into the map or the decompressed chunk, never copied (the pages of
uncompressed chunks are mapped on those threads too), and chunks that overlap in time are merged. A chunk that
cannot be read (bit flip: CRC or decompression error) is skipped and counted in ``corrupt_chunks``, or stops the
reading with :class:`BagReadError` if asked. Files without a chunk index, or without a summary (``require_summary``
False), are read by the mcap library's own readers.
"""
from __future__ import annotations

import ctypes
import heapq
import mmap
import re
import struct
import sys
import zlib
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator, NamedTuple

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, SeekingReader, make_reader
from zstandard import ZstdError

from needle_common.qos import OfferedQos, parse_offered_qos_profiles


class BagReadError(RuntimeError):
    """The recording cannot be read; the message names the file."""


# What a cut or damaged record raises while being parsed or decompressed (CRC mismatch is a ValueError; the lz4
# and zstd decoders raise RuntimeError / ZstdError).
CHUNK_ERRORS = (McapError, ValueError, struct.error, RuntimeError, ZstdError, UnicodeDecodeError, EOFError, KeyError)

_MESSAGE, _CHUNK = 0x05, 0x06
_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct("<QQQIi")  # start, end, uncompressed size, uncompressed crc, compression length
AHEAD_BYTES = 64 << 20  # decompressed bytes in flight at most (at least two chunks)
MADV_POPULATE_READ = getattr(mmap, "MADV_POPULATE_READ", 22)  # Linux's value (Python 3.12 does not name it)


def bag_files(source: Path) -> list[Path]:
    """The .mcap file itself, or a bag directory's files: those metadata.yaml lists, in its order, else its .mcap
    files in split order (``name_0``, ``name_1`` ...)."""
    metadata = source / "metadata.yaml"
    if source.is_dir() and metadata.is_file():
        try:
            info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
            return [source / Path(name).name for name in info["relative_file_paths"]]
        except (OSError, KeyError, TypeError, yaml.YAMLError) as error:
            raise BagReadError(f"cannot read recording '{source}': {error}") from error
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


class BagMessage(NamedTuple):
    """One message: topic (with a leading '/'), schema name, log time [ns], serialized bytes (a view)."""

    topic: str
    schema: str
    log_time_ns: int
    data: memoryview | bytes


def absolute_topic(name: str) -> str:
    """``name`` with one leading '/' (how the bag names its topics)."""
    return "/" + name.lstrip("/")


class BagReader:
    """Topics and time range from the summaries (topic names with a leading '/'); :meth:`messages` streams the
    messages. ``require_summary`` False: files without a summary are read too, and ``summarized`` says whether
    ``topics`` and the time range cover every file."""

    def __init__(self, path: str | Path, stop_on_corrupt: bool = False, require_summary: bool = True,
                 threads: int = 2) -> None:
        self.path = Path(path)
        self.stop_on_corrupt = stop_on_corrupt
        self.threads = threads
        self.corrupt_chunks = 0
        self.summarized = True
        self.files = bag_files(self.path)
        self.topics: dict[str, RecordedTopic] = {}
        self._summaries: dict[Path, object] = {}  # each file's summary, read once (parsed in Python)
        self.start_time_ns: int | None = None
        self.end_time_ns: int | None = None
        for file in self.files:
            self._read_summary(file, require_summary)
        if self.start_time_ns is None:
            self.start_time_ns = self.end_time_ns = 0

    def check_start_offset(self, offset: float) -> None:
        """ValueError if a run that skips the first ``offset`` [s] would find no message (0 s: always fine)."""
        length = (self.end_time_ns - self.start_time_ns) / 1e9
        if offset > length:
            raise ValueError(f"--start-offset {offset:g} s: '{self.path}' spans only {length:.3f} s")

    def type_mismatches(self, expected: dict[str, str]) -> dict[str, tuple[str, str]]:
        """{topic: (recorded type, expected type)} of the recorded topics whose type is not the expected one."""
        return {topic: (recorded.type_name, expected[topic]) for topic, recorded in self.topics.items()
                if topic in expected and recorded.type_name != expected[topic]}

    def _read_summary(self, file: Path, require_summary: bool) -> None:
        if file.is_file() and file.stat().st_size == 0:
            raise BagReadError(f"cannot read '{file}': the file is empty (0 bytes)")
        try:
            with open(file, "rb") as stream:
                summary = self._summaries[file] = make_reader(stream).get_summary()
        except FileNotFoundError as error:
            raise BagReadError(f"cannot read '{file}': listed in the bag's metadata.yaml but missing") from error
        except (OSError, *CHUNK_ERRORS) as error:
            if not require_summary:
                self.summarized = False
                return
            raise BagReadError(f"cannot read '{file}': not a complete MCAP file (truncated or corrupt: "
                               f"{str(error) or type(error).__name__}); needle_mcap_recover may save its data"
                               ) from error
        if summary is None or summary.statistics is None:
            if not require_summary:
                self.summarized = False
                return
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
            name = absolute_topic(channel.topic)
            known = self.topics.get(name)
            self.topics[name] = RecordedTopic(name, schema.name if schema else "",
                                              qos or (known.offered_qos if known else ()),
                                              count + (known.message_count if known else 0))
        if statistics.message_count:
            start, end = statistics.message_start_time, statistics.message_end_time
            self.start_time_ns = start if self.start_time_ns is None else min(self.start_time_ns, start)
            self.end_time_ns = end if self.end_time_ns is None else max(self.end_time_ns, end)

    def messages(self, topics: Iterable[str] | None = None, start_time_ns: int | None = None
                 ) -> Iterator[BagMessage]:
        """Messages of ``topics`` (with or without a leading '/'; all if None) logged at or after
        ``start_time_ns``, in log-time order within each file, files in order. Raises BagReadError naming the
        file for a file that cannot be read (and, with ``stop_on_corrupt``, for a corrupt chunk)."""
        wanted = None if topics is None else {absolute_topic(topic) for topic in topics}
        for file in self.files:
            try:
                yield from self._file_messages(file, wanted, start_time_ns or 0)
            except BagReadError:
                raise
            except (OSError, *CHUNK_ERRORS) as error:
                raise BagReadError(f"cannot read '{file}': {str(error) or type(error).__name__}") from error

    def _file_messages(self, file: Path, wanted: set[str] | None, start: int) -> Iterator[BagMessage]:
        with open(file, "rb") as stream:
            summary = self._summaries[file] if file in self._summaries else make_reader(stream).get_summary()
            if summary is None or not summary.chunk_indexes:
                yield from _library_messages(stream, summary, wanted, start)
                return
            channels = {cid: (absolute_topic(c.topic), summary.schemas[c.schema_id].name if c.schema_id else "")
                        for cid, c in summary.channels.items() if wanted is None or absolute_topic(c.topic) in wanted}
            indexed = all(index.message_index_offsets for index in summary.chunk_indexes)
            chunks = sorted((index for index in summary.chunk_indexes if index.message_end_time >= start
                             and (not indexed or channels.keys() & index.message_index_offsets.keys())),
                            key=lambda index: (index.message_start_time, index.chunk_start_offset))
            if not chunks:
                return
            mapped = mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
        # The map is never closed here: message views keep it alive, it is unmapped when the last one goes.
        view = memoryview(mapped)
        starts = [index.message_start_time for index in chunks[1:]] + [None]  # no later chunk starts before these
        pending: deque[tuple[Future, int, int | None]] = deque()
        heap: list[tuple[int, int, int, BagMessage]] = []  # (log time, chunk order, position, message)
        in_flight = 0
        with ThreadPoolExecutor(max_workers=self.threads, thread_name_prefix="mcap-chunk") as pool:
            try:
                for order, (index, following) in enumerate(zip(chunks, starts)):
                    while len(pending) >= 2 and in_flight + index.uncompressed_size > AHEAD_BYTES:
                        in_flight -= pending[0][1]
                        yield from self._merge(file, pending.popleft(), heap, start)
                    future = pool.submit(_chunk_messages, mapped, view, index.chunk_start_offset, channels, order)
                    pending.append((future, index.uncompressed_size, following))
                    in_flight += index.uncompressed_size
                while pending:
                    yield from self._merge(file, pending.popleft(), heap, start)
            finally:
                for future, _, _ in pending:
                    future.cancel()

    def _merge(self, file: Path, job: tuple[Future, int, int | None], heap: list, start: int) -> Iterator[BagMessage]:
        """Add a read chunk's messages (from ``start`` on) to the heap, then yield those no later chunk can precede
        (older than the next chunk's first message: chunks that overlap in time are merged). A corrupt chunk is
        counted (or raises, with ``stop_on_corrupt``)."""
        future, _, following = job
        try:
            order, messages = future.result()
        except _ChunkError as error:
            self.corrupt_chunks += 1
            if self.stop_on_corrupt:
                raise BagReadError(f"'{file}': corrupt chunk at byte {error.offset} ({error.reason})") from error
            messages = []
        for position, message in enumerate(messages):
            if message.log_time_ns >= start:
                heapq.heappush(heap, (message.log_time_ns, order, position, message))
        while heap and (following is None or heap[0][0] < following):
            yield heapq.heappop(heap)[3]


class _ChunkError(Exception):
    """A chunk that fails its CRC or cannot be decompressed or parsed."""

    def __init__(self, offset: int, error: Exception) -> None:
        super().__init__(offset, error)
        self.offset = offset
        self.reason = str(error) or type(error).__name__


def _library_messages(stream, summary, wanted: set[str] | None, start: int) -> Iterator[BagMessage]:
    """The mcap library's log-time ordered reading (streaming when there is no summary)."""
    stream.seek(0)
    reader = SeekingReader(stream) if summary is not None else NonSeekingReader(stream)
    for schema, channel, message in reader.iter_messages(start_time=start or None, log_time_order=True):
        topic = absolute_topic(channel.topic)
        if wanted is None or topic in wanted:
            yield BagMessage(topic, schema.name if schema else "", message.log_time, message.data)


def _decompress(compression: str, data: memoryview, size: int) -> memoryview | bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.decompress(data)
    raise ValueError(f"unsupported chunk compression '{compression}'")


def _libc_madvise() -> Callable[[int, int, int], int] | None:
    """libc's ``madvise`` through ctypes, which releases the GIL during the call (``mmap.madvise`` holds it: ~0.6 ms
    per pair that no other thread of the process could run); None off Linux."""
    if sys.platform != "linux":
        return None
    function = ctypes.CDLL(None, use_errno=True).madvise
    function.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    function.restype = ctypes.c_int
    return function


_MADVISE = _libc_madvise()


def _populate(mapped: mmap.mmap, start: int, length: int) -> None:
    """Map the pages of an uncompressed chunk here (a worker thread, without the GIL), so that the first reader of
    the pixels (the measurement) does not take the page faults (~0.5 ms per 1440x1080 image); Linux >= 5.14, else
    nothing."""
    if _MADVISE is not None:
        aligned = start - start % mmap.PAGESIZE
        pages = np.frombuffer(mapped, np.uint8)  # its address; the map stays mapped while the array exists
        _MADVISE(pages.ctypes.data + aligned, min(length + start - aligned, len(mapped) - aligned), MADV_POPULATE_READ)


def _chunk_messages(mapped: mmap.mmap, file: memoryview, offset: int, channels: dict[int, tuple[str, str]],
                    order: int) -> tuple[int, list[BagMessage]]:
    """The messages of ``channels`` in the chunk record at ``offset`` of the mapped file, in log-time order;
    _ChunkError for a chunk that fails its CRC, does not decompress or does not parse."""
    try:
        opcode, _ = _RECORD.unpack_from(file, offset)
        if opcode != _CHUNK:
            raise ValueError(f"no chunk record (opcode {opcode:#x}): the chunk index is wrong")
        position = offset + _RECORD.size
        _, _, size, crc, name_length = _CHUNK_HEAD.unpack_from(file, position)
        position += _CHUNK_HEAD.size
        compression = bytes(file[position:position + name_length]).decode()
        position += name_length
        (length,) = struct.unpack_from("<Q", file, position)
        position += 8
        if position + length > len(file):
            raise ValueError("the chunk runs past the end of the file")
        if compression == "":
            _populate(mapped, position, length)
        records = _decompress(compression, file[position:position + length], size)
        if crc and zlib.crc32(records) != crc:
            raise ValueError("CRC mismatch")
        view = memoryview(records)
        messages, position, end = [], 0, len(view)
        while position < end:
            opcode, length = _RECORD.unpack_from(view, position)
            position += _RECORD.size
            if opcode == _MESSAGE:
                channel, _, log_time, _ = _MESSAGE_HEAD.unpack_from(view, position)
                if channel in channels:
                    topic, schema = channels[channel]
                    messages.append(BagMessage(topic, schema, log_time,
                                               view[position + _MESSAGE_HEAD.size:position + length]))
            position += length
        if position != end:
            raise ValueError("a record runs past the chunk's end")
    except CHUNK_ERRORS as error:
        raise _ChunkError(offset, error) from error
    messages.sort(key=lambda message: message.log_time_ns)  # stable: ties keep the file order
    return order, messages
