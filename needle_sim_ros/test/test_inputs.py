"""The simulator's input rules (needle_sim_ros.inputs), which the node and the offline stage share."""
import math

import numpy as np
import pytest

from needle_sim_ros.base_trajectory import PoseVerdict
from needle_sim_ros.inputs import InputRejected, SimulatorInputs, rejected_poses
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import simulation_from_parameters

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
QUARTER_TURN_Z = (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))  # base x along world y


def inputs(max_stamp_offset: float = math.inf) -> SimulatorInputs:
    return SimulatorInputs(simulation_from_parameters(PARAMETERS), "world", "needle_base", max_stamp_offset)


def test_poses_keep_their_stamps_unless_unset_or_off_the_live_clock():
    live = inputs(0.5)
    first = live.offer_pose("", 10.0, (0.0, 0.0, 0.0), QUARTER_TURN_Z, received=10.2)
    assert first == (PoseVerdict.ACCEPTED, 10.0, False)
    assert live.offer_pose("world", 0.0, (0, 0, 0), QUARTER_TURN_Z, received=10.3)[1:] == (10.3, True)
    assert live.offer_pose("world", 3.0, (0, 0, 0), QUARTER_TURN_Z, received=10.4)[1:] == (10.4, True)
    replay = inputs()  # simulated time: a recorded stamp far from the clock is kept
    assert replay.offer_pose("world", 3.0, (0, 0, 0), QUARTER_TURN_Z, received=10.4)[1:] == (3.0, False)
    with pytest.raises(InputRejected, match="frame 'camera'") as error:
        replay.offer_pose("camera", 4.0, (0, 0, 0), QUARTER_TURN_Z, received=4.0)
    assert error.value.kind == "wrong_frame"


def test_forces_in_the_base_frame_turn_with_the_base_and_bad_ones_are_refused():
    rules = inputs()
    with pytest.raises(InputRejected, match="no base pose yet") as error:
        rules.world_force("needle_base", (1.0, 0.0, 0.0), "tip_load_rejected")
    assert error.value.kind == "tip_load_rejected"
    rules.offer_pose("world", 1.0, (0.0, 0.0, 0.0), QUARTER_TURN_Z, received=1.0)
    # the base's x axis lies along world y: a force along base x pulls along world y
    assert np.allclose(rules.world_force("needle_base", (0.1, 0.0, 0.0), "k"), [0.0, 0.1, 0.0], atol=1e-15)
    assert np.array_equal(rules.world_force("", (0.1, 0.0, 0.0), "k"), [0.1, 0.0, 0.0])
    for frame, force, reason in (("camera", (0, 0, 0), "neither 'world' nor 'needle_base'"),
                                 ("world", (math.nan, 0, 0), "not finite")):
        with pytest.raises(InputRejected, match=reason):
            rules.world_force(frame, force, "k")
    rules.set_point_load("tip", 0.27, "needle_base", (0.0, 0.0, -0.1))
    assert np.allclose(rules.sim.point_loads["tip"].vector, [0.0, 0.0, -0.1])
    with pytest.raises(InputRejected, match="exceeds") as error:
        rules.set_point_load("tip", 0.27, "world", (0.0, 0.0, -100.0))
    assert error.value.kind == "point_load_rejected"


def test_twists_must_be_finite_in_the_world_frame_and_within_the_limits():
    rules = inputs()
    rules.set_twist("world", (0.01, 0.0, 0.0), (0.0, 0.0, 0.1), received=1.0)
    assert np.array_equal(rules.sim.twist, [1.0, 0.01, 0.0, 0.0, 0.0, 0.0, 0.1])
    for frame, linear, reason in (("needle_base", (0.0, 0.0, 0.0), "not in the world frame"),
                                  ("world", (math.inf, 0.0, 0.0), "not finite"),
                                  ("world", (50.0, 0.0, 0.0), "max_linear_speed")):
        with pytest.raises(InputRejected, match=reason) as error:
            rules.set_twist(frame, linear, (0.0, 0.0, 0.0), received=2.0)
        assert error.value.kind == "twist_rejected"


def test_the_offline_stage_takes_recorded_twists_as_the_node_does():
    from geometry_msgs.msg import TwistStamped

    from needle_sim_ros.offline.stages import SimulatorStage
    from needle_sim_ros.parameters.experiment import node_parameters

    stage = SimulatorStage(node_parameters("needle_simulator", {}))
    twist = TwistStamped()
    twist.header.frame_id, twist.twist.linear.x = "world", 0.02
    stage.on_twist(twist, 2_000_000_000)
    assert np.array_equal(stage.sim.twist, [2.0, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0])
    twist.header.frame_id = "camera"
    stage.on_twist(twist, 3_000_000_000)
    assert stage.rejected == {"twist_rejected": 1} and stage.sim.twist[0] == 2.0


def test_every_rejecting_verdict_counts_as_a_rejected_pose():
    """The diagnostics' rejected_poses counts each verdict whose text says "rejected" (out of range included: it was
    left out, so poses beyond pose_input.max_position never raised a WARN), and no accepted one."""
    counts = {verdict: 1 for verdict in PoseVerdict}
    rejecting = [verdict for verdict in PoseVerdict if verdict.value.startswith("rejected")]
    assert PoseVerdict.OUT_OF_RANGE in rejecting
    assert rejected_poses(counts) == len(rejecting)
    assert rejected_poses({PoseVerdict.OUT_OF_RANGE: 3, PoseVerdict.ACCEPTED: 5}) == 3


def test_a_tip_load_message_sets_the_topic_s_load_on_the_tip_in_the_world_frame():
    from geometry_msgs.msg import WrenchStamped

    from needle_sim_ros.simulation import TIP_LOAD_TOPIC

    rules = inputs()
    rules.offer_pose("world", 1.0, (0.0, 0.0, 0.0), QUARTER_TURN_Z, received=1.0)
    message = WrenchStamped()
    message.header.frame_id, message.wrench.force.x = "needle_base", 0.1
    rules.on_tip_load(message)
    load = rules.sim.point_loads[TIP_LOAD_TOPIC]  # replaced, not added, by the next message
    assert load.arc_length == rules.sim.model.props.length and np.allclose(load.vector, [0.0, 0.1, 0.0], atol=1e-15)
    message.header.frame_id, message.wrench.force.z = "world", -100.0
    with pytest.raises(InputRejected, match="exceeds") as error:
        rules.on_tip_load(message)
    assert error.value.kind == "tip_load_rejected" and list(rules.sim.point_loads) == [TIP_LOAD_TOPIC]
