"""Recovery of an MCAP recording that was cut short (killed writer, full disk): no summary, no footer.

The data section is read record by record (``opcode (1 B) | length (8 B) | body``) up to the first incomplete or
corrupt record (a chunk counts if it decompresses and matches its CRC); what was found is rewritten by
:class:`.McapBagWriter` into a valid, indexed file with a regenerated ``rosbag2`` record.
CLI: ``needle_mcap_recover in.mcap out.mcap`` (a bag directory as input: all its .mcap files, in order).
"""
from __future__ import annotations

import argparse
import io
import struct
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from needle_common.cli_types import command_status
from needle_common.output_files import check_output_dir, check_output_file

from needle_sim_ros.recording.bag_metadata import METADATA_RECORD_NAME
from needle_common.bag_reader import CHUNK_ERRORS, BagReadError, bag_files
from needle_sim_ros.recording.mcap_writer import COMPRESSION, PROFILE, McapBagWriter, RecordingError, WriterOptions

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")


class RecoveryError(RuntimeError):
    """The input is not a recoverable MCAP file."""


@dataclass
class RecoveryReport:
    """What was recovered: messages, complete chunks read, and bytes of an incomplete or corrupt tail dropped."""

    messages: int = 0
    chunks: int = 0
    topics: int = 0
    metadata: int = 0
    attachments: int = 0
    discarded_bytes: int = 0
    complete_input: bool = True

    def describe(self) -> str:
        tail = ("the input was complete" if self.complete_input
                else f"discarded an incomplete tail of {self.discarded_bytes} bytes")
        return (f"recovered {self.messages} messages on {self.topics} topics from {self.chunks} chunks, "
                f"{self.metadata} metadata records and {self.attachments} attachments; {tail}")


def _records(path: Path, report: RecoveryReport) -> Iterator[object]:
    """The complete records of one MCAP file, chunks broken up into their records."""
    try:
        with open(path, "rb") as source:
            size = source.seek(0, io.SEEK_END)
            source.seek(0)
            if source.read(len(MAGIC)) != MAGIC:
                raise RecoveryError(f"'{path}' is not an MCAP file (bad magic)")
            good_end = source.tell()
            while len(head := source.read(_RECORD_HEAD.size)) == _RECORD_HEAD.size:
                opcode, length = _RECORD_HEAD.unpack(head)
                if length > size - source.tell():
                    break
                body = source.read(length)
                profile = Header.read(ReadDataStream(io.BytesIO(body))).profile if opcode == Opcode.HEADER else PROFILE
                if profile != PROFILE:
                    raise RecoveryError(f"'{path}' has MCAP profile '{profile}', not '{PROFILE}'")
                try:
                    records = _parse(opcode, body, report)
                except CHUNK_ERRORS:
                    break  # everything from this record on is lost
                if records is None:  # end of the data section: the file was complete
                    return
                good_end = source.tell()
                yield from records
    except OSError as error:
        raise RecoveryError(f"cannot read '{path}': {error.strerror or error}") from error
    report.complete_input = False
    report.discarded_bytes += size - good_end


def _parse(opcode: int, body: bytes, report: RecoveryReport) -> list[object] | None:
    """The records kept of one record's ``body``; None at the end of the data section."""
    stream = ReadDataStream(io.BytesIO(body))
    if opcode in (Opcode.DATA_END, Opcode.FOOTER):
        return None
    if opcode == Opcode.CHUNK:
        records = breakup_chunk(Chunk.read(stream), validate_crc=True)
        report.chunks += 1
        return records
    if opcode == Opcode.MESSAGE:
        return [Message.read(stream, len(body))]
    readers = {Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read, Opcode.METADATA: Metadata.read,
               Opcode.ATTACHMENT: Attachment.read}
    return [readers[opcode](stream)] if opcode in readers else []  # indexes are rebuilt by the writer


def recover(source: str | Path, destination: str | Path, options: WriterOptions = WriterOptions()) -> RecoveryReport:
    """Rewrite every complete message of ``source`` (file or bag directory) into a valid MCAP ``destination``."""
    report = RecoveryReport()
    sources = bag_files(Path(source))
    for path in sources:
        if path.stat().st_size < len(MAGIC):
            raise RecoveryError(f"'{path}' is {path.stat().st_size} bytes long: nothing to recover")
    writer = McapBagWriter(destination, options)
    done = False
    try:
        for path in sources:
            schemas: dict[int, Schema] = {}
            topics: dict[int, str] = {}
            for record in _records(path, report):
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel) and record.schema_id in schemas:
                    schema = schemas[record.schema_id]
                    writer.add_channel(record.topic, schema.name, schema.encoding, schema.data, record.metadata,
                                       record.message_encoding)
                    topics[record.id] = record.topic
                elif isinstance(record, Message) and record.channel_id in topics:
                    writer.write(topics[record.channel_id], record.data, record.log_time, record.publish_time,
                                 record.sequence)
                    report.messages += 1
                elif isinstance(record, Metadata) and record.name != METADATA_RECORD_NAME:
                    writer.add_metadata(record.name, record.metadata)
                    report.metadata += 1
                elif isinstance(record, Attachment):
                    writer.add_attachment(record.name, record.media_type, record.data, record.log_time)
                    report.attachments += 1
        done = True
    finally:
        writer.close()
        if not done:  # leave nothing that looks like a recovered file
            for written in writer.files:
                Path(written).unlink(missing_ok=True)
    report.topics = len(writer.topics)
    return report


def check_output(output: Path, overwrite: bool) -> None:
    """ValueError before the work if the output cannot be written: it exists (without ``overwrite``), a directory
    is in the way of an .mcap file, a file in the way of its folder, an unwritable folder."""
    if (output.is_file() or output.is_dir() and any(output.iterdir())) and not overwrite:
        raise ValueError(f"output '{output}' already exists (--overwrite replaces it)")
    if output.suffix == ".mcap":
        check_output_file(output, "output")
    else:  # a bag directory: made by the writer in its folder
        check_output_dir(output.parent, "output folder")


def run(args: argparse.Namespace) -> int:
    """Check the output, recover into it and say what was recovered."""
    check_output(args.output, args.overwrite)
    report = recover(args.input, args.output, WriterOptions(compression=args.compression, overwrite=args.overwrite))
    if report.messages == 0:
        print(f"needle_mcap_recover: warning: no complete message in '{args.input}': '{args.output}' holds no data",
              file=sys.stderr)
    print(f"needle_mcap_recover: {report.describe()} -> {args.output}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="needle_mcap_recover",
        description="Rebuild a valid, indexed MCAP file from a recording cut short (no summary/footer): every "
                    "message of every complete chunk is kept.")
    parser.add_argument("input", type=Path, help="truncated .mcap file, or a bag directory of .mcap files")
    parser.add_argument("output", type=Path, help="recovered .mcap file (or bag directory without .mcap suffix)")
    parser.add_argument("--compression", choices=COMPRESSION, default="zstd",
                        help="chunk compression of the output (default: zstd)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output")
    args = parser.parse_args(argv)
    if args.input.resolve() == args.output.resolve():
        parser.error("output must differ from input")
    return command_status("needle_mcap_recover", run, args, (ValueError, RecoveryError, BagReadError),
                          (RecordingError,))


if __name__ == "__main__":
    sys.exit(main())
