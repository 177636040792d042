"""The needle_sim pipeline: simulator, stereo reconstruction and comparison (bringup.launch.py with the
measurement side on).

    ros2 launch needle_sim_ros needle_pipeline.launch.py                                  # live, wall-clock time
    ros2 launch needle_sim_ros needle_pipeline.launch.py bag:=bags/dynamic_pitch.mcap experiment:=dynamic_pitch

With a bag: mode replay (simulated time, the bag plays once the simulator is active); without: mode sim. Every
run logs to a new needle_compare_<time>_<pid>.mcap unless log:=... names one. Without launch (not installable
from PyPI), ``needle_bringup`` composes the same nodes in one process.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.substitutions import FindPackageShare

FORWARDED = {
    "bag": ("", "rosbag2 MCAP to replay (empty: live, wall-clock time)"),
    "experiment": ("", "experiment parameter file: a name in config/experiments or a path"),
    "stereo": ("true", "run the stereo reconstruction"),
    "image_transport": ("raw", "images of the stereo reconstruction: raw | compressed (with a bag: its images played "
                        "as PNG CompressedImage)"),
    "log": ("", "MCAP log of the comparison; empty: a new needle_compare_<time>_<pid>.mcap in log_dir"),
    "log_dir": (".", "directory of the generated log names"),
}


def generate_launch_description() -> LaunchDescription:
    bag = LaunchConfiguration("bag")
    mode = PythonExpression(["'replay' if '", bag, "' else 'sim'"])
    arguments = {name: LaunchConfiguration(name) for name in FORWARDED}
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, text) in FORWARDED.items()),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(
                PathJoinSubstitution([FindPackageShare("needle_sim_ros"), "launch", "bringup.launch.py"])),
            launch_arguments={**arguments, "mode": mode, "compare": "true"}.items()),
    ])
