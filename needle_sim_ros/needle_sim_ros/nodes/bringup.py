"""``needle_bringup``: needle_simulator, needle_stereo and needle_compare composed in one process (no launch needed).

    needle_bringup [--experiment config/experiments/dynamic_pitch.yaml] [--no-stereo] [--ros-args ...]

Each node is the class of its own executable, spun by a MultiThreadedExecutor (the simulator keeps its integration
thread). The comparison's inputs are remapped onto the other nodes' outputs unless the command line remaps them
first. ``--experiment`` passes the node config files and then the experiment file as parameter files, and the
experiment decides whether the stereo node runs. ROS arguments apply as for any node (``-p`` to all three; one node:
its section in a ``--params-file``). On SIGINT/SIGTERM the comparison finalizes its log and summary. Exit status 2:
a parameter is invalid (the log names it).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import rclpy

from needle_common.parameters import check_ros_arguments
from needle_common.ros.command_line import EXIT_BAD_ARGUMENTS, checked_command_line
from needle_common.ros.runner import run_nodes

from needle_sim_ros.parameters.experiment import NODES, load_experiment, node_specs

NAME = "needle_bringup"
COMPARE_REMAPS = ("needle_compare:model/shape:=needle/shape", "needle_compare:measured/shape:=needle/measured_shape")


def parse_arguments(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog=NAME, description=__doc__.split("\n\n")[0],
                                     epilog="ROS arguments follow --ros-args (--params-file, -p, -r, --log-level).")
    parser.add_argument("--experiment", type=Path, help="experiment params file (config/experiments/<bag>.yaml): "
                        "adds the node config files and the experiment as parameter files")
    parser.add_argument("--no-stereo", action="store_true", help="do not run needle_stereo (the measurement "
                        "comes from elsewhere, e.g. a shape-sensing needle in the bag)")
    return parser.parse_args(argv)


def rcl_arguments(argv: list[str], args: argparse.Namespace) -> tuple[list[str], bool]:
    """The arguments for rclpy.init and whether the stereo node runs. The experiment's parameter files come
    before the command line's ROS arguments (later parameter values win), the comparison's remaps after them (the
    first matching rule wins), so the command line overrides both."""
    files: list[str] = []
    stereo = not args.no_stereo
    if args.experiment is not None:
        experiment = load_experiment(args.experiment)
        for path in dict.fromkeys(p for node_files in experiment.files.values() for p in node_files):
            files += ["--params-file", str(path)]
        stereo = stereo and experiment.settings.stereo
    remaps = [a for rule in COMPARE_REMAPS for a in ("-r", rule)]
    return [argv[0], "--ros-args", *files, "--", *argv[1:], "--ros-args", *remaps], stereo


def check_node_arguments(rcl_args: list[str], stereo: bool, logger) -> None:
    """Every --params-file checked for each node before rclpy reads them (ParameterError, a ValueError)."""
    nodes = {name: node_specs(name) for name in NODES if stereo or name != "needle_stereo"}
    for name, specs in nodes.items():  # a '/**' section reaches all three nodes: each ignores the others' names
        others = {spec.name for other, other_specs in nodes.items() if other != name for spec in other_specs}
        check_ros_arguments(rcl_args, name, specs, logger.warning, others)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    logger = rclpy.logging.get_logger(NAME)

    def arguments(others: list[str]) -> tuple[list[str], bool]:
        rcl_args, stereo = rcl_arguments(argv, parse_arguments(others[1:]))
        check_node_arguments(rcl_args, stereo, logger)
        return rcl_args, stereo
    checked = checked_command_line(argv, logger, NAME, arguments)
    if checked is None:
        return EXIT_BAD_ARGUMENTS
    rcl_args, stereo = checked
    from needle_vision.ros.stereo_node import NeedleStereoNode

    from needle_sim_ros.nodes.compare_node import CompareNode
    from needle_sim_ros.nodes.simulator_node import NeedleSimulatorNode
    return run_nodes((NeedleSimulatorNode, *((NeedleStereoNode,) if stereo else ()), CompareNode), rcl_args, logger,
                     NAME)


if __name__ == "__main__":
    sys.exit(main())
