"""needle_stereo_offline on an image folder and on an MCAP bag made here."""
import csv
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from vision_shapes import SHAPES, distance_to_curve
from needle_common.cdr import camera_info
from needle_vision.calibration.rig import camera_info_fields
from needle_vision.streams.image_codec import image_fields
from needle_vision.offline import main


def params_file(tmp_path: Path, rig, **overrides) -> Path:
    parameters = {"background": {"frames": 3}, "output_frame": "world",
                  "output_transform": rig.world_from_left.as_xyz_quaternion(), **overrides}
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": parameters}}))
    return path


def read_rows(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path) as stream:
        comment = stream.readline()
        assert comment.startswith("# needle_stereo_offline: points in frame ") and "[m]" in comment
        rows = list(csv.reader(stream))
    return rows[0], np.array([[float(v) if v else np.nan for v in row] for row in rows[1:]])


@pytest.mark.parametrize("suffix", [".png", ".bmp"])  # BMP: grey ones are read as their rows, colour ones decoded
def test_image_folder(tmp_path, rig, background_frames, renders, capsys, suffix):
    for side, index in (("left", 0), ("right", 1)):
        (tmp_path / "frames" / side).mkdir(parents=True)
        for k, pair in enumerate(background_frames[:3]):
            image = pair[index] if k else cv2.cvtColor(pair[index], cv2.COLOR_GRAY2BGR)
            cv2.imwrite(str(tmp_path / "frames" / side / f"{k:04d}{suffix}"), image)
        cv2.imwrite(str(tmp_path / "frames" / side / f"0003{suffix}"), renders("planar")[index])
    output = tmp_path / "out.csv"
    code = main([str(tmp_path / "frames"), "--params", str(params_file(tmp_path, rig)), "--quiet",
                 "--left-calibration", "package://needle_vision/config/stereo/left.yaml",
                 "--right-calibration", "package://needle_vision/config/stereo/right.yaml", "--output", str(output)])
    assert code == 0
    header, rows = read_rows(output)
    assert header == ["frame", "stamp", "sample", "arc_length", "x", "y", "z", "uncertainty"]
    assert set(rows[:, 0]) == {3} and rows[0, 1] == pytest.approx(3 / 220.0)  # stamps from --fps
    distance, _ = distance_to_curve(rows[:, 4:7], SHAPES["planar"])
    assert np.sqrt(np.mean(distance ** 2)) < 1e-4  # lossless: same accuracy as in memory
    assert "3  used to build the background model" in capsys.readouterr().out


def write_bag(path: Path, rig, frames, encoding_of=lambda k: "mono8", compressed: bool = False,
              extra=lambda k: (), **writer_options):
    """An MCAP bag with camera_info and, per frame, Image (or PNG CompressedImage on .../compressed) messages,
    after the frame's ``extra(k)`` messages (topic, type name, fields)."""
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    ros = rig.with_ros_rectification()
    with open(path, "wb") as stream:
        writer = Writer(stream, **writer_options)
        schemas = {name: writer.register_msgdef(name, store.generate_msgdef(name, ros_version=2)[0])
                   for name in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                                "sensor_msgs/msg/CompressedImage", "geometry_msgs/msg/PoseStamped")}
        for k, (stamp, left, right) in enumerate(frames):
            time = {"sec": int(stamp), "nanosec": int(round((stamp % 1) * 1e9))}
            for topic, type_name, fields in extra(k):
                writer.write_message(topic, schemas[type_name], fields, log_time=int(stamp * 1e9))
            for side, image, camera in (("left", left, ros.left), ("right", right, ros.right)):
                if image is None:
                    continue
                header = {"stamp": time, "frame_id": f"{side}_optical"}
                info = {**camera_info_fields(camera), "header": header, "binning_x": 0, "binning_y": 0,
                        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}
                writer.write_message(f"/{side}/camera_info", schemas["sensor_msgs/msg/CameraInfo"], info,
                                     log_time=int(stamp * 1e9))
                if compressed:
                    writer.write_message(f"/{side}/image_raw/compressed", schemas["sensor_msgs/msg/CompressedImage"],
                                         {"header": header, "format": "mono8; png compressed ",
                                          "data": cv2.imencode(".png", image)[1].tobytes()}, log_time=int(stamp * 1e9))
                    continue
                fields = image_fields(image, "mono8")
                fields["encoding"] = encoding_of(k)
                writer.write_message(f"/{side}/image_raw", schemas["sensor_msgs/msg/Image"],
                                     {**fields, "header": header}, log_time=int(stamp * 1e9))
        writer.finish()


def test_mcap_bag_with_camera_info_and_bad_frames(tmp_path, rig, background_frames, renders, capsys):
    frames = [(1.0 + 0.01 * k, *pair) for k, pair in enumerate(background_frames[:3])]
    frames += [(1.05, renders("3d")[0], None),  # the right frame was dropped
               (1.06, *renders("3d")),  # unsupported encoding (set below)
               (1.07, *renders("3d"))]
    bag = tmp_path / "recording.mcap"
    write_bag(bag, rig, frames, encoding_of=lambda k: "yuv422" if k == 4 else "mono8")
    output = tmp_path / "new" / "out.csv"  # its folder is made
    assert main([str(bag), "--params", str(params_file(tmp_path, rig, tracking={"enabled": True})),
                 "--output", str(output), "--quiet"]) == 0
    header, rows = read_rows(output)
    assert header[-6:] == ["vx", "vy", "vz", "ax", "ay", "az"]
    assert set(rows[:, 0]) == {4}  # index of the synchronised pair (the unusable yuv422 pair is pair 3)
    assert np.all(np.isnan(rows[:, -6:]))  # tracking needs 5 frames before it reports motion
    distance, _ = distance_to_curve(rows[:, 4:7], SHAPES["3d"])
    assert np.sqrt(np.mean(distance ** 2)) < 1e-4  # calibration from the bag's camera_info
    report = capsys.readouterr().out
    assert "unsupported image encoding 'yuv422'" in report and "without a partner" in report
    assert "1  needle measured" in report


def test_a_bag_is_opened_once_and_its_camera_info_decoded_by_the_project(tmp_path, rig, background_frames, renders,
                                                                          monkeypatch):
    """One BagReader per run (its summaries read once: before, up to four), the calibration from its camera_info
    messages decoded by needle_common.cdr (before: mcap_ros2's decoder on a second opening of every file)."""
    from needle_common.bag_reader import BagReader
    import needle_vision.offline as offline

    bag = tmp_path / "recording.mcap"
    write_bag(bag, rig, [(1.0 + 0.01 * k, *pair) for k, pair in enumerate(background_frames[:3])]
              + [(1.03, *renders("planar"))])
    opened, decoded = [], []

    class CountedReader(BagReader):
        def __init__(self, *arguments, **options) -> None:
            opened.append(arguments[0])
            super().__init__(*arguments, **options)

    def counted_camera_info(data):
        decoded.append(bytes(data[:4]))
        return camera_info(data)
    monkeypatch.setattr(offline, "BagReader", CountedReader)
    monkeypatch.setattr(offline, "camera_info", counted_camera_info)
    assert main([str(bag), "--params", str(params_file(tmp_path, rig)), "--output", str(tmp_path / "out.csv"),
                 "--quiet", "--background", "median"]) == 0  # median: a pass of its own before the measured one
    assert opened == [bag] and len(decoded) == 2


def test_errors_are_reported_with_exit_code_2(tmp_path, capsys):
    def error(*arguments: str) -> str:
        assert main([*arguments, "--quiet", "--output", str(tmp_path / "out.csv")]) == 2
        message = capsys.readouterr().err
        assert message.count("\n") == 1 and "Traceback" not in message and not (tmp_path / "out.csv").exists()
        return message

    assert "does not exist" in error(str(tmp_path / "absent.mcap"))
    frames = tmp_path / "frames"
    (frames / "left").mkdir(parents=True)
    (frames / "right").mkdir()
    assert "no images at all" in error(str(frames))
    for side in ("left", "right"):
        cv2.imwrite(str(frames / side / "0000.png"), np.zeros((4, 4), np.uint8))
    assert "needs calibration files" in error(str(frames))
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"sync_tolerance": -1.0}}}))
    assert "parameter 'sync_tolerance'" in error(str(frames), "--params", str(bad))
    # an output that cannot be written is refused before any pair is read (before: after all of them)
    for output, words in ((tmp_path, "is a directory"), (bad / "out.csv", "a file is in the way")):
        assert main([str(tmp_path / "absent.mcap"), "--quiet", "--output", str(output)]) == 2
        message = capsys.readouterr().err
        assert message.startswith("needle_stereo_offline: error: --output ") and words in message, message
    calibration = ["--left-calibration", "package://needle_vision/config/stereo/left.yaml",
                   "--right-calibration", "package://needle_vision/config/stereo/right.yaml"]
    (frames / "left" / "0001.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    (frames / "right" / "0001.png").mkdir()  # a directory with an image's name
    assert "cannot read image" in error(str(frames), *calibration, "--background", "none")
    assert "parameter 'needle_polarity'" in error(str(frames), *calibration, "--polarity", "grey")
    assert "neither first, median, none" in error(str(frames), *calibration, "--background", "elsewhere")
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + bytes(100))
    assert "cannot read" in error(str(corrupt), *calibration)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert "the file is empty (0 bytes)" in error(str(empty), *calibration)
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(bytes(64))
    assert re.search(r"cannot read '.*garbage.mcap': \S", error(str(garbage), *calibration))  # the reason given
    plain = tmp_path / "plain"
    plain.mkdir()
    assert "neither an .mcap file" in error(str(plain), *calibration)
