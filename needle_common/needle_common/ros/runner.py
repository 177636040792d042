"""The `main` of every node of the suite: init, construct, spin, and a clean, defined exit.

SIGINT and SIGTERM are handled here, not by rclpy: rclpy's handler shuts the context down at once, after which a
node can publish nothing more, not even the zero a haptic output owes its arm. Here a signal ends the spinning
(within :data:`SPIN_SLICE`), the nodes' ``finish()`` hooks run with the context alive, then rclpy shuts down; the
exit status is 0. An exception escaping the executor runs the same hooks, then propagates (exit status 1 with its
traceback: a crash does not pretend success). SIGKILL cannot be handled by any process.
"""
from __future__ import annotations

import signal
import sys
from typing import Callable, Sequence

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from needle_common.parameters import ParameterError, ParamSpec, check_ros_arguments
from needle_common.ros.command_line import EXIT_BAD_ARGUMENTS, init_rclpy, non_ros_arguments


def run_node(make_node: Callable[[], Node], name: str, args=None,
             specs: Sequence[ParamSpec] | None = None) -> int:
    """Spin one node until SIGINT/SIGTERM; a bad command line (malformed ROS arguments, other arguments, a bad
    ``--params-file`` checked against ``specs`` before rclpy reads it) or a ParameterError at construction exits
    with code 2.

    Optional node hooks: ``start()`` after construction (e.g. a real-time thread), ``finish()`` before destruction
    (e.g. stop that thread, finalize a log file).
    """
    argv, logger = sys.argv if args is None else args, rclpy.logging.get_logger(name)
    if non_ros_arguments(argv, logger, name, takes_others=False) is None:
        return EXIT_BAD_ARGUMENTS
    try:
        check_ros_arguments(argv, name, specs, logger.warning)
    except ParameterError as error:
        logger.fatal(str(error))
        return EXIT_BAD_ARGUMENTS
    if not init_rclpy(args, logger, name, own_signals=True):
        return EXIT_BAD_ARGUMENTS
    signals = StopSignals()
    try:
        node = make_node()
    except ParameterError as error:
        logger.fatal(str(error))
        rclpy.try_shutdown()
        return EXIT_BAD_ARGUMENTS
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    if hasattr(node, "start"):
        node.start()
    spin_until_shutdown(executor, [node], signals)
    return 0


SPIN_SLICE = 0.05  # [s] longest executor wait between checks for a stop signal


class StopSignals:
    """SIGINT/SIGTERM recorded as a request to stop (rclpy initialised with ``own_signals``); a second signal while
    stopping interrupts the stop (KeyboardInterrupt)."""

    def __init__(self) -> None:
        self.received: int | None = None
        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, self._on_signal)

    def _on_signal(self, number: int, frame) -> None:
        if self.received is not None:
            raise KeyboardInterrupt
        self.received = number


def spin_until_shutdown(executor: Executor, nodes: Sequence[Node], signals: StopSignals | None = None) -> None:
    """Spin until SIGINT/SIGTERM (``signals``: ours, checked every :data:`SPIN_SLICE`; without: rclpy's, and a
    context shut down while the executor waited is such a shutdown too, not an error), then the nodes' ``finish()``
    hooks, their destruction and rclpy's shutdown (also when an exception escapes the executor)."""
    try:
        if signals is None:
            executor.spin()
        while signals is not None and signals.received is None and rclpy.ok():
            executor.spin_once(timeout_sec=SPIN_SLICE)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:  # the context was shut down (SIGINT) while the executor waited: a shutdown like the others
        if rclpy.ok():
            raise
    finally:
        for node in nodes:
            if hasattr(node, "finish"):
                node.finish()
        executor.shutdown()
        for node in nodes:
            try:
                node.destroy_node()
            except RCLError:  # entities already invalidated by the shutdown
                pass
        rclpy.try_shutdown()
