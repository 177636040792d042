"""Moved to :mod:`needle_common.ros.command_line`; the stereo node still imports it from here."""
from needle_common.ros.command_line import EXIT_BAD_ARGUMENTS, init_rclpy, non_ros_arguments

__all__ = ["EXIT_BAD_ARGUMENTS", "init_rclpy", "non_ros_arguments"]
