"""needle_replay: play a rosbag2 MCAP recording onto ROS topics with the recorded timing (like ``ros2 bag play``).

Options: ``needle_replay --help`` and README, "needle_replay". Messages go out as the recorded CDR bytes with the QoS
the recorded publishers offered. The start handshake (``--wait-for-subscribers``, ``--wait-for-nodes``) reads the
subscribers' own reports on the latched readiness topic (``needle_common.ros.input_status``): discovery is two-sided.
``--linger`` waits for every reliable subscriber's acknowledgement at the end (a lost fragment is resent only then).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Callable

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger

from needle_common.cli_types import non_negative, positive
from needle_common.parameters import check_ros_arguments
from needle_common.ros.command_line import EXIT_BAD_ARGUMENTS, checked_command_line, init_rclpy
from needle_common.ros.input_status import InputReports, fully_qualified_name
from needle_vision.streams.image_codec import ImageFormatError, compress_image, deserialize_image, image_to_array

from needle_sim_ros.messages import cdr
from needle_sim_ros.nodes.recording_bridge import message_class, playback_qos
from needle_common.bag_reader import BagReadError, BagReader
from needle_sim_ros.recording.playback import EXPECTED_TYPES, PlaybackSchedule

NODE_NAME = "needle_replay"
LINGER = 10.0  # [s] longest wait for the acknowledgements after the last message (--linger)


def _node_name(text: str) -> str:
    """A node's fully qualified name; a name without the leading slash is in the root namespace."""
    name = text.strip("/")
    if not name:
        raise argparse.ArgumentTypeError(f"not a node name: '{text}'")
    return f"/{name}"


def parse_arguments(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog=NODE_NAME, description=__doc__.split("\n\n")[0],
                                     epilog="Remap topics with ROS arguments: --ros-args -r FROM:=TO")
    parser.add_argument("bag", help="recording: a .mcap file or a rosbag2 bag directory")
    parser.add_argument("--rate", "-r", type=positive, default=1.0, help="playback rate factor (default 1)")
    parser.add_argument("--start-offset", type=non_negative, default=0.0, help="skip the first S seconds of the bag")
    parser.add_argument("--loop", "-l", action="store_true", help="play again from the start when done")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics (default: all)")
    parser.add_argument("--clock", nargs="?", type=non_negative, const=100.0, default=0.0, metavar="HZ",
                        help="publish the playback time on /clock at HZ (default 100 when given)")
    parser.add_argument("--delay", type=non_negative, default=0.0,
                        help="wait S seconds before playing (after --wait-for-subscribers)")
    parser.add_argument("--linger", type=non_negative, default=LINGER, metavar="S",
                        help="after the last message, wait up to S seconds until every reliable subscriber has "
                        "acknowledged all of it (default %(default)g)")
    parser.add_argument("--in-namespace", action="store_true",
                        help="publish the recorded topics in the player's namespace (/base_pose as <ns>/base_pose), "
                        "where the nodes of a launch in that namespace read them")
    parser.add_argument("--wait-for-subscribers", type=non_negative, default=0.0, metavar="S",
                        help="wait up to S seconds until every topic has a subscriber, matched from the "
                        "player's side and from the subscriber's where it reports its inputs")
    parser.add_argument("--wait-for-nodes", nargs="+", metavar="NODE", type=_node_name,
                        help="with --wait-for-subscribers: wait for these nodes (fully qualified names) instead, until "
                        "each has matched the played topics it subscribes to and its other inputs that someone "
                        "publishes; other topics hold nothing")
    parser.add_argument("--start-paused", action="store_true",
                        help="wait for a call of the service ~/resume (std_srvs/Trigger) before playing")
    parser.add_argument("--stop-on-corrupt", action="store_true",
                        help="stop at a corrupt chunk (default: skip it, count it and warn)")
    parser.add_argument("--compress-images", choices=("png", "jpeg"), help="play sensor_msgs/Image topics as "
                        "sensor_msgs/CompressedImage on <topic>/compressed (image_transport's compressed transport)")
    parser.add_argument("--jpeg-quality", type=int, choices=range(1, 101), default=95, metavar="Q",
                        help="with --compress-images jpeg: quality 1-100 (default %(default)s)")
    parser.add_argument("--allow-type-mismatch", action="store_true", help="also play topics whose recorded type "
                        "differs from what the suite's nodes expect on that name (default: skip them)")
    args = parser.parse_args(argv)
    if args.wait_for_nodes and not args.wait_for_subscribers:
        parser.error("--wait-for-nodes needs --wait-for-subscribers S (how long to wait for them)")
    return args


class ReplayNode(Node):
    def __init__(self, reader: BagReader, args: argparse.Namespace) -> None:
        super().__init__(NODE_NAME)
        self.reader, self.args = reader, args
        self.publishers_by_topic = {}
        self.compressing: set[str] = set()  # recorded Image topics played as CompressedImage on <topic>/compressed
        mismatches = {} if args.allow_type_mismatch else reader.type_mismatches(EXPECTED_TYPES)
        for topic in args.topics or sorted(reader.topics):
            recorded = reader.topics[topic]
            if topic in mismatches:
                self.get_logger().error(f"skipping topic '{topic}': recorded type '{mismatches[topic][0]}', the "
                                        f"nodes expect '{mismatches[topic][1]}' (--allow-type-mismatch plays it)")
                continue
            try:
                message_type = message_class(recorded.type_name)
            except (ImportError, AttributeError, ValueError) as error:
                self.get_logger().warning(f"skipping topic '{topic}': type '{recorded.type_name}' is not "
                                          f"installed ({error})")
                continue
            name = topic.lstrip("/") if args.in_namespace else topic
            if args.compress_images and recorded.type_name == "sensor_msgs/msg/Image":
                message_type, name = message_class("sensor_msgs/msg/CompressedImage"), f"{name}/compressed"
                self.compressing.add(topic)
            self.publishers_by_topic[topic] = self.create_publisher(message_type, name,
                                                                    playback_qos(recorded.offered_qos))
        self.clock_publisher = self.create_publisher(Clock, "/clock", QoSProfile(depth=1)) if args.clock else None
        self.published = 0
        self.clock_ns = self.start_time_ns  # bag time [ns] /clock holds: the start, then the last sent (>= last msg)
        self.resumed = not args.start_paused
        if args.start_paused:
            self.create_service(Trigger, "~/resume", self.on_resume)

    def on_resume(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Served only while paused: the playing loop does not spin."""
        self.resumed, response.success, response.message = True, True, "playing"
        return response

    @property
    def start_time_ns(self) -> int:
        return self.reader.start_time_ns + round(self.args.start_offset * 1e9)

    def hold_clock(self, done: Callable[[], bool], timeout: float = math.inf) -> None:
        """Spin until ``done()`` or ``timeout`` [s], the last time on /clock meanwhile (before playing: the start)."""
        deadline = time.monotonic() + timeout
        period = 1.0 / self.args.clock if self.args.clock else 0.01
        while rclpy.ok() and not done() and time.monotonic() < deadline:
            if self.clock_publisher is not None:
                self.publish_clock(self.clock_ns)
            rclpy.spin_once(self, timeout_sec=period)

    def wait_for_subscribers(self, timeout: float) -> None:
        """Up to ``timeout`` [s] until every played topic has a subscriber and each subscriber reporting its inputs has
        matched it from its own side (with --clock, following the start time); with --wait-for-nodes, until each of
        those nodes has matched the played topics it subscribes to and its other inputs that someone publishes. The
        player's publishers must have matched those subscriptions too (:meth:`unmatched`)."""
        reports = InputReports(self)
        topics = [p.topic_name for p in self.publishers_by_topic.values()]
        clock_ns = self.start_time_ns if self.clock_publisher is not None else None
        nodes = self.args.wait_for_nodes

        def waiting() -> list[str]:
            return (reports.waiting_for(nodes, topics, clock_ns) if nodes else reports.waiting(
                topics, time.monotonic(), clock_ns)) + self.unmatched(nodes)

        self.hold_clock(lambda: not waiting(), timeout)
        missing = waiting()
        reports.close()
        if missing:
            self.get_logger().warning(f"playing after {timeout} s without: {'; '.join(missing)}")

    def unmatched(self, nodes: list[str] | None) -> list[str]:
        """The played topics whose publisher has not matched, from its own side, every subscription in the graph (of
        the named ``nodes`` only, if given). Discovery is two-sided: a subscriber that reports its match may not be
        matched by the publisher yet, and what is published before that is lost to it (reliable, volatile), e.g. a
        simulator's first poses (the needle started 15 ms into the bag)."""
        lines = []
        for publisher in self.publishers_by_topic.values():
            subscribers = [fully_qualified_name(info.node_namespace, info.node_name)
                           for info in self.get_subscriptions_info_by_topic(publisher.topic_name)]
            expected = sum(name in nodes for name in subscribers) if nodes else len(subscribers)
            matched = publisher.get_subscription_count()
            if matched < expected:
                lines.append(f"{publisher.topic_name}: the player has matched {matched} of its {expected} "
                             "subscription(s)")
        return lines

    def publish_clock(self, bag_time_ns: int) -> None:
        self.clock_ns = bag_time_ns
        self.clock_publisher.publish(Clock(clock=Time(nanoseconds=bag_time_ns).to_msg()))

    def play_once(self) -> bool:
        """Publish every selected message at its due time; False if interrupted."""
        start = self.start_time_ns
        schedule = PlaybackSchedule(start, time.monotonic_ns(), self.args.rate)
        clock_period = round(1e9 / self.args.clock) if self.args.clock else 0
        next_clock = schedule.wall_start_ns
        for message in self.reader.messages(self.publishers_by_topic, start_time_ns=start):
            data = self.compressed(bytes(message.data)) if message.topic in self.compressing else bytes(message.data)
            due = schedule.wall_time_ns(message.log_time_ns)
            while True:
                now = time.monotonic_ns()
                if clock_period and now >= next_clock:
                    self.publish_clock(schedule.bag_time_ns(now))
                    next_clock = max(next_clock + clock_period, now)
                if now >= due:
                    break
                if not rclpy.ok():
                    return False
                wake = min(due, next_clock) if clock_period else due
                time.sleep((wake - now) / 1e9)
            if not rclpy.ok():
                return False
            self.publishers_by_topic[message.topic].publish(data)
            self.published += 1
            self.clock_ns = max(self.clock_ns, message.log_time_ns)
        return True

    def compressed(self, data: bytes) -> bytes:
        """A serialized Image as a serialized CompressedImage (--compress-images); one that cannot be read or encoded
        becomes an empty CompressedImage of format 'unreadable' (its receiver counts a decode error), with a warning."""
        stamp, frame_id = (0, 0), ""
        try:
            image = deserialize_image(data, compressed=False)
            stamp, frame_id = (image.sec, image.nanosec), image.frame_id
            image_format, payload = compress_image(image_to_array(**image.fields), image.fields["encoding"],
                                                   self.args.compress_images, self.args.jpeg_quality)
        except ImageFormatError as error:
            self.get_logger().warning(f"image not compressed: {error}", throttle_duration_sec=2.0)
            image_format, payload = "unreadable", b""
        return cdr.compressed_image_message(*stamp, frame_id, image_format, payload)

    def play(self) -> bool:
        """Wait as asked, then play (again with --loop); False if interrupted."""
        self.hold_clock(lambda: self.resumed)
        if self.args.wait_for_subscribers:
            self.wait_for_subscribers(self.args.wait_for_subscribers)
        if self.args.delay:  # after discovery, lets reliable connections settle before the first message
            time.sleep(self.args.delay)
        while (completed := self.play_once()) and self.args.loop:
            pass
        if completed:
            if self.clock_publisher is not None:  # the clocks of the nodes reach the last message's time
                self.publish_clock(self.clock_ns)
            self.hold_clock(lambda: not self.unacknowledged(), self.args.linger)
            if not rclpy.ok():  # SIGINT/SIGTERM ended the wait
                return False
            if unacknowledged := self.unacknowledged():
                self.get_logger().warning(f"not acknowledged by every subscriber {self.args.linger:g} s after the "
                                          f"last message: {', '.join(unacknowledged)}")
        return completed

    def unacknowledged(self) -> list[str]:
        """Played topics with a reliable subscriber that has not acknowledged all their messages yet."""
        return [p.topic_name for p in self.publishers_by_topic.values() if not p.wait_for_all_acked(Duration())]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    logger = rclpy.logging.get_logger(NODE_NAME)

    def arguments(others: list[str]) -> argparse.Namespace:
        args = parse_arguments(others[1:])
        # its params files (e.g. use_sim_time) read as rcl will, with messages that name the problem
        check_ros_arguments(argv, NODE_NAME, None, logger.warning)
        return args
    args = checked_command_line(argv, logger, NODE_NAME, arguments)
    if args is None:
        return EXIT_BAD_ARGUMENTS
    try:
        reader = BagReader(args.bag, stop_on_corrupt=args.stop_on_corrupt)
        reader.check_start_offset(args.start_offset)
    except (BagReadError, ValueError) as error:
        logger.fatal(str(error))
        return EXIT_BAD_ARGUMENTS
    unknown = sorted(set(args.topics or ()) - set(reader.topics))
    if unknown:
        logger.fatal(f"--topics: not in '{args.bag}': {', '.join(unknown)} "
                     f"(recorded: {', '.join(sorted(reader.topics))})")
        return EXIT_BAD_ARGUMENTS
    if not init_rclpy(argv, logger, NODE_NAME):
        return EXIT_BAD_ARGUMENTS
    node = ReplayNode(reader, args)
    status, played, interrupted = 0, False, False
    try:
        if not node.publishers_by_topic:
            node.get_logger().fatal(f"nothing to play from '{args.bag}'")
            status = 2
        else:
            played, interrupted = True, not node.play()
    except BagReadError as error:
        node.get_logger().fatal(str(error))
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):  # SIGINT/SIGTERM while spinning (paused or waiting)
        played, interrupted = True, True
    except RCLError:  # a publish raced the shutdown by SIGINT/SIGTERM
        if rclpy.ok():
            raise
        played, interrupted = True, True
    finally:
        def closing(log) -> None:
            if played:
                log.info(f"played {node.published} messages from {args.bag}")
            if reader.corrupt_chunks:
                log.warning(f"skipped {reader.corrupt_chunks} corrupt chunk(s) of '{args.bag}'")

        # on /rosout as well, unless a SIGINT/SIGTERM is taking the context and with it the node's /rosout publisher
        # down (in rclpy's signal thread, at any moment): then on the console, once the node is gone
        if not interrupted:
            closing(node.get_logger())
        node.destroy_node()
        rclpy.try_shutdown()
        if interrupted:
            closing(logger)
    return status


if __name__ == "__main__":
    sys.exit(main())
