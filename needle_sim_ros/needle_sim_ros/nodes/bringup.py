"""``needle_bringup``: needle_simulator, needle_stereo and needle_compare composed in one process (no launch needed).

    needle_bringup [--experiment config/experiments/dynamic_pitch.yaml] [--no-stereo] [--ros-args ...]

Each node is the class of its own executable. A MultiThreadedExecutor spins the three (each node's callbacks stay
mutually exclusive; the nodes run concurrently) and the simulator keeps its own integration thread. The comparison's
inputs are remapped onto the other nodes' outputs (``needle_compare:model/shape:=needle/shape``,
``needle_compare:measured/shape:=needle/measured_shape``) unless the command line remaps them first. With
``--experiment`` the node config files (``config/needle_<node>.yaml``) and then the experiment file are passed as
parameter files, and the experiment decides whether the stereo node runs. ROS arguments apply as for any node
(``-p`` to all three; target one node with its section in a ``--params-file``). On SIGINT/SIGTERM the comparison
finalizes its MCAP log and summary. Exit status 2: a parameter is invalid (the log names it).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import rclpy
from rclpy.executors import MultiThreadedExecutor

from needle_common.parameters import ParameterError
from needle_common.ros.command_line import EXIT_BAD_ARGUMENTS, init_rclpy, non_ros_arguments
from needle_common.ros.runner import StopSignals, spin_until_shutdown

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
        from needle_sim_ros.parameters.experiment import load_experiment
        experiment = load_experiment(args.experiment)
        for path in dict.fromkeys(p for node_files in experiment.files.values() for p in node_files):
            files += ["--params-file", str(path)]
        stereo = stereo and experiment.settings.stereo
    remaps = [a for rule in COMPARE_REMAPS for a in ("-r", rule)]
    return [argv[0], "--ros-args", *files, "--", *argv[1:], "--ros-args", *remaps], stereo


def check_node_arguments(rcl_args: list[str], stereo: bool, logger) -> None:
    """Every --params-file checked for each node before rclpy reads them (ParameterError, a ValueError)."""
    from needle_common.parameters import check_ros_arguments
    from needle_vision.parameters import SPECS as STEREO_PARAMETERS

    from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS
    from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
    nodes = {"needle_simulator": SIMULATOR_PARAMETERS, "needle_compare": COMPARE_PARAMETERS,
             **({"needle_stereo": STEREO_PARAMETERS} if stereo else {})}
    for name, specs in nodes.items():  # a '/**' section reaches all three nodes: each ignores the others' names
        others = {spec.name for other, other_specs in nodes.items() if other != name for spec in other_specs}
        check_ros_arguments(rcl_args, name, specs, logger.warning, others)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    logger = rclpy.logging.get_logger(NAME)
    others = non_ros_arguments(argv, logger, NAME, takes_others=True)
    if others is None:
        return EXIT_BAD_ARGUMENTS
    args = parse_arguments(others[1:])
    try:
        rcl_args, stereo = rcl_arguments(argv, args)
        check_node_arguments(rcl_args, stereo, logger)
    except ValueError as error:
        logger.fatal(str(error))
        return EXIT_BAD_ARGUMENTS
    if not init_rclpy(rcl_args, logger, NAME, own_signals=True):
        return EXIT_BAD_ARGUMENTS
    signals = StopSignals()  # the simulator's haptic zero goes out before rclpy shuts down
    from needle_vision.ros.stereo_node import NeedleStereoNode

    from needle_sim_ros.nodes.compare_node import CompareNode
    from needle_sim_ros.nodes.simulator_node import NeedleSimulatorNode
    nodes = []
    try:
        for make in (NeedleSimulatorNode, *((NeedleStereoNode,) if stereo else ()), CompareNode):
            nodes.append(make())
    except ParameterError as error:
        logger.fatal(str(error))
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
        return EXIT_BAD_ARGUMENTS
    executor = MultiThreadedExecutor(num_threads=len(nodes) + 1)
    for node in nodes:
        executor.add_node(node)
        if hasattr(node, "start"):  # the hooks of needle_common.ros.runner.run_node
            node.start()
    logger.info(f"running {', '.join(node.get_name() for node in nodes)} in one process")
    spin_until_shutdown(executor, nodes, signals)
    return 0


if __name__ == "__main__":
    sys.exit(main())
