"""The needle_sim pipeline on a full ROS 2 Jazzy install: simulator, stereo reconstruction and comparison.

    ros2 launch needle_sim_ros needle_pipeline.launch.py                      # live, wall-clock time
    ros2 launch needle_sim_ros needle_pipeline.launch.py bag:=/path/to.mcap   # replay a bag with ros2 bag play --clock

Without launch (not installable from PyPI), `needle_bringup` composes the same three nodes in one process.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.conditions import IfCondition, LaunchConfigurationNotEquals
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    config = PathJoinSubstitution([FindPackageShare("needle_sim_ros"), "config"])
    bag = LaunchConfiguration("bag")
    use_sim_time = PythonExpression(["'", bag, "' != ''"])
    common = {"use_sim_time": use_sim_time}
    return LaunchDescription([
        DeclareLaunchArgument("bag", default_value="", description="rosbag2 MCAP to replay (empty: live)"),
        DeclareLaunchArgument("log", default_value="needle_compare.mcap", description="MCAP log of the comparison"),
        DeclareLaunchArgument("stereo", default_value="true", description="run the stereo reconstruction"),
        # The wrench is offered reliably so that needle_compare (a reliable subscriber) can record it.
        Node(package="needle_sim_ros", executable="needle_simulator", name="needle_simulator", output="screen",
             parameters=[PathJoinSubstitution([config, "needle_simulator.yaml"]), common, {"qos.wrench": "reliable"}]),
        Node(package="needle_vision", executable="needle_stereo", name="needle_stereo", output="screen",
             condition=IfCondition(LaunchConfiguration("stereo")),
             parameters=[PathJoinSubstitution([config, "needle_stereo.yaml"]), common, {"output_frame": "world"}]),
        Node(package="needle_sim_ros", executable="needle_compare", name="needle_compare", output="screen",
             parameters=[PathJoinSubstitution([config, "needle_compare.yaml"]), common,
                         {"log.path": LaunchConfiguration("log")}],
             remappings=[("model/shape", "needle/shape"), ("measured/shape", "needle/measured_shape")]),
        ExecuteProcess(cmd=["ros2", "bag", "play", "--clock", "1000", bag], output="screen",
                       condition=LaunchConfigurationNotEquals("bag", "")),
    ])
