"""Serialized messages of chosen topics from an MCAP file (rosbag2's storage), read for throughput.

An indexed file (summary with chunk indexes, as rosbag2 and the mcap writers leave it) is memory-mapped; the
chunks holding the topics are decompressed (zstd, lz4) on worker threads a few chunks ahead of the reader
(zstandard and lz4 release the GIL) and their records parsed there; message payloads are views into the map or
the decompressed chunk, never copied (the pages of uncompressed chunks are mapped on those threads too). Files
without a summary or chunk index (written without them), and files whose chunks overlap in time, are read by the
mcap library's own readers; a file without a footer fails as it does there.
"""
from __future__ import annotations

import ctypes
import mmap
import struct
import sys
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Iterable, Iterator, NamedTuple

import numpy as np

_MESSAGE, _CHUNK = 0x05, 0x06
_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct("<QQQIi")  # start, end, uncompressed size, uncompressed crc, compression length
AHEAD_BYTES = 64 << 20  # decompressed bytes in flight at most (at least two chunks)
MADV_POPULATE_READ = getattr(mmap, "MADV_POPULATE_READ", 22)  # Linux's value (Python 3.12 does not name it)


class BagMessage(NamedTuple):
    """One message: topic (with a leading '/'), schema name, log time [ns], serialized bytes (a view)."""

    topic: str
    schema: str
    log_time: int
    data: memoryview | bytes


def _topic(name: str) -> str:
    return "/" + name.lstrip("/")


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


def _chunk_messages(mapped: mmap.mmap, file: memoryview, offset: int, channels: dict[int, tuple[str, str]]
                    ) -> list[BagMessage]:
    """The messages of ``channels`` in the chunk record at ``offset`` of the mapped file, in log-time order."""
    opcode, _ = _RECORD.unpack_from(file, offset)
    if opcode != _CHUNK:
        raise ValueError(f"no chunk record at byte {offset} (opcode {opcode:#x}): the chunk index is wrong")
    position = offset + _RECORD.size
    _, _, size, _, name_length = _CHUNK_HEAD.unpack_from(file, position)
    position += _CHUNK_HEAD.size
    compression = bytes(file[position:position + name_length]).decode()
    position += name_length
    (length,) = struct.unpack_from("<Q", file, position)
    position += 8
    if compression == "":
        _populate(mapped, position, length)
    records = _decompress(compression, file[position:position + length], size)
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
        raise ValueError(f"chunk at byte {offset}: a record runs past the chunk's end")
    messages.sort(key=lambda message: message.log_time)  # stable: ties keep the file order
    return messages


def _library_messages(stream, summary, topics: list[str]) -> Iterator[BagMessage]:
    """The mcap library's log-time ordered reading (streaming when there is no summary)."""
    from mcap.reader import NonSeekingReader, SeekingReader

    stream.seek(0)
    reader = SeekingReader(stream) if summary is not None else NonSeekingReader(stream)
    for schema, channel, message in reader.iter_messages(topics=topics):
        yield BagMessage(_topic(channel.topic), schema.name if schema else "", message.log_time, message.data)


def read_messages(file: Path, topics: Iterable[str], threads: int = 2) -> Iterator[BagMessage]:
    """The messages of ``topics`` (with or without a leading '/') in log-time order. Raises what the mcap
    library raises on a corrupt file, ValueError on a chunk that cannot be read."""
    from mcap.reader import make_reader

    wanted = {_topic(topic) for topic in topics}
    with open(file, "rb") as stream:
        summary = make_reader(stream).get_summary()
        if summary is None or not summary.chunk_indexes:
            yield from _library_messages(stream, summary, sorted(wanted | {t.lstrip("/") for t in wanted}))
            return
        channels = {cid: (_topic(c.topic), summary.schemas[c.schema_id].name if c.schema_id else "")
                    for cid, c in summary.channels.items() if _topic(c.topic) in wanted}
        indexed = all(index.message_index_offsets for index in summary.chunk_indexes)
        chunks = sorted((index for index in summary.chunk_indexes
                         if not indexed or channels.keys() & index.message_index_offsets.keys()),
                        key=lambda index: (index.message_start_time, index.chunk_start_offset))
        if any(later.message_start_time < earlier.message_end_time for earlier, later in zip(chunks, chunks[1:])):
            yield from _library_messages(stream, summary, [c.topic for c in summary.channels.values()
                                                           if _topic(c.topic) in wanted])
            return
        mapped = mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) if chunks else None
    if mapped is None:
        return
    # The map is never closed here: message views keep it alive, it is unmapped when the last one goes.
    view = memoryview(mapped)
    pending: deque[tuple[Future, int]] = deque()
    in_flight = 0
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="mcap-chunk") as pool:
        try:
            for index in chunks:
                while pending and (len(pending) >= 2 and in_flight + index.uncompressed_size > AHEAD_BYTES):
                    future, size = pending.popleft()
                    in_flight -= size
                    yield from future.result()
                pending.append((pool.submit(_chunk_messages, mapped, view, index.chunk_start_offset, channels),
                                index.uncompressed_size))
                in_flight += index.uncompressed_size
            while pending:
                future, size = pending.popleft()
                yield from future.result()
        finally:
            for future, _ in pending:
                future.cancel()
