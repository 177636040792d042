"""MCAP recording core: rosbag2 layout, independent readers, crash recovery, clear errors."""
import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from geometry_msgs.msg import PoseStamped, WrenchStamped
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from needle_interfaces.msg import NeedleShape, ShapeError
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from std_msgs.msg import String

from needle_common.bag_reader import BagReader
from needle_common.qos import OfferedQos, parse_offered_qos_profiles
from needle_sim_ros.recording import (McapBagWriter, RecordingError, WriterOptions, message_definition, recover,
                                      type_description_hash)
from needle_sim_ros.recording import mcap_writer, recovery
from needle_common.qos import DURATION_INFINITE_NS

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
BEST_EFFORT = OfferedQos(depth=5, reliability="best_effort", durability="transient_local",
                         deadline_ns=DURATION_INFINITE_NS, liveliness="automatic")


def msg_file(type_name: str) -> str:
    package, _, name = type_name.split("/")
    return (Path(get_package_share_directory(package)) / "msg" / f"{name}.msg").read_text()


def section(type_name: str) -> str:
    package, _, name = type_name.split("/")
    return "\n" + "=" * 80 + "\n" + f"MSG: {package}/{name}\n" + msg_file(type_name)


def test_schema_text_is_laid_out_as_rosbag2_writes_it():
    # Order by hand, following rosbag2's rule (dependencies of a file sorted by name, each type once, depth first):
    # PoseStamped -> {geometry_msgs/Pose -> {Point, Quaternion}, std_msgs/Header -> {builtin_interfaces/Time}}.
    expected = (msg_file("geometry_msgs/msg/PoseStamped") + section("geometry_msgs/msg/Pose")
                + section("geometry_msgs/msg/Point") + section("geometry_msgs/msg/Quaternion")
                + section("std_msgs/msg/Header") + section("builtin_interfaces/msg/Time"))
    assert message_definition("geometry_msgs/msg/PoseStamped") == expected
    # NeedleShape -> {Point, Pose -> {Point (seen), Quaternion}, Vector3, Header -> {Time}}.
    expected = (msg_file("needle_interfaces/msg/NeedleShape") + section("geometry_msgs/msg/Point")
                + section("geometry_msgs/msg/Pose") + section("geometry_msgs/msg/Quaternion")
                + section("geometry_msgs/msg/Vector3") + section("std_msgs/msg/Header")
                + section("builtin_interfaces/msg/Time"))
    assert message_definition("needle_interfaces/msg/NeedleShape") == expected


def test_type_hash_is_the_installed_rihs01_hash():
    share = Path(get_package_share_directory("needle_interfaces"))
    hashes = json.loads((share / "msg" / "ShapeError.json").read_text())["type_hashes"]
    assert type_description_hash("needle_interfaces/msg/ShapeError") == hashes[0]["hash_string"]
    assert hashes[0]["hash_string"].startswith("RIHS01_")


def sample_messages():
    shape = NeedleShape(source="model", arc_length=[0.0, 0.1], uncertainty=[0.001, 0.002], length=0.1)
    shape.header.frame_id = "needle_base"
    shape.points = [shape.tip_pose.position, shape.tip_pose.position]
    shape.points[1].x = 0.1
    error = ShapeError(rmse=0.0012, max_error=0.003, tip_error=0.002, matched_samples=2, errors=[0.001, 0.003],
                       arc_length=[0.0, 0.1])
    wrench = WrenchStamped()
    wrench.wrench.force.z = -1.5
    pose = PoseStamped()
    pose.pose.orientation.w = 1.0
    return {"/model/shape": shape, "/shape_error": error, "/wrench": wrench, "/base_pose": pose}


def type_name(message) -> str:
    return f"{type(message).__module__.split('.')[0]}/msg/{type(message).__name__}"


def write_samples(path, options=WriterOptions(), repeats=20, qos=(OfferedQos(),)) -> list[tuple[str, int, object]]:
    written = []
    with McapBagWriter(path, options) as writer:
        for topic, message in sample_messages().items():
            writer.add_topic(topic, type_name(message), [BEST_EFFORT] if topic == "/wrench" else qos)
        for k in range(repeats):
            for i, (topic, message) in enumerate(sample_messages().items()):
                stamp = 1_700_000_000_000_000_000 + k * 10_000_000 + i
                message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                writer.write(topic, serialize_message(message), stamp)
                written.append((topic, stamp, message))
    return written


def test_message_index_records_are_mcaps():
    """The writer packs a chunk's message indexes itself: the same bytes as the mcap library's record."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import MessageIndex

    from needle_sim_ros.recording.mcap_writer import _message_index

    for entries in ([], [(1_700_000_000_123_456_789, 0)], [(t, 31 * t) for t in range(1000, 1300)]):
        builder = RecordBuilder()
        MessageIndex(7, entries).write(builder)
        assert _message_index(7, entries) == builder.end()


def test_written_file_decodes_message_by_message_with_mcap_ros2(tmp_path):
    path = tmp_path / "run.mcap"
    written = write_samples(path)
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [(channel.topic, message.log_time, ros) for _, channel, message, ros in
                   reader.iter_decoded_messages(log_time_order=True)]
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
    assert [(t, s) for t, s, _ in decoded] == [(t, s) for t, s, _ in written]
    for (_, _, got), (_, _, sent) in zip(decoded, written):
        for field in sent.get_fields_and_field_types():
            if field == "header":
                assert (got.header.stamp.sec, got.header.stamp.nanosec, got.header.frame_id) == \
                    (sent.header.stamp.sec, sent.header.stamp.nanosec, sent.header.frame_id)
            elif field in ("errors", "arc_length", "uncertainty"):
                np.testing.assert_array_equal(getattr(got, field), list(getattr(sent, field)))
            elif isinstance(getattr(sent, field), (int, float, str)):
                assert getattr(got, field) == getattr(sent, field), field
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert summary.statistics.message_count == len(written)
    assert summary.chunk_indexes and all(c.compression == "zstd" and c.message_index_offsets
                                         for c in summary.chunk_indexes)


def test_written_file_decodes_with_rosbags_and_keeps_qos_and_hash(tmp_path):
    path = tmp_path / "run.mcap"
    written = write_samples(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(path) as reader:
        for connection in reader.connections:
            typestore.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
        by_topic = {c.topic: c for c in reader.connections}
        got = [(c.topic, t, typestore.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]
        assert reader.message_count == len(written)
    assert [(t, s) for t, s, _ in got] == [(t, s) for t, s, _ in written]
    shapes = [m for t, _, m in got if t == "/model/shape"]
    assert shapes[0].points[1].x == 0.1 and shapes[0].header.frame_id == "needle_base"
    assert [m.wrench.force.z for t, _, m in got if t == "/wrench"] == [-1.5] * 20
    wrench_qos = by_topic["/wrench"].ext.offered_qos_profiles[0]
    assert (wrench_qos.reliability.name, wrench_qos.durability.name, wrench_qos.depth) == \
        ("BEST_EFFORT", "TRANSIENT_LOCAL", 5)
    assert (wrench_qos.deadline.sec, wrench_qos.deadline.nsec) == (9223372036, 854775807)  # RMW infinite


def test_channel_metadata_and_bag_metadata_record(tmp_path):
    path = tmp_path / "run.mcap"
    write_samples(path, repeats=3)
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        channels = {c.topic: c for c in reader.get_summary().channels.values()}
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert parse_offered_qos_profiles(channels["/wrench"].metadata["offered_qos_profiles"]) == [BEST_EFFORT]
    assert channels["/shape_error"].metadata["topic_type_hash"] == \
        type_description_hash("needle_interfaces/msg/ShapeError")
    import yaml
    bag = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert bag["version"] == 9 and bag["storage_identifier"] == "mcap" and bag["message_count"] == 12
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in bag["topics_with_message_count"]} == \
        {"/model/shape": 3, "/shape_error": 3, "/wrench": 3, "/base_pose": 3}
    assert bag["duration"]["nanoseconds"] == 2 * 10_000_000 + 3


def test_rosbag2_v8_and_v9_qos_texts_are_read():
    version_8 = ("- history: 1\n  depth: 10\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 0\n    nsec: 0\n"
                 "  lifespan:\n    sec: 0\n    nsec: 0\n  liveliness: 0\n  liveliness_lease_duration:\n    sec: 0\n"
                 "    nsec: 0\n  avoid_ros_namespace_conventions: false\n")
    assert parse_offered_qos_profiles(version_8) == [OfferedQos(liveliness="system_default")]
    version_9 = version_8.replace("history: 1", "history: keep_all").replace("reliability: 1", "reliability: "
                                                                             "best_effort")
    version_9 = version_9.replace("durability: 2", "durability: transient_local").replace("liveliness: 0",
                                                                                          "liveliness: automatic")
    version_9 = version_9.replace("deadline:\n    sec: 0\n    nsec: 0", "deadline:\n    sec: 2147483647\n"
                                  "    nsec: 4294967295")  # Fast DDS Foxy-era infinity
    assert parse_offered_qos_profiles(version_9) == [OfferedQos(
        history="keep_all", reliability="best_effort", durability="transient_local", liveliness="automatic",
        deadline_ns=DURATION_INFINITE_NS)]
    with pytest.raises(ValueError, match="offered_qos_profiles"):
        parse_offered_qos_profiles("- nonsense")


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
@pytest.mark.parametrize("split", [False, True])
def test_background_compression_writes_the_same_files(tmp_path, compression, split):
    """Chunks compressed on the worker thread: byte for byte the file(s) written without it (also split by size)."""
    samples = sample_messages()
    messages = [(topic, 1_700_000_000_000_000_000 + k * 10_000_000 + i, serialize_message(message))
                for k in range(40) for i, (topic, message) in enumerate(samples.items())]
    files = []
    for background in (False, True):
        options = WriterOptions(compression=compression, chunk_size=2048, max_file_size=4096 if split else 0,
                                background=background)
        path = tmp_path / str(background) / ("bag" if split else "run.mcap")  # the name is in the bag metadata
        with McapBagWriter(path, options) as writer:
            for topic, message in samples.items():
                writer.add_topic(topic, type_name(message))
            for topic, stamp, data in messages:
                writer.write(topic, data, stamp)
        files.append([f.read_bytes() for f in sorted(path.glob("*.mcap"))] if split else [path.read_bytes()])
    assert len(files[0]) > (2 if split else 0) and files[0] == files[1]


def test_bag_directory_split_by_size_reads_back_whole(tmp_path):
    bag = tmp_path / "split_bag"
    written = write_samples(bag, WriterOptions(chunk_size=2048, max_file_size=4096), repeats=40)
    files = sorted(bag.glob("*.mcap"))
    assert len(files) > 2
    with Reader(bag) as reader:                      # rosbags reads the directory through metadata.yaml
        got = [(c.topic, t) for c, t, _ in reader.messages()]
        assert len(reader.topics) == 4
    assert got == [(t, s) for t, s, _ in written]
    reader = BagReader(bag)
    assert [m.log_time_ns for m in reader.messages()] == [s for _, s, _ in written]
    assert reader.topics["/wrench"].message_count == 40


def test_splitting_needs_a_bag_directory(tmp_path):
    with pytest.raises(ValueError, match="bag directory"):
        McapBagWriter(tmp_path / "x.mcap", WriterOptions(max_file_duration=10.0))


def test_unwritable_or_existing_path_gives_a_clear_error(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(RecordingError, match=f"cannot write recording file '{blocker}/run.mcap'"):
        McapBagWriter(blocker / "run.mcap")
    existing = tmp_path / "old.mcap"
    existing.write_text("keep me")
    with pytest.raises(RecordingError, match="already exists"):
        McapBagWriter(existing)
    assert existing.read_text() == "keep me"


def test_full_disk_gives_a_clear_error(tmp_path):
    full = tmp_path / "full.mcap"
    full.symlink_to("/dev/full")
    with pytest.raises(RecordingError, match="disk full"):
        McapBagWriter(full, WriterOptions(overwrite=True))


@pytest.mark.parametrize("background", [False, True])
def test_disk_full_mid_recording_stops_cleanly_and_the_file_is_recoverable(tmp_path, monkeypatch, background):
    path = tmp_path / "run.mcap"
    writer = McapBagWriter(path, WriterOptions(chunk_size=1024, chunk_interval=0, background=background))
    writer.add_topic("/chatter", "std_msgs/msg/String")
    real_write, budget = os.write, [6000]

    def write_until_full(fd, data):
        if budget[0] < len(data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        budget[0] -= len(data)
        return real_write(fd, data)

    monkeypatch.setattr(mcap_writer.os, "write", write_until_full)
    with pytest.raises(RecordingError, match="disk full"):
        for k in range(10_000):
            writer.write("/chatter", serialize_message(String(data=f"{k:06d}" + "x" * 50)), k)
    with pytest.raises(RecordingError, match="stopped after an earlier error"):
        writer.write("/chatter", serialize_message(String(data="late")), 10_001)
    writer.close()
    monkeypatch.undo()
    report = recover(path, tmp_path / "recovered.mcap")
    assert not report.complete_input and report.messages > 0
    recovered = [m.data for m in BagReader(tmp_path / "recovered.mcap").messages()]
    assert recovered == [serialize_message(String(data=f"{k:06d}" + "x" * 50)) for k in range(len(recovered))]


KILLED_WRITER = """
import sys, time
from rclpy.serialization import serialize_message
from std_msgs.msg import String
from needle_sim_ros.recording import McapBagWriter, WriterOptions
writer = McapBagWriter(sys.argv[1], WriterOptions(chunk_size=4096, chunk_interval=0.0))
writer.add_topic('/counter', 'std_msgs/msg/String')
writer.add_metadata('run', {'purpose': 'sigkill test'})
k = 0
while True:
    writer.write('/counter', serialize_message(String(data=f'{k:08d}' + sys.argv[2])), 1_000_000 * k)
    k += 1
    if k % 100 == 0:
        time.sleep(0.002)
"""


def complete_chunk_messages(path: Path) -> int:
    """Messages in the complete chunks of a truncated file, counted with mcap's own stream reader."""
    count = 0
    try:
        for record in StreamReader(str(path), validate_crcs=True).records:
            count += type(record).__name__ == "Message"
    except Exception:  # the reader fails at the cut: whatever it yielded before is the complete part
        pass
    return count


def test_sigkilled_writer_leaves_a_file_recoverable_up_to_the_last_complete_chunk(tmp_path):
    path = tmp_path / "killed.mcap"
    padding = os.urandom(60).hex()  # incompressible, so chunks reach the disk at a steady pace
    child = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(path), padding])
    try:
        deadline = time.monotonic() + 30.0
        while (not path.exists() or path.stat().st_size < 60_000) and time.monotonic() < deadline:
            assert child.poll() is None, "writer died on its own"
            time.sleep(0.01)
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait()
    assert child.returncode == -signal.SIGKILL
    with open(path, "rb") as stream:
        assert stream.read()[-8:] != b"\x89MCAP0\r\n"  # no footer: the file was cut
    expected = complete_chunk_messages(path)
    assert expected > 100

    assert recovery.main([str(path), str(tmp_path / "fixed.mcap")]) == 0
    with Reader(tmp_path / "fixed.mcap") as reader:
        typestore = get_typestore(Stores.ROS2_JAZZY)
        texts = [typestore.deserialize_cdr(raw, c.msgtype).data for c, _, raw in reader.messages()]
    assert len(texts) == expected
    assert texts == [f"{k:08d}" + padding for k in range(expected)]
    with open(tmp_path / "fixed.mcap", "rb") as stream:
        reader = make_reader(stream)
        assert reader.get_summary().statistics.message_count == expected
        assert {m.name: m.metadata for m in reader.iter_metadata()}["run"] == {"purpose": "sigkill test"}


def test_recover_cli_reports_bad_input(tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    assert recovery.main([str(junk), str(tmp_path / "out.mcap")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert not (tmp_path / "out.mcap").exists()  # nothing that looks like a recovered file
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert recovery.main([str(empty), str(tmp_path / "out.mcap")]) == 2
    assert "0 bytes long: nothing to recover" in capsys.readouterr().err
    assert not (tmp_path / "out.mcap").exists()
    # outputs that cannot be written: exit 2 before reading (before: exit 1 from the writer)
    good = tmp_path / "good.mcap"
    write_samples(good, repeats=1)
    taken = tmp_path / "taken.mcap"
    taken.write_bytes(b"someone's file")
    blocker = tmp_path / "blocker"
    blocker.write_bytes(b"")
    for output, words in ((taken, "already exists (--overwrite replaces it)"), (blocker / "x.mcap", "in the way")):
        assert recovery.main([str(good), str(output)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err, err
    assert taken.read_bytes() == b"someone's file"
    assert recovery.main([str(good), str(taken), "--overwrite"]) == 0


def test_the_compression_choices_offered_are_the_writers(capsys):
    """needle_mcap_recover --compression and needle_compare's log.compression offer what WriterOptions accepts."""
    from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS
    with pytest.raises(SystemExit):
        recovery.main(["--help"])
    assert f"--compression {{{','.join(mcap_writer.COMPRESSION)}}}" in capsys.readouterr().out
    assert next(s for s in COMPARE_PARAMETERS if s.name == "log.compression").choices == mcap_writer.COMPRESSION
    for compression in mcap_writer.COMPRESSION:
        WriterOptions(compression=compression)
    with pytest.raises(ValueError, match="is not one of zstd, lz4, none"):
        WriterOptions(compression="gzip")


def test_a_bag_written_atomically_records_its_final_file_name(tmp_path):
    from needle_common.output_files import write_atomically

    path = tmp_path / "run.mcap"
    write_atomically(path, lambda temporary: write_samples(temporary, repeats=1))
    assert [p.name for p in tmp_path.iterdir()] == ["run.mcap"]  # no staging folder left
    import yaml
    with open(path, "rb") as stream:
        records = {m.name: m.metadata for m in make_reader(stream).iter_metadata()}
    bag = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert bag["relative_file_paths"] == ["run.mcap"] and [f["path"] for f in bag["files"]] == ["run.mcap"]


def test_make_bags_refuses_an_unusable_output_before_the_ground_truth(tmp_path, capsys):
    from needle_sim_ros.experiments.make_bags import main

    blocker = tmp_path / "bags"
    blocker.write_text("a file, not a folder")
    start = time.perf_counter()
    assert main(["--output-dir", str(blocker), "--experiments", "static_tip_load"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("needle_make_bags: error: bag ") and "a file is in the way" in err and err.count("\n") == 1
    assert time.perf_counter() - start < 2.0 and blocker.read_text() == "a file, not a folder"
