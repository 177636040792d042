"""rosbag2-compatible MCAP recording of already CDR-serialized messages (``ros2 bag info/play``, Foxglove).

Layout as rosbag2_storage_mcap writes it: profile ``ros2``; a schema per type (``ros2msg``,
:mod:`.message_definitions`); a channel per topic (``cdr``, metadata ``offered_qos_profiles``, ``topic_type_hash``);
zstd/lz4 chunks with message and chunk indexes, statistics and summary; on close a ``rosbag2`` metadata record
(:mod:`.bag_metadata`). Records go straight to the OS and a chunk is written at ``chunk_size`` bytes or
``chunk_interval`` of log time, so after SIGKILL the file holds every complete chunk (:mod:`.recovery`). A path
ending in ``.mcap`` is one file, any other a bag directory (``<name>_<i>.mcap`` + metadata.yaml), split by size or time.
"""
from __future__ import annotations

import errno
import os
import struct
import zlib
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd, Footer, Header,
                          Metadata, MetadataIndex, Schema, Statistics, SummaryOffset)
from mcap.writer import LIBRARY_IDENTIFIER, MCAP0_MAGIC

from needle_sim_ros.recording.bag_metadata import (METADATA_RECORD_KEY, METADATA_RECORD_NAME, FileSummary,
                                                   TopicSummary, bag_metadata, metadata_record_text,
                                                   metadata_yaml_text)
from needle_sim_ros.recording.message_definitions import SCHEMA_ENCODING, message_definition, type_description_hash
from needle_common.qos import OfferedQos, offered_qos_profiles_yaml

PROFILE = "ros2"
LIBRARY = f"needle_sim_ros recorder; {LIBRARY_IDENTIFIER}"
COMPRESSION = ("zstd", "lz4", "none")  # WriterOptions.compression
_MESSAGE = struct.Struct("<BQHIQQ")  # a Message record: opcode, length, channel id, sequence, log and publish time
_INDEX_HEAD = struct.Struct("<BQHI")  # a MessageIndex record: opcode, length, channel id, entries' byte length


class RecordingError(RuntimeError):
    """The recording cannot be written (unwritable path, existing output, disk full ...); names the file."""


@dataclass(frozen=True)
class WriterOptions:
    """How the MCAP files are written.

    compression: ``zstd`` (level 1), ``lz4`` or ``none``. chunk_size: uncompressed bytes [B] per chunk.
    chunk_interval: log-time span [s] after which a chunk is written (bounds a crash's loss); 0 = by size only.
    max_file_size [B], max_file_duration [s]: a bag directory continues in a new file beyond them; 0 = never.
    overwrite: replace an existing output instead of refusing.
    background: compress each chunk on a worker thread and write it with the next message (the same file)."""

    compression: str = "zstd"
    chunk_size: int = 1 << 20
    chunk_interval: float = 1.0
    max_file_size: int = 0
    max_file_duration: float = 0.0
    overwrite: bool = False
    background: bool = False

    def __post_init__(self) -> None:
        if self.compression not in COMPRESSION:
            raise ValueError(f"compression '{self.compression}' is not one of {', '.join(COMPRESSION)}")
        for name in ("chunk_size", "chunk_interval", "max_file_size", "max_file_duration"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1 byte, got {self.chunk_size}")


@dataclass
class _Channel:
    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    metadata: dict[str, str]
    message_count: int = 0


class _UnbufferedFile:
    """Output stream that hands every record to the OS at once and counts the bytes written."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.position = 0
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
            self.position += written

    def close(self) -> None:
        os.close(self._fd)


class _McapFile:
    """One MCAP file laid out as ``mcap.Writer`` lays it out (chunks with message indexes; a summary with schemas,
    channels, statistics, chunk, metadata and attachment indexes, offsets and CRC), the message records packed here
    (faster: docs/design_notes.md). Schemas and channels are written before the chunks that use them."""

    def __init__(self, path: Path, options: WriterOptions) -> None:
        self.stream = _UnbufferedFile(path)
        self.options = options
        self.channel_ids: dict[str, int] = {}
        self.schema_ids: dict[tuple[str, str, bytes], int] = {}
        self.counts: dict[int, int] = defaultdict(int)
        self.first_log_time_ns: int | None = None
        self.last_log_time_ns = 0
        self._statistics = Statistics(0, 0, self.counts, 0, 0, 0, 0, 0, 0)
        self._summary: dict[int, list] = {  # the summary section's groups in mcap.Writer's order
            Opcode.SCHEMA: [], Opcode.CHANNEL: [], Opcode.STATISTICS: [self._statistics], Opcode.CHUNK_INDEX: [],
            Opcode.ATTACHMENT_INDEX: [], Opcode.METADATA_INDEX: []}
        self._chunk: list[bytes] = []
        self._chunk_size = 0
        self._chunk_times = (0, 0)
        self._index: dict[int, list[tuple[int, int]]] = {}
        self._compress = {"zstd": zstandard.ZstdCompressor(level=1).compress, "lz4": lz4.frame.compress}.get(
            options.compression)
        self._worker = ThreadPoolExecutor(1, "mcap-compress") if options.background and self._compress else None
        self._pending: tuple | None = None  # a chunk being compressed: (future, its fields)
        self.stream.write(MCAP0_MAGIC)
        self._write(Header(PROFILE, LIBRARY))

    @property
    def buffered(self) -> int:
        """Bytes of messages in the open chunk."""
        return self._chunk_size

    @property
    def chunk_start_ns(self) -> int | None:
        return self._chunk_times[0] if self._chunk else None

    def _write(self, *records) -> int:
        """Write records (after a chunk being compressed); returns the offset of the first."""
        self.write_pending()
        return self._records(*records)

    def _records(self, *records) -> int:
        builder, offset = RecordBuilder(), self.stream.position
        for record in records:
            record.write(builder)
        self.stream.write(builder.end())
        return offset

    def add_channel(self, channel: _Channel) -> None:
        """Write the channel, after its schema unless the file has that schema already."""
        key = (channel.schema_name, channel.schema_encoding, channel.schema_data)
        if key not in self.schema_ids:
            schema = Schema(id=len(self.schema_ids) + 1, name=key[0], encoding=key[1], data=key[2])
            self.schema_ids[key] = schema.id
            self._summary[Opcode.SCHEMA].append(schema)
            self._write(schema)
        record = Channel(id=len(self.channel_ids) + 1, topic=channel.topic, message_encoding=channel.message_encoding,
                         schema_id=self.schema_ids[key], metadata=channel.metadata)
        self.channel_ids[channel.topic] = record.id
        self._summary[Opcode.CHANNEL].append(record)
        self._write(record)

    def add_static(self, record: Metadata | Attachment) -> None:
        """A metadata record or an attachment, indexed in the summary."""
        offset = self._write(record)
        length = self.stream.position - offset
        if isinstance(record, Metadata):
            self._summary[Opcode.METADATA_INDEX].append(MetadataIndex(offset, length, record.name))
        else:
            self._summary[Opcode.ATTACHMENT_INDEX].append(AttachmentIndex(
                offset=offset, length=length, create_time=record.create_time, log_time=record.log_time,
                data_size=len(record.data), name=record.name, media_type=record.media_type))

    def add_messages(self, channel_id: int, messages: list[bytes], log_time_ns: int, publish_time_ns: int,
                     sequence: int) -> None:
        """Append messages received at one time to the open chunk; the chunk is written when it holds
        ``chunk_size`` bytes or spans ``chunk_interval`` of log time."""
        if self._pending is not None and self._pending[0].done():
            self.write_pending()
        start, end = self._chunk_times if self._chunk else (log_time_ns, log_time_ns)
        self._chunk_times = (min(start, log_time_ns), max(end, log_time_ns))
        index, size, chunk = self._index.setdefault(channel_id, []), self._chunk_size, self._chunk
        for data in messages:
            index.append((log_time_ns, size))
            chunk += (_MESSAGE.pack(Opcode.MESSAGE, 22 + len(data), channel_id, sequence, log_time_ns,
                                    publish_time_ns), data)
            size += 31 + len(data)
        self._chunk_size = size
        self.counts[channel_id] += len(messages)
        self.first_log_time_ns = log_time_ns if self.first_log_time_ns is None else \
            min(self.first_log_time_ns, log_time_ns)
        self.last_log_time_ns = max(self.last_log_time_ns, log_time_ns)
        interval = self.options.chunk_interval
        if size >= self.options.chunk_size or (interval and log_time_ns - start >= interval * 1e9):
            self.flush()

    def flush(self) -> None:
        """Write the open chunk and its message indexes (with ``background``: compress it on the worker; it is
        written by the next write, :meth:`write_pending`)."""
        self.write_pending()
        if not self._chunk:
            return
        data = b"".join(self._chunk)
        fields = (len(data), self._chunk_times, self._index)
        self._chunk, self._chunk_size, self._index = [], 0, {}
        if self._worker is None:
            self._write_chunk(self._pack(data), *fields)
        else:
            self._pending = (self._worker.submit(self._pack, data), *fields)

    def _pack(self, data: bytes) -> tuple[bytes, int]:
        """The chunk's records compressed, and their CRC."""
        return (self._compress(data) if self._compress else data), zlib.crc32(data)

    def write_pending(self) -> None:
        """Write the chunk being compressed, if any (waits for it)."""
        if self._pending is not None:
            future, *fields = self._pending
            self._pending = None
            self._write_chunk(future.result(), *fields)

    def _write_chunk(self, packed: tuple[bytes, int], size: int, times: tuple[int, int],
                     index: dict[int, list[tuple[int, int]]]) -> None:
        compressed, crc = packed
        chunk = Chunk(compression=self.options.compression if self._compress else "", data=compressed,
                      message_start_time=times[0], message_end_time=times[1], uncompressed_crc=crc,
                      uncompressed_size=size)
        start = self._records(chunk)
        indexes = position = self.stream.position
        offsets, records = {}, []
        for channel_id, entries in index.items():
            offsets[channel_id] = position
            records.append(_message_index(channel_id, entries))
            position += len(records[-1])
        self.stream.write(b"".join(records))
        self._summary[Opcode.CHUNK_INDEX].append(ChunkIndex(
            chunk_start_offset=start, chunk_length=indexes - start, message_index_offsets=offsets,
            message_index_length=self.stream.position - indexes, compression=chunk.compression,
            compressed_size=len(compressed), uncompressed_size=size, message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time))

    def finish(self) -> None:
        """Write the open chunk, the data end, the summary and the footer, and close the file."""
        self.flush()
        self._write(DataEnd(0))
        if self._worker is not None:
            self._worker.shutdown()
        stats, summary = self._statistics, self._summary
        stats.message_count = sum(self.counts.values())
        stats.message_start_time, stats.message_end_time = self.first_log_time_ns or 0, self.last_log_time_ns
        stats.schema_count, stats.channel_count = len(summary[Opcode.SCHEMA]), len(summary[Opcode.CHANNEL])
        stats.chunk_count, stats.metadata_count, stats.attachment_count = (
            len(summary[op]) for op in (Opcode.CHUNK_INDEX, Opcode.METADATA_INDEX, Opcode.ATTACHMENT_INDEX))
        start, builder, groups = self.stream.position, RecordBuilder(), []
        for opcode, records in summary.items():
            group = builder.count
            for record in records:
                record.write(builder)
            groups.append(SummaryOffset(opcode, start + group, builder.count - group))
        offsets = start + builder.count
        for group in groups:
            group.write(builder)
        data = builder.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, start, offsets), zlib.crc32(data))
        self.stream.write(data)
        self._write(Footer(start, offsets, crc))
        self.stream.write(MCAP0_MAGIC)
        self.stream.close()


def _message_index(channel_id: int, entries: list[tuple[int, int]]) -> bytes:
    """The MessageIndex record of a chunk's (log time, offset) entries of one channel: the bytes of
    :class:`mcap.records.MessageIndex`, packed at once (its writer packs each number apart: ~5 ms per run)."""
    data = np.array(entries, dtype="<u8").tobytes()
    return _INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + len(data), channel_id, len(data)) + data


def _describe(error: OSError, path: Path) -> str:
    reason = "disk full" if error.errno == errno.ENOSPC else (error.strerror or str(error))
    return f"cannot write recording file '{path}': {reason} [errno {error.errno}]"


class McapBagWriter:
    """Writes serialized messages into a rosbag2-compatible MCAP file or bag directory; ``custom_data`` goes into the
    bag metadata (``ros2 bag info``). A write failure raises RecordingError and stops the recording (what was
    written stays recoverable)."""

    def __init__(self, path: str | os.PathLike, options: WriterOptions = WriterOptions(),
                 custom_data: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        self.options = options
        self.custom_data = dict(custom_data or {})
        self.is_directory = self.path.suffix != ".mcap"
        if not self.is_directory and (options.max_file_size or options.max_file_duration):
            raise ValueError(f"splitting by max_file_size/max_file_duration needs a bag directory path "
                             f"(without .mcap suffix), got '{self.path}'")
        self._channels: dict[str, _Channel] = {}
        self._static: list[Metadata | Attachment] = []  # written into every file of the bag
        self._files: list[FileSummary] = []
        self._file: _McapFile | None = None
        self._failure: str | None = None
        self._prepare_output()
        self._open_next_file()

    # --- public API -------------------------------------------------------------------------------------------
    @property
    def files(self) -> list[Path]:
        """Storage files written so far (the open one included)."""
        names = [f.path for f in self._files] + ([self._file.stream.path.name] if self._file else [])
        return [self._file_path(name) for name in names]

    @property
    def topics(self) -> list[str]:
        return list(self._channels)

    @property
    def message_count(self) -> int:
        return sum(c.message_count for c in self._channels.values())

    def add_topic(self, topic: str, type_name: str, offered_qos: Sequence[OfferedQos] = (OfferedQos(),)) -> None:
        """Register a topic of ROS 2 type ``pkg/msg/Type`` (schema from the installed .msg files)."""
        self.add_channel(topic, type_name, SCHEMA_ENCODING, message_definition(type_name).encode(),
                         {"offered_qos_profiles": offered_qos_profiles_yaml(offered_qos),
                          "topic_type_hash": type_description_hash(type_name)})

    def add_channel(self, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes,
                    metadata: dict[str, str], message_encoding: str = "cdr") -> None:
        """Register a topic with an explicit schema and channel metadata (e.g. copied from another file)."""
        channel = _Channel(topic, schema_name, schema_encoding, bytes(schema_data), message_encoding, dict(metadata))
        known = self._channels.get(topic)
        if known is not None:
            if (known.schema_name, known.schema_data) != (channel.schema_name, channel.schema_data):
                raise ValueError(f"topic '{topic}' is already recorded with type '{known.schema_name}'")
            return
        self._channels[topic] = channel
        self._guarded(self._file.add_channel, channel)

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None,
              sequence: int = 0) -> None:
        """Append one serialized message; ``log_time_ns`` is the receive time (rosbag2's recv_timestamp)."""
        self.write_many(topic, [data], log_time_ns, publish_time_ns, sequence)

    def write_many(self, topic: str, messages: list[bytes], log_time_ns: int, publish_time_ns: int | None = None,
                   sequence: int = 0) -> None:
        """Append serialized messages of one topic received (and published) at one time."""
        channel = self._channels.get(topic)
        if channel is None:
            raise KeyError(f"topic '{topic}' was not added to the recording")
        if messages:
            self._guarded(self._write, channel, messages, int(log_time_ns),
                          int(log_time_ns if publish_time_ns is None else publish_time_ns), sequence)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Key-value metadata record (Foxglove's metadata panel); repeated in every file of a split bag."""
        self._add_static(Metadata(name=name, metadata={str(k): str(v) for k, v in data.items()}))

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time_ns: int = 0) -> None:
        """Attachment (e.g. a parameter file); repeated in every file of a split bag."""
        self._add_static(Attachment(create_time=int(log_time_ns), log_time=int(log_time_ns), name=name,
                                    media_type=media_type, data=bytes(data)))

    def _add_static(self, record: Metadata | Attachment) -> None:
        self._static.append(record)
        self._guarded(self._file.add_static, record)

    def flush_due(self, now_ns: int) -> None:
        """Write the open chunk if it has waited ``chunk_interval`` (call periodically when messages are sparse)."""
        file = self._file
        if file and file.chunk_start_ns is not None and self.options.chunk_interval > 0 \
                and now_ns - file.chunk_start_ns >= self.options.chunk_interval * 1e9:
            self._guarded(file.flush)

    def close(self) -> list[Path]:
        """Write the summary and footer (and metadata.yaml of a bag directory); returns the files written."""
        if self._file is not None:
            if self._failure is None:
                self._guarded(self._finish_file)
            else:
                self._abandon_file()
        return self.files

    def __enter__(self) -> "McapBagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- files ------------------------------------------------------------------------------------------------
    def _file_path(self, name: str) -> Path:
        return self.path / name if self.is_directory else self.path

    def _prepare_output(self) -> None:
        target = self.path
        try:
            if self.is_directory:
                if target.exists() and any(target.iterdir()):
                    if not self.options.overwrite:
                        raise RecordingError(f"recording directory '{target}' already exists and is not empty")
                    for old in [*target.glob("*.mcap"), target / "metadata.yaml"]:
                        old.unlink(missing_ok=True)
                target.mkdir(parents=True, exist_ok=True)
            else:
                if target.exists() and not self.options.overwrite:
                    raise RecordingError(f"recording file '{target}' already exists")
                target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise RecordingError(_describe(error, target)) from error

    def _open_next_file(self) -> None:
        name = f"{self.path.name}_{len(self._files)}.mcap" if self.is_directory else self.path.name
        path = self._file_path(name)
        try:
            self._file = _McapFile(path, self.options)
        except OSError as error:
            self._failure = _describe(error, path)
            raise RecordingError(self._failure) from error
        self._guarded(self._start_file)

    def _start_file(self) -> None:
        for record in self._static:
            self._file.add_static(record)
        for channel in self._channels.values():
            self._file.add_channel(channel)

    def _summary(self, file: _McapFile) -> FileSummary:
        count = sum(file.counts.values())
        start = file.first_log_time_ns or 0
        return FileSummary(file.stream.path.name, start, file.last_log_time_ns - start if count else 0, count)

    def _topic_summaries(self) -> list[TopicSummary]:
        return [TopicSummary(c.topic, c.schema_name, c.message_encoding, c.metadata.get("offered_qos_profiles", ""),
                             c.metadata.get("topic_type_hash", ""), c.message_count)
                for c in self._channels.values()]

    def _finish_file(self) -> None:
        file = self._file
        summary = self._summary(file)
        metadata = bag_metadata(self._topic_summaries(), [*self._files, summary], self.custom_data)
        file.add_static(Metadata(name=METADATA_RECORD_NAME,
                                 metadata={METADATA_RECORD_KEY: metadata_record_text(metadata)}))
        file.finish()
        self._files.append(summary)
        self._file = None
        if self.is_directory:
            temporary = self.path / "metadata.yaml.tmp"
            temporary.write_text(metadata_yaml_text(metadata))
            os.replace(temporary, self.path / "metadata.yaml")

    def _abandon_file(self) -> None:
        try:
            self._file.stream.close()
        except OSError:
            pass
        self._files.append(self._summary(self._file))
        self._file = None

    # --- records ----------------------------------------------------------------------------------------------
    def _guarded(self, action, *arguments) -> None:
        if self._failure is not None:
            raise RecordingError(f"recording stopped after an earlier error: {self._failure}")
        try:
            action(*arguments)
        except OSError as error:
            self._failure = _describe(error, self._file.stream.path if self._file else self.path)
            raise RecordingError(self._failure) from error

    def _split_due(self, file: _McapFile, log_time_ns: int) -> bool:
        if file.first_log_time_ns is None:
            return False
        too_big = self.options.max_file_size and file.stream.position + file.buffered >= self.options.max_file_size
        too_long = self.options.max_file_duration and \
            log_time_ns - file.first_log_time_ns >= self.options.max_file_duration * 1e9
        return bool(too_big or too_long)

    def _write(self, channel: _Channel, messages: list[bytes], log_time_ns: int, publish_time_ns: int,
               sequence: int) -> None:
        if self.is_directory:
            self._file.write_pending()  # the file's size counts it
            if self._split_due(self._file, log_time_ns):
                self._finish_file()
                self._open_next_file()
        self._file.add_messages(self._file.channel_ids[channel.topic], messages, log_time_ns, publish_time_ns, sequence)
        channel.message_count += len(messages)
