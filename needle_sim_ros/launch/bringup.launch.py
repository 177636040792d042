"""needle_sim bringup: the simulator as a managed node, with the measurement side and a bag player by mode.

    ros2 launch needle_sim_ros bringup.launch.py mode:=sim                 # wall clock, poses from pose_topic
    ros2 launch needle_sim_ros bringup.launch.py mode:=replay bag:=bags/dynamic_pitch.mcap experiment:=dynamic_pitch
    ros2 launch needle_sim_ros bringup.launch.py mode:=replay bag:=bags/dynamic_pitch.mcap experiment:=dynamic_pitch \
        image_transport:=compressed          # the bag's images played and taken as CompressedImage (PNG)
    ros2 launch needle_sim_ros bringup.launch.py mode:=external experiment:=dynamic_pitch   # then, elsewhere:
        ros2 bag play bags/dynamic_pitch.mcap --clock 200
    ros2 launch needle_sim_ros bringup.launch.py mode:=hil namespace:=/PSM1 pose_topic:=measured_cp \
        pose_frame:=PSM1_base haptic_topic:=servo_cf experiment:=my_tool.yaml      # a CRTK (dVRK-style) arm

Modes: ``sim`` runs the simulator in wall-clock time on poses from ``pose_topic``; ``replay`` adds stereo
reconstruction, comparison and the bag player in simulated time (the bag plays once the simulator is active, and
the launch ends when the bag has played unless ``keep_alive:=true``); ``external`` is replay without the player
(simulated time from another /clock source, e.g. ``ros2 bag play --clock``); ``hil`` is the wall-clock simulator
with its haptic output on (``haptics.enable``): a robot driver's measured pose in (CRTK ``measured_cp``), the force
the operator should feel out on ``haptic_topic`` (CRTK ``servo_cf``).

The simulator configures and activates itself at start (its ``autostart``: no launch event to miss, see the README);
``activate:=false``: the launch only configures it; ``configure:=false``: no transition at all, a lifecycle manager
drives it. The simulator exiting with an error (a bad parameter, its configure rejected at start: status 2), or
failing a transition the launch sees (its transition_event), ends the launch with a non-zero status; so does the bag
player failing.
Experiment sections keyed by a bare node name apply in any namespace, the namespace of a parent launch's
PushRosNamespace included.
"""
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit
from launch.events import matches_action
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState, StateTransition
from launch_ros.substitutions import FindPackageShare
from lifecycle_msgs.msg import Transition

from needle_sim_ros.launch_support import (MODES, exit_error, experiment_file, failed_transition, flag,
                                           full_namespace, image_codec, image_transport, mode_settings,
                                           namespaced_params_file, player_arguments, unique_log_path)

ARGUMENTS = {
    "mode": ("sim", f"what runs: {' | '.join(MODES)}"),
    "bag": ("", "rosbag2 MCAP to replay (mode:=replay)"),
    "keep_alive": ("false", "mode:=replay: keep the nodes up when the bag has played (false: the launch ends)"),
    "experiment": ("", "experiment parameter file: a name in config/experiments (e.g. dynamic_pitch) or a path"),
    "stereo": ("auto", "run needle_stereo: true | false | auto (replay and external)"),
    "compare": ("auto", "run needle_compare: true | false | auto (replay and external)"),
    "image_transport": ("raw", "images of needle_stereo: raw (sensor_msgs/Image on left|right/image_raw) | "
                        "compressed (sensor_msgs/CompressedImage on left|right/image_raw/compressed; mode:=replay "
                        "plays the bag's raw images so, encoded with image_codec)"),
    "image_codec": ("png", "mode:=replay with image_transport:=compressed: png (lossless) | jpeg (quality 95)"),
    "log": ("", "MCAP log of the comparison; empty: a new needle_compare_<time>_<pid>.mcap in log_dir"),
    "log_dir": (".", "directory of the generated log names"),
    "pose_topic": ("base_pose", "geometry_msgs/PoseStamped of the needle holder (CRTK: <arm>/measured_cp)"),
    "pose_frame": ("world", "frame_id of those poses: the simulator's world frame (frames.world)"),
    "wrench_topic": ("wrench", "geometry_msgs/WrenchStamped out: the needle's wrench on the holder"),
    "haptic_topic": ("haptic/wrench", "geometry_msgs/WrenchStamped out (mode:=hil): the force to render "
                     "(CRTK: <arm>/servo_cf)"),
    "namespace": ("", "namespace of all nodes (relative: under a parent launch's PushRosNamespace)"),
    "configure": ("true", "configure the simulator at start (false: no lifecycle transition at all)"),
    "activate": ("true", "activate the simulator after configuring it (false: leave it to a lifecycle manager)"),
}


def _choice(name: str, value: str, automatic: bool) -> bool:
    return automatic if value == "auto" else flag(name, value)


def _ends_launch(name: str, shutdown_when_done: bool):
    """OnProcessExit's action: a non-zero exit fails the launch (an exception: launch exits 1), a clean one ends it
    if ``shutdown_when_done``."""
    def on_exit(event, context):
        error = exit_error(name, event.returncode, context.is_shutdown)
        if error:
            raise RuntimeError(error)
        return [Shutdown(reason=f"{name} is done")] if shutdown_when_done and not context.is_shutdown else []
    return on_exit


def _transition_failed(context):
    raise RuntimeError("needle_simulator failed a lifecycle transition (its log says why): the launch stops")


def _nodes(context):
    arg = {name: context.launch_configurations[name] for name in ARGUMENTS}
    config = FindPackageShare("needle_sim_ros").perform(context) + "/config"
    stereo_config = FindPackageShare("needle_vision").perform(context) + "/config"
    settings = mode_settings(arg["mode"], arg["bag"])
    experiment = namespaced_params_file(experiment_file(arg["experiment"], Path(config)))
    namespace = full_namespace(context.launch_configurations.get("ros_namespace"), arg["namespace"])
    extra = [experiment] if experiment else []
    common = {"use_sim_time": settings["use_sim_time"]}
    haptics = {"haptics.enable": True} if settings["haptics"] else {}
    configure = flag("configure", arg["configure"])
    autostart = configure and flag("activate", arg["activate"])
    simulator = LifecycleNode(
        package="needle_sim_ros", executable="needle_simulator", name="needle_simulator",
        namespace=arg["namespace"], output="screen",
        parameters=[f"{config}/needle_simulator.yaml", *extra, common, haptics,
                    {"autostart": autostart, "frames.world": arg["pose_frame"]}],
        remappings=[("base_pose", arg["pose_topic"]), ("wrench", arg["wrench_topic"]),
                    ("haptic/wrench", arg["haptic_topic"])])
    actions = [simulator,
               RegisterEventHandler(OnProcessExit(target_action=simulator,
                                                  on_exit=_ends_launch("needle_simulator", True))),
               RegisterEventHandler(OnStateTransition(
                   matcher=lambda event: isinstance(event, StateTransition) and event.action is simulator
                   and failed_transition(event.start_state, event.goal_state),
                   entities=[OpaqueFunction(function=_transition_failed)]))]
    if configure and not autostart:  # the change_state service, called until it answers
        actions.append(EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(simulator),
                                                   transition_id=Transition.TRANSITION_CONFIGURE)))
    nodes = ["needle_simulator"]  # the nodes the bag player waits for
    compressed = image_transport(arg["image_transport"]) == "compressed"
    if _choice("stereo", arg["stereo"], settings["stereo"]):
        nodes.append("needle_stereo")
        actions.append(Node(package="needle_vision", executable="needle_stereo", name="needle_stereo",
                            namespace=arg["namespace"], output="screen",
                            parameters=[f"{stereo_config}/needle_stereo.yaml", common,
                                        {"output_frame": "world"}, *extra,
                                        {"image_transport": image_transport(arg["image_transport"])}]))
    if _choice("compare", arg["compare"], settings["compare"]):
        nodes.append("needle_compare")
        actions.append(Node(
            package="needle_sim_ros", executable="needle_compare", name="needle_compare",
            namespace=arg["namespace"], output="screen",
            parameters=[f"{config}/needle_compare.yaml", *extra, common,
                        {"log.path": unique_log_path(arg["log"], arg["log_dir"])}],
            remappings=[("model/shape", "needle/shape"), ("measured/shape", "needle/measured_shape"),
                        ("base_pose", arg["pose_topic"]), ("wrench", arg["wrench_topic"])]))
    if settings["player"]:  # plays once every node has matched the bag's topics and takes input (the simulator: active)
        player = Node(package="needle_sim_ros", executable="needle_replay", name="needle_replay",
                      namespace=arg["namespace"], output="screen",
                      arguments=player_arguments(arg["bag"], namespace, nodes,
                                                 image_codec(arg["image_codec"]) if compressed else ""))
        # Activated by a lifecycle manager, any time later: the player starts at its first activation.
        start = player if autostart else RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=simulator, start_state="activating", goal_state="active", handle_once=True,
            entities=[player]))
        actions += [start, RegisterEventHandler(OnProcessExit(target_action=player, on_exit=_ends_launch(
            "needle_replay", not flag("keep_alive", arg["keep_alive"]))))]
    return actions


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in ARGUMENTS.items()),
        OpaqueFunction(function=_nodes),
    ])
