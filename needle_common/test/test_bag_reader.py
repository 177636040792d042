"""needle_common.bag_reader against the mcap library's own reader: the same messages in the same order for every way a
writer may lay out an MCAP file (chunk compression, no chunks, no index or summary, overlapping chunks); split bags in
metadata.yaml's order; damaged chunks skipped and counted."""
import mmap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from needle_common.bag_reader import BagReader, BagReadError, _populate, bag_files

TOPICS = ("/left/image_raw", "/right/image_raw", "/base_pose")


def write_file(path: Path, log_times, **options) -> Path:
    """Messages of random sizes (up to 300 kB) on three topics and one unwanted topic."""
    rng = np.random.default_rng(0)
    with open(path, "wb") as stream:
        writer = Writer(stream, **options)
        writer.start()
        schema = writer.register_schema("std_msgs/msg/UInt8MultiArray", "ros2msg", b"uint8[] data")
        channels = [writer.register_channel(topic, "cdr", schema) for topic in (*TOPICS, "/other")]
        for k, log_time in enumerate(log_times):
            data = rng.integers(0, 256, int(rng.integers(0, 300_000)), dtype=np.uint8).tobytes()
            writer.add_message(channels[k % 4], log_time, data, log_time, sequence=k)
        writer.finish()
    return path


def library(path: Path, topics) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as stream:
        return [(channel.topic, message.log_time, message.data)
                for _, channel, message in make_reader(stream).iter_messages(topics=list(topics))]


IN_ORDER = [1_000_000 * k for k in range(60)]
LAYOUTS = {
    "zstd chunks": {"compression": CompressionType.ZSTD, "chunk_size": 1 << 20},
    "lz4 chunks": {"compression": CompressionType.LZ4, "chunk_size": 1 << 20},
    "uncompressed chunks": {"compression": CompressionType.NONE, "chunk_size": 1 << 20},
    "a message per chunk": {"compression": CompressionType.NONE, "chunk_size": 1},
    "no chunks": {"use_chunking": False},
    "no index": {"index_types": IndexType.NONE, "compression": CompressionType.ZSTD},
    "no summary": {"index_types": IndexType.NONE, "repeat_channels": False, "repeat_schemas": False,
                   "use_statistics": False, "use_summary_offsets": False},
}


@pytest.mark.parametrize("layout", LAYOUTS)
def test_same_messages_as_the_mcap_library(tmp_path, layout):
    path = write_file(tmp_path / "bag.mcap", IN_ORDER, **LAYOUTS[layout])
    expected = library(path, TOPICS)
    assert len(expected) == 45
    reader = BagReader(path, require_summary=False)
    assert reader.summarized == (layout != "no summary")
    read = [(m.topic, m.log_time_ns, bytes(m.data)) for m in reader.messages([t.lstrip("/") for t in TOPICS])]
    assert read == expected
    assert [m.schema for m in reader.messages(TOPICS[:1])] == ["std_msgs/msg/UInt8MultiArray"] * 15


def test_messages_out_of_order_in_and_across_chunks(tmp_path):
    """Log times decreasing (chunks overlap in time) and shuffled within chunks: log-time order as the library (the
    memory-mapped reading merges the chunks)."""
    shuffled = np.random.default_rng(1).permutation(IN_ORDER).tolist()
    for name, times in (("reversed", IN_ORDER[::-1]), ("shuffled", shuffled)):
        path = write_file(tmp_path / f"{name}.mcap", times, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        read = [(m.topic, m.log_time_ns, bytes(m.data)) for m in BagReader(path).messages(TOPICS)]
        assert read == library(path, TOPICS) and [t for _, t, _ in read] == sorted(t for _, t, _ in read)


def test_uncompressed_payloads_are_views_of_the_file(tmp_path):
    path = write_file(tmp_path / "bag.mcap", IN_ORDER, compression=CompressionType.NONE)
    message = next(BagReader(path).messages(TOPICS))
    assert isinstance(message.data, memoryview) and isinstance(message.data.obj, mmap.mmap)  # not copied
    assert bytes(message.data) == library(path, TOPICS)[0][2]


def test_page_mapping_lets_other_threads_run(tmp_path):
    """Mapping the pages of a chunk (256 MB here) runs without the GIL: another Python thread keeps running during
    it (with ``mmap.madvise`` it stopped for the whole call)."""
    path = tmp_path / "chunk.bin"
    with open(path, "wb") as stream:
        stream.truncate(256 << 20)
    with open(path, "rb") as stream:
        mapped = mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
    done, gaps = threading.Event(), []

    def spin() -> None:
        last = time.perf_counter()
        while not done.is_set():
            now = time.perf_counter()
            gaps.append(now - last)
            last = now

    thread = threading.Thread(target=spin)
    thread.start()
    time.sleep(0.02)
    start = time.perf_counter()
    _populate(mapped, 0, len(mapped))
    duration = time.perf_counter() - start
    done.set()
    thread.join()
    assert duration > 0.01  # the pages were mapped here (long enough to tell)
    assert max(gaps) < 0.5 * duration


def test_a_split_bag_is_read_in_the_order_metadata_yaml_gives(tmp_path):
    """Before, needle_stereo_offline read a bag folder's files in name order, whatever metadata.yaml said (and put
    ``name_10`` before ``name_2``): its messages came out of order."""
    folder = tmp_path / "bag"
    folder.mkdir()
    times = {name: [1_000_000 * (10 * k + i) for i in range(8)] for k, name in enumerate(("b_2", "a_10", "c_1"))}
    for name, log_times in times.items():
        write_file(folder / f"{name}.mcap", log_times, compression=CompressionType.ZSTD)
    (folder / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": {
        "relative_file_paths": ["b_2.mcap", "a_10.mcap", "c_1.mcap"]}}))
    read = [m.log_time_ns for m in BagReader(folder).messages(TOPICS)]
    expected = [t for name in ("b_2", "a_10", "c_1") for k, t in enumerate(times[name]) if k % 4 != 3]
    assert read == expected
    (folder / "metadata.yaml").unlink()  # without it: split order by the number after the last '_'
    assert bag_files(folder) == [folder / "c_1.mcap", folder / "b_2.mcap", folder / "a_10.mcap"]


def test_a_start_time_skips_earlier_messages_and_chunks(tmp_path):
    path = write_file(tmp_path / "bag.mcap", IN_ORDER, compression=CompressionType.ZSTD, chunk_size=1 << 20)
    start = IN_ORDER[20]
    read = [(m.topic, m.log_time_ns, bytes(m.data)) for m in BagReader(path).messages(TOPICS, start_time_ns=start)]
    assert read == [m for m in library(path, TOPICS) if m[1] >= start]


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.NONE])
def test_a_damaged_chunk_is_skipped_and_counted_or_stops_the_reading(tmp_path, compression):
    path = write_file(tmp_path / "bag.mcap", IN_ORDER, compression=compression, chunk_size=1 << 20)
    with open(path, "rb") as stream:
        indexes = make_reader(stream).get_summary().chunk_indexes
    assert len(indexes) > 3
    data = bytearray(path.read_bytes())
    damaged = indexes[1]
    data[damaged.chunk_start_offset + damaged.chunk_length // 2] ^= 0x10  # inside its records: CRC or zstd fails
    path.write_bytes(data)
    reader = BagReader(path)
    read = [m.log_time_ns for m in reader.messages(TOPICS)]
    assert reader.corrupt_chunks == 1 and 0 < len(read) < 45
    assert not any(damaged.message_start_time <= t <= damaged.message_end_time for t in read)
    with pytest.raises(BagReadError, match=f"corrupt chunk at byte {damaged.chunk_start_offset}"):
        list(BagReader(path, stop_on_corrupt=True).messages(TOPICS))
