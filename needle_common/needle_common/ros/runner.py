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
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node

from needle_common.parameters import ParameterError, ParamSpec, check_ros_arguments
from needle_common.ros.command_line import EXIT_BAD_ARGUMENTS, checked_command_line, init_rclpy


def run_node(make_node: Callable[[], Node], name: str, args=None,
             specs: Sequence[ParamSpec] | None = None) -> int:
    """Spin one node until SIGINT/SIGTERM; a bad command line (malformed ROS arguments, other arguments, a bad
    ``--params-file`` checked against ``specs`` before rclpy reads it) or a ParameterError at construction exits
    with code 2.

    Optional node hooks: ``start()`` after construction (e.g. a real-time thread), ``finish()`` before destruction
    (e.g. stop that thread, finalize a log file).
    """
    argv, logger = sys.argv if args is None else args, rclpy.logging.get_logger(name)
    if checked_command_line(argv, logger, name, lambda _: check_ros_arguments(argv, name, specs, logger.warning),
                            takes_others=False) is None:
        return EXIT_BAD_ARGUMENTS
    return run_nodes([make_node], args, logger, name)


def run_nodes(makers: Sequence[Callable[[], Node]], args, logger, name: str) -> int:
    """``rclpy.init(args)`` (SIGINT/SIGTERM handled here), construct the nodes (a ParameterError: exit status 2),
    their ``start()`` hooks, spin them until SIGINT/SIGTERM (several: each in a thread of a MultiThreadedExecutor,
    each node's callbacks mutually exclusive); exit status 0."""
    if not init_rclpy(args, logger, name, own_signals=True):
        return EXIT_BAD_ARGUMENTS
    signals = StopSignals()  # before any node: e.g. the simulator's haptic zero goes out before rclpy shuts down
    nodes = []
    try:
        for make in makers:
            nodes.append(make())
    except ParameterError as error:
        logger.fatal(str(error))
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
        return EXIT_BAD_ARGUMENTS
    executor = SingleThreadedExecutor() if len(nodes) == 1 else MultiThreadedExecutor(num_threads=len(nodes) + 1)
    for node in nodes:
        executor.add_node(node)
        if hasattr(node, "start"):
            node.start()
    if len(nodes) > 1:
        logger.info(f"running {', '.join(node.get_name() for node in nodes)} in one process")
    spin_until_shutdown(executor, nodes, signals)
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


def spin_until_shutdown(executor: Executor, nodes: Sequence[Node], signals: StopSignals) -> None:
    """Spin until SIGINT/SIGTERM (``signals``, checked every :data:`SPIN_SLICE`), then the nodes' ``finish()``
    hooks, their destruction and rclpy's shutdown (also when an exception escapes the executor)."""
    try:
        while signals.received is None and rclpy.ok():
            executor.spin_once(timeout_sec=SPIN_SLICE)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:  # the context was shut down while the executor waited: a shutdown like the others
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
