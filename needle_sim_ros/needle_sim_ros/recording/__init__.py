"""rosbag2-compatible MCAP recording (ROS-free): writer, schemas, QoS metadata, recovery, reading for playback."""
from needle_sim_ros.recording.bag_reader import BagReadError, BagReader, RecordedMessage, RecordedTopic
from needle_sim_ros.recording.mcap_writer import McapBagWriter, RecordingError, WriterOptions
from needle_sim_ros.recording.message_definitions import (MessageDefinitionError, message_definition,
                                                          type_description_hash)
from needle_sim_ros.recording.playback import PlaybackSchedule
from needle_sim_ros.recording.qos import OfferedQos, offered_qos_profiles_yaml, parse_offered_qos_profiles
from needle_sim_ros.recording.recovery import RecoveryError, RecoveryReport, recover

__all__ = ["BagReadError", "BagReader", "McapBagWriter", "MessageDefinitionError", "OfferedQos", "PlaybackSchedule",
           "RecordedMessage", "RecordedTopic", "RecordingError", "RecoveryError", "RecoveryReport", "WriterOptions",
           "message_definition", "offered_qos_profiles_yaml", "parse_offered_qos_profiles", "recover",
           "type_description_hash"]
