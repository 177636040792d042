"""Base and tip told by the needle's base pose (issue 16): the pose store, the CDR reader, the pipeline's order of
preference (base pose, temporal continuity, base_point) and needle_stereo_offline --base-pose-topic."""
import math

import numpy as np
import pytest

from test_offline import params_file, read_rows, write_bag
from vision_shapes import SHAPES
from needle_vision.streams.base_pose import BasePoseStore, output_from_pose_frame
from needle_vision.offline import main
from needle_vision.pipeline import FrameStatus, StereoConfig, StereoNeedlePipeline
from needle_vision.matching.reconstruction import ReconstructionConfig
from needle_common.transforms import RigidTransform

MOVING = ("straight", "planar", "3d", "hook")
BASE = np.zeros(3)  # the shapes' base (clamp point A) in the world frame
WRONG_BASE_POINT = SHAPES["straight"][-1]  # a base_point at the first frame's tip: every frame reversed


def pose_fields(stamp: float, position, orientation=(0.0, 0.0, 0.0, 1.0), frame_id: str = "world") -> dict:
    return {"header": {"stamp": {"sec": int(stamp), "nanosec": int(round(stamp % 1 * 1e9))}, "frame_id": frame_id},
            "pose": {"position": dict(zip("xyz", map(float, position))),
                     "orientation": dict(zip("xyzw", map(float, orientation)))}}


def test_store_gives_the_nearest_fresh_pose_with_its_rotated_offset():
    half_turn_z = (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))  # 90 deg about z
    store = BasePoseStore(max_age=0.01, offset=(0.02, 0.0, 0.0))
    store.add(1.0, (1.0, 2.0, 3.0), half_turn_z)
    store.add(0.9, (5.0, 5.0, 5.0), (0.0, 0.0, 0.0, 2.0))  # out of order, unnormalized quaternion
    np.testing.assert_allclose(store.base_at(1.005), [1.0, 2.02, 3.0])  # x offset turned onto y
    np.testing.assert_allclose(store.base_at(0.895), [5.02, 5.0, 5.0])
    assert store.base_at(1.02) is None and store.base_at(0.95) is None  # older / newer than max_age
    shifted = BasePoseStore(max_age=1.0)
    shifted.add(0.0, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), RigidTransform(translation=[0.0, 0.0, 0.5]))
    np.testing.assert_allclose(shifted.base_at(0.0), [1.0, 0.0, 0.5])


@pytest.mark.parametrize("position, orientation, message", [
    ((np.nan, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), "non-finite"),
    ((0.0, 0.0, 0.0), (0.0, np.inf, 0.0, 1.0), "non-finite"),
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), "zero quaternion"),
])
def test_store_refuses_unusable_poses(position, orientation, message):
    store = BasePoseStore(max_age=1.0)
    with pytest.raises(ValueError, match=message):
        store.add(0.0, position, orientation)
    assert len(store) == 0 and store.base_at(0.0) is None


def test_pose_frames_usable_for_the_output_frame():
    camera = RigidTransform(translation=[0.1, 0.0, 0.0])
    assert np.allclose(output_from_pose_frame("world", "world", ("cam",), camera).translation, 0)
    assert output_from_pose_frame("cam", "world", ("cam",), camera) is camera
    assert np.allclose(output_from_pose_frame("", "world", ("cam",), camera).translation, 0)
    assert output_from_pose_frame("map", "world", ("cam",), camera) is None


def measure_sequence(rig, background_frames, renders, poses=None, max_age=0.1):
    """Orderings and whether each frame's first sample is the true base, for the moving needle with a
    base_point at the first frame's tip; ``poses``: (stamp, position) of base poses, world frame."""
    config = StereoConfig(background_frames=len(background_frames),
                          reconstruction=ReconstructionConfig(base_point=WRONG_BASE_POINT))
    store = BasePoseStore(max_age)
    pipeline = StereoNeedlePipeline(rig, config, rig.world_from_left, store)
    for k, pair in enumerate(background_frames):
        pipeline.process(0.01 * k, *pair)
    for stamp, position in poses or ():
        store.add(stamp, position, (0.0, 0.0, 0.0, 1.0))
    outcome = []
    for k, name in enumerate(MOVING):
        result = pipeline.process(1.0 + 0.01 * k, *renders(name))
        assert result.status is FrameStatus.MEASURED, result.reason
        outcome.append((result.ordering, bool(np.linalg.norm(result.measurement.points[0] - BASE) < 2e-3)))
    return outcome


def test_base_pose_orders_a_moving_needle_that_continuity_gets_wrong(rig, background_frames, renders):
    """Independent truth: the shapes' base is the origin. With base_point at the tip of the first frame, the
    first frame is reversed and continuity carries the reversal on; fresh base poses order every frame."""
    without = measure_sequence(rig, background_frames, renders)
    assert without[0] == ("base point", False) and all(o == ("continuity", False) for o in without[1:])
    poses = [(1.0 + 0.01 * k - 0.002, BASE) for k in range(len(MOVING))]  # 2 ms before each pair
    assert measure_sequence(rig, background_frames, renders, poses) == [("base pose", True)] * len(MOVING)
    stale = measure_sequence(rig, background_frames, renders, poses, max_age=0.001)  # too old: not used
    assert [o[0] for o in stale] == ["base point"] + ["continuity"] * (len(MOVING) - 1)


def test_offline_base_pose_topic_orders_base_and_tip(tmp_path, rig, background_frames, renders, capsys):
    """A bag with the needle moving and its base pose at 1 kHz-like spacing before each pair (world frame; one
    non-finite pose among them): base first in every pair, although base_point is at the first frame's tip."""
    frames = [(1.0 + 0.01 * k, *pair) for k, pair in enumerate(background_frames[:3])]
    frames += [(1.03 + 0.01 * k, *renders(name)) for k, name in enumerate(MOVING)]

    def extra(k: int):
        stamp = frames[k][0]
        bad = [("/base_pose", "geometry_msgs/msg/PoseStamped", pose_fields(stamp - 0.001, (np.nan, 0.0, 0.0)))]
        return [("/base_pose", "geometry_msgs/msg/PoseStamped", pose_fields(stamp - 0.002, BASE))] \
            + (bad if k == 4 else [])
    bag = tmp_path / "moving.mcap"
    write_bag(bag, rig, frames, extra=extra)
    params = params_file(tmp_path, rig, base_point=WRONG_BASE_POINT.tolist())
    output = tmp_path / "out.csv"
    assert main([str(bag), "--params", str(params), "--output", str(output), "--quiet"]) == 0
    _, rows = read_rows(output)
    without = capsys.readouterr().out
    firsts = rows[rows[:, 2] == 0]
    assert len(firsts) == len(MOVING) and np.all(np.linalg.norm(firsts[:, 4:7] - BASE, axis=1) > 0.1)  # premise
    assert main([str(bag), "--params", str(params), "--output", str(output), "--quiet",
                 "--base-pose-topic", "base_pose"]) == 0
    _, rows = read_rows(output)
    firsts = rows[rows[:, 2] == 0]
    assert len(firsts) == len(MOVING) and np.all(np.linalg.norm(firsts[:, 4:7] - BASE, axis=1) < 2e-3)
    report = capsys.readouterr().out
    assert f"told by: base pose {len(MOVING)}" in report and "told by" not in without
    assert "1  base pose ignored: non-finite" in report


def test_offline_base_pose_errors_exit_2(tmp_path, rig, background_frames, capsys):
    bag = tmp_path / "still.mcap"
    write_bag(bag, rig, [(1.0 + 0.01 * k, *pair) for k, pair in enumerate(background_frames[:4])])
    folder = tmp_path / "frames"
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True)
    bad_age = params_file(tmp_path, rig, base_pose={"max_age": -1.0})
    for arguments, message in ((["--base-pose-topic", "base_pose"], "no messages on the base pose topic"),
                               (["--base-pose-topic", "left/camera_info"], "not geometry_msgs/msg/PoseStamped"),
                               (["--base-pose-topic", "2bad//name"], "not a valid ROS 2 topic name"),
                               (["--base-pose-topic", "/left/image_raw"], "also an image topic"),
                               (["--params", str(bad_age)], "parameter 'base_pose.max_age'")):
        assert main([str(bag), "--output", str(tmp_path / "out.csv"), "--quiet", *arguments]) == 2, arguments
        error = capsys.readouterr().err
        assert message in error and error.count("\n") == 1 and "Traceback" not in error
    assert main([str(folder), "--base-pose-topic", "base_pose", "--quiet"]) == 2
    assert "needs an MCAP input" in capsys.readouterr().err

