"""Fuzz-style: corrupt, truncated and mistyped recordings and bag directories (issue 15). Seeded; each case asserts
the exit status, a one-line message without a traceback, no NaN in the outputs and no output left by a failed run."""
import json
import random
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from needle_common.bag_reader import BagReader, BagReadError

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "insertion.mcap"  # small, no images: the shape sensor's /needle/measured_shape
EXPERIMENT = REPO / "config" / "experiments" / "insertion.yaml"
SEED = 15


def chunk_offsets(path: Path) -> list[int]:
    with open(path, "rb") as stream:
        return [index.chunk_start_offset for index in make_reader(stream).get_summary().chunk_indexes]


def flipped(path: Path, target: Path, chunk: int = 1) -> Path:
    """A copy with one bit flipped inside the compressed data of a chunk (after its 9-byte record head and
    the chunk's own fields)."""
    data = bytearray(path.read_bytes())
    data[chunk_offsets(path)[chunk] + 200] ^= 0x10
    target.write_bytes(data)
    return target


def bag_directory(target: Path, files: list[str], metadata: str | None = None) -> Path:
    target.mkdir()
    shutil.copy(BAG, target / f"{target.name}_0.mcap")
    if metadata is None:
        with open(BAG, "rb") as stream:
            statistics = make_reader(stream).get_summary().statistics
        metadata = yaml_metadata(files, statistics)
    (target / "metadata.yaml").write_text(metadata)
    return target


def yaml_metadata(files: list[str], statistics) -> str:
    return (f"rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n"
            f"  relative_file_paths: [{', '.join(files)}]\n"
            f"  starting_time: {{nanoseconds_since_epoch: {statistics.message_start_time}}}\n"
            f"  message_count: {statistics.message_count}\n")


def retyped(target: Path, topic: str, type_name: str) -> Path:
    """A copy whose ``topic`` is declared with another type (schema) than it was recorded with."""
    with open(BAG, "rb") as source, open(target, "wb") as out:
        reader = make_reader(source)
        summary = reader.get_summary()
        writer = Writer(out)
        writer.start()
        schemas = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        other = next(sid for sid, s in summary.schemas.items() if s.name == type_name)
        channels = {cid: writer.register_channel(c.topic, c.message_encoding,
                                                 schemas[other if c.topic == topic else c.schema_id], c.metadata)
                    for cid, c in summary.channels.items()}
        for _, channel, message in reader.iter_messages():
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
    return target


def test_random_damage_is_a_read_error_or_counted_corrupt_chunks(tmp_path):
    """Seeded bit flips and truncations anywhere: opening fails with BagReadError naming the file, or every
    message of the intact chunks is read and the damaged chunks are counted; nothing else is raised."""
    rng = random.Random(SEED)
    original = BAG.read_bytes()
    total = sum(1 for _ in BagReader(BAG).messages())
    outcomes = {"refused": 0, "read": 0, "skipped_chunks": 0}
    path = tmp_path / "damaged.mcap"
    for case in range(60):
        data = bytearray(original)
        if case % 2:
            data = data[:rng.randrange(len(data))]
        else:
            for _ in range(rng.randint(1, 3)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        path.write_bytes(data)
        try:
            reader = BagReader(path)
            count = sum(1 for _ in reader.messages())
        except BagReadError as error:
            assert str(path) in str(error) and "\n" not in str(error)
            outcomes["refused"] += 1
            continue
        assert count <= total
        outcomes["read"] += 1
        outcomes["skipped_chunks"] += reader.corrupt_chunks
    assert outcomes["refused"] >= 20 and outcomes["read"] >= 10, outcomes


def test_a_flipped_bit_skips_one_chunk_or_stops_on_request(tmp_path):
    damaged = flipped(BAG, tmp_path / "flip.mcap")
    reader = BagReader(damaged)
    count = sum(1 for _ in reader.messages())
    assert reader.corrupt_chunks == 1 and 0 < count < sum(1 for _ in BagReader(BAG).messages())
    with pytest.raises(BagReadError, match="corrupt chunk"):
        sum(1 for _ in BagReader(damaged, stop_on_corrupt=True).messages())


def offline(bag: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(["needle_offline", str(bag), "--experiment", str(EXPERIMENT), "--output-dir", str(out),
                           "--duration", "1.5", "--quiet", *extra],
                          cwd=REPO, capture_output=True, text=True, timeout=600)


def wrench_values(log: Path) -> np.ndarray:
    from mcap_ros2.decoder import DecoderFactory
    with open(log, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x, m.wrench.torque.y,
                          m.wrench.torque.z] for _, _, _, m in reader.iter_decoded_messages(topics=["/wrench"])])


@pytest.mark.slow
def test_needle_offline_on_damaged_and_mistyped_bags(tmp_path):
    out = tmp_path / "out"
    good = offline(bag_directory(tmp_path / "bagdir", ["bagdir_0.mcap"]), out)  # a bag directory is supported
    assert good.returncode == 0, good.stderr
    assert "Traceback" not in good.stdout + good.stderr
    values = wrench_values(out / "pipeline.mcap")
    assert len(values) > 100 and np.all(np.isfinite(values))
    before = {name: (out / name).read_bytes() for name in ("pipeline.mcap", "summary.json")}
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(BAG.read_bytes()[:len(BAG.read_bytes()) // 3])
    refused = {
        "empty": (empty, "is empty"),
        "truncated": (truncated, "not a complete MCAP file"),
        "wrong type": (retyped(tmp_path / "retyped.mcap", "/needle/measured_shape", "geometry_msgs/msg/PoseStamped"),
                       "has type 'geometry_msgs/msg/PoseStamped', expected 'needle_interfaces/msg/NeedleShape'"),
        "wrong truth type": (retyped(tmp_path / "retyped_truth.mcap", "/ground_truth/wrench",
                                     "geometry_msgs/msg/PoseStamped"),
                             "has type 'geometry_msgs/msg/PoseStamped', expected 'geometry_msgs/msg/WrenchStamped'"),
        "missing split": (bag_directory(tmp_path / "missing", ["missing_0.mcap", "missing_1.mcap"]), "missing"),
        "bad metadata": (bag_directory(tmp_path / "badmeta", [], metadata=": : [\n"), "cannot read recording"),
        "flip, stop": (flipped(BAG, tmp_path / "flip_stop.mcap"), "corrupt chunk"),
    }
    for case, (bag, words) in refused.items():
        result = offline(bag, out, *(["--stop-on-corrupt"] if case == "flip, stop" else []))
        output = result.stdout + result.stderr
        assert result.returncode == 2, (case, output)
        assert "Traceback" not in output, case
        errors = [line for line in output.splitlines() if line.startswith("needle_offline: error:")]
        assert len(errors) == 1 and words in errors[0], (case, output)
        # The previous run's results are untouched (no partial log next to an old summary) and no staging is left.
        assert {name: (out / name).read_bytes() for name in before} == before, case
        assert sorted(p.name for p in out.iterdir()) == ["pipeline.mcap", "summary.json"], case
    skipped = offline(flipped(BAG, tmp_path / "flip.mcap"), tmp_path / "out_flip")
    assert skipped.returncode == 0 and "skipped 1 corrupt chunk(s)" in skipped.stderr
    summary = json.loads((tmp_path / "out_flip" / "summary.json").read_text())
    assert summary["corrupt_chunks"] == 1
    assert np.all(np.isfinite(wrench_values(tmp_path / "out_flip" / "pipeline.mcap")))


def test_needle_offline_names_the_bag_problem_before_the_experiment_file(tmp_path):
    """Without --experiment the experiment file is looked up by the bag's name: a missing bag must be reported as
    missing (not as a missing experiment file), and a user's own bag gets the --experiment hint."""
    (tmp_path / "own_recording.mcap").write_bytes(BAG.read_bytes())
    cases = {"missing.mcap": "input 'missing.mcap' does not exist",
             "own_recording.mcap": "(give the bag's experiment file with --experiment FILE)"}
    for bag, words in cases.items():
        result = subprocess.run(["needle_offline", bag, "--quiet"], cwd=tmp_path, capture_output=True, text=True,
                                timeout=300)
        assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
        assert result.stderr.count("\n") == 1 and words in result.stderr, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["own_recording.mcap"]


@pytest.mark.slow
@pytest.mark.ros
def test_needle_replay_skips_corrupt_chunks_and_mistyped_topics(tmp_path, ros_env):
    def replay(bag: Path, *extra: str) -> subprocess.CompletedProcess:
        return subprocess.run(["needle_replay", str(bag), "--rate", "20", *extra], env=ros_env, capture_output=True,
                              text=True, timeout=120)
    damaged = flipped(BAG, tmp_path / "flip.mcap")
    result = replay(damaged)
    assert result.returncode == 0 and "skipped 1 corrupt chunk(s)" in result.stdout + result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    stopped = replay(damaged, "--stop-on-corrupt")
    assert stopped.returncode == 2 and "corrupt chunk" in stopped.stdout + stopped.stderr
    mistyped = replay(retyped(tmp_path / "retyped.mcap", "/base_pose", "needle_interfaces/msg/NeedleShape"))
    output = mistyped.stdout + mistyped.stderr
    assert mistyped.returncode == 0 and "skipping topic '/base_pose'" in output and "Traceback" not in output
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    refused = replay(empty)
    assert refused.returncode == 2 and "is empty" in refused.stdout + refused.stderr


@pytest.mark.slow
def test_out_of_range_times_are_refused_before_any_work(tmp_path, ros_env):
    """NaN, inf, negative, and a start offset past the bag's end (before: NaN and inf ended in a traceback, an offset
    past the end ran "successfully" over -994 s at -3928x real time, and needle_replay played 0 messages with exit
    status 0)."""
    commands = {("needle_offline", "--start-offset", "nan"): "argument --start-offset: must be a finite number, got "
                                                             "nan",
                ("needle_offline", "--duration", "inf"): "argument --duration: must be a finite number, got inf",
                ("needle_offline", "--duration", "-1"): "argument --duration: must be > 0, got -1",
                ("needle_offline", "--start-offset", "1000"): f"--start-offset 1000 s: '{BAG}' spans only",
                ("needle_replay", "--start-offset", "1000"): f"--start-offset 1000 s: '{BAG}' spans only",
                ("needle_replay", "--rate", "inf"): "argument --rate/-r: must be a finite number, got inf"}
    for (executable, *option), words in commands.items():
        quiet = ["--quiet"] if executable == "needle_offline" else []
        result = subprocess.run([executable, str(BAG), *option, *quiet], cwd=tmp_path, env=ros_env,
                                capture_output=True, text=True, timeout=300)
        output = result.stdout + result.stderr
        assert result.returncode == 2 and "Traceback" not in output and words in output, (executable, option, output)
    assert not any(tmp_path.iterdir())  # nothing written
