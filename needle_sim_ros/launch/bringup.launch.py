"""needle_sim bringup: the simulator as a managed node, with the measurement side and a bag player by mode.

    ros2 launch needle_sim_ros bringup.launch.py mode:=sim                 # wall clock, poses from pose_topic
    ros2 launch needle_sim_ros bringup.launch.py mode:=replay bag:=bags/dynamic_pitch.mcap experiment:=dynamic_pitch
    ros2 launch needle_sim_ros bringup.launch.py mode:=hil pose_topic:=/PSM1/measured_cp pose_frame:=PSM1_base \
        wrench_topic:=/PSM1/needle/wrench                                 # a CRTK (dVRK-style) robot driver

Modes (in the spirit of SmartNeedle's sim_level): ``sim`` runs the simulator in wall-clock time on poses from
``pose_topic``; ``replay`` adds stereo reconstruction, comparison and the bag player in simulated time (the bag
starts only once the simulator is active); ``hil`` drives the simulator from a robot driver's measured pose
(CRTK ``measured_cp``, geometry_msgs/PoseStamped) and sends the needle's wrench on the holder to
``wrench_topic`` (geometry_msgs/WrenchStamped in ``needle_base``). The simulator is sequenced through its
lifecycle: configure at start, then activate (unless ``activate:=false``: a robot bringup activates it).
"""
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.events import matches_action
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from launch_ros.substitutions import FindPackageShare
from lifecycle_msgs.msg import Transition

from needle_sim_ros.launch_support import MODES, experiment_file, mode_settings, player_arguments, unique_log_path

ARGUMENTS = {
    "mode": ("sim", f"what runs: {' | '.join(MODES)}"),
    "bag": ("", "rosbag2 MCAP to replay (mode:=replay)"),
    "experiment": ("", "experiment parameter file: a name in config/experiments (e.g. dynamic_pitch) or a path"),
    "stereo": ("auto", "run needle_stereo: true | false | auto (replay only)"),
    "compare": ("auto", "run needle_compare: true | false | auto (replay only)"),
    "log": ("", "MCAP log of the comparison; empty: a new needle_compare_<time>_<pid>.mcap in log_dir"),
    "log_dir": (".", "directory of the generated log names"),
    "pose_topic": ("base_pose", "geometry_msgs/PoseStamped of the needle holder (CRTK: <arm>/measured_cp)"),
    "pose_frame": ("world", "frame_id of those poses: the simulator's world frame (frames.world)"),
    "wrench_topic": ("wrench", "geometry_msgs/WrenchStamped out: the needle's wrench on the holder"),
    "namespace": ("", "namespace of all nodes"),
    "activate": ("true", "activate the simulator after configuring it (false: leave it to a lifecycle manager)"),
}


def _flag(value: str, automatic: bool) -> bool:
    return automatic if value == "auto" else value.lower() in ("true", "1", "yes")


def _nodes(context):
    arg = {name: context.launch_configurations[name] for name in ARGUMENTS}
    config = FindPackageShare("needle_sim_ros").perform(context) + "/config"
    stereo_config = FindPackageShare("needle_vision").perform(context) + "/config"
    settings = mode_settings(arg["mode"], arg["bag"])
    experiment = experiment_file(arg["experiment"], Path(config))
    extra = [experiment] if experiment else []
    common = {"use_sim_time": settings["use_sim_time"]}
    simulator = LifecycleNode(
        package="needle_sim_ros", executable="needle_simulator", name="needle_simulator",
        namespace=arg["namespace"], output="screen",
        parameters=[f"{config}/needle_simulator.yaml", *extra, common,
                    {"autostart": False, "frames.world": arg["pose_frame"]}],
        remappings=[("base_pose", arg["pose_topic"]), ("wrench", arg["wrench_topic"])])
    actions = [simulator,
               EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(simulator),
                                           transition_id=Transition.TRANSITION_CONFIGURE))]
    if _flag(arg["activate"], True):
        actions.append(RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=simulator, start_state="configuring", goal_state="inactive",
            entities=[EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(simulator),
                                                  transition_id=Transition.TRANSITION_ACTIVATE))])))
    nodes = ["needle_simulator"]  # the nodes the bag player waits for
    if _flag(arg["stereo"], settings["stereo"]):
        nodes.append("needle_stereo")
        actions.append(Node(package="needle_vision", executable="needle_stereo", name="needle_stereo",
                            namespace=arg["namespace"], output="screen",
                            parameters=[f"{stereo_config}/needle_stereo.yaml", common,
                                        {"output_frame": "world"}, *extra]))
    if _flag(arg["compare"], settings["compare"]):
        nodes.append("needle_compare")
        actions.append(Node(
            package="needle_sim_ros", executable="needle_compare", name="needle_compare",
            namespace=arg["namespace"], output="screen",
            parameters=[f"{config}/needle_compare.yaml", *extra, common,
                        {"log.path": unique_log_path(arg["log"], arg["log_dir"])}],
            remappings=[("model/shape", "needle/shape"), ("measured/shape", "needle/measured_shape"),
                        ("base_pose", arg["pose_topic"]), ("wrench", arg["wrench_topic"])]))
    if settings["player"]:  # once the simulator is active and every node has matched the bag's topics it reads
        player = Node(package="needle_sim_ros", executable="needle_replay", name="needle_replay",
                      namespace=arg["namespace"], output="screen",
                      arguments=player_arguments(arg["bag"], arg["namespace"], nodes))
        actions.append(RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=simulator, start_state="activating", goal_state="active", entities=[player])))
    return actions


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in ARGUMENTS.items()),
        OpaqueFunction(function=_nodes),
    ])
