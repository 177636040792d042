"""A node's command line before rclpy starts: malformed ROS arguments (rcl rejects them with a traceback) and
arguments a node does not take become one fatal log line; the caller exits with :data:`EXIT_BAD_ARGUMENTS`."""
from __future__ import annotations

import re
from typing import Callable, Sequence, TypeVar

import rclpy
from rclpy._rclpy_pybind11 import RCLError, UnknownROSArgsError
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from needle_common.parameters import ros_arguments

EXIT_BAD_ARGUMENTS = 2
ROS_ARGUMENTS_USAGE = "--ros-args -p NAME:=VALUE --params-file FILE -r FROM:=TO"
Checked = TypeVar("Checked")


def _rcl_message(error: Exception) -> str:
    """rcl's complaint without its source location (``..., at /path/arguments.c:356``)."""
    if isinstance(error, UnknownROSArgsError):
        return f"unknown ROS argument(s) {error}"
    message = re.sub(r",? at \S+:\d+$", "", str(error))
    return message.removeprefix("Failed to parse ROS arguments: ").removeprefix("failed to initialize rcl: ")


def non_ros_arguments(argv: Sequence[str], logger, name: str, takes_others: bool) -> list[str] | None:
    """``argv`` without its ROS arguments (``argv[0]`` first), or None after logging one fatal line: the ROS arguments
    do not parse (params files aside: :class:`needle_common.parameters.RosArguments`), or there are others and the
    node takes none (``takes_others`` False)."""
    try:
        others = remove_ros_args(ros_arguments(argv).rcl_arguments)
    except (UnknownROSArgsError, RCLError) as error:
        usage = f"{name} --help" if takes_others else f"{name} {ROS_ARGUMENTS_USAGE}"
        logger.fatal(f"invalid ROS arguments: {_rcl_message(error)} (usage: {usage})")
        return None
    if not takes_others and len(others) > 1:
        logger.fatal(f"unexpected argument '{others[1]}': {name} takes ROS arguments only ({ROS_ARGUMENTS_USAGE})")
        return None
    return others


def checked_command_line(argv: Sequence[str], logger, name: str, check: Callable[[list[str]], Checked],
                         takes_others: bool = True) -> Checked | None:
    """``check(others)``, which parses the non-ROS arguments and checks the params files; None after one fatal log
    line where the ROS arguments are malformed or ``check`` raises a ValueError (a ParameterError is one)."""
    others = non_ros_arguments(argv, logger, name, takes_others)
    if others is None:
        return None
    try:
        return check(others)
    except ValueError as error:
        logger.fatal(str(error))
        return None


def init_rclpy(args: Sequence[str] | None, logger, name: str, own_signals: bool = False) -> bool:
    """``rclpy.init(args=args)``; False after one fatal log line if rcl refuses the arguments (e.g. a params file
    only rcl's parser rejects). ``own_signals``: rclpy installs no SIGINT/SIGTERM handler (its handler shuts the
    context down at once, before the node could publish anything more); the caller handles them."""
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO if own_signals else None)
    except (UnknownROSArgsError, RCLError) as error:
        logger.fatal(f"invalid ROS arguments: {_rcl_message(error)} (usage: {name} --help)")
        return False
    return True
