"""rosbag2-compatible MCAP recording (ROS-free): writer, schemas, recovery, the playback schedule (reading:
:mod:`needle_common.bag_reader`, QoS metadata: :mod:`needle_common.qos`)."""
from needle_sim_ros.recording.mcap_writer import McapBagWriter, RecordingError, WriterOptions
from needle_sim_ros.recording.message_definitions import (MessageDefinitionError, message_definition,
                                                          type_description_hash)
from needle_sim_ros.recording.playback import PlaybackSchedule
from needle_sim_ros.recording.recovery import RecoveryError, RecoveryReport, recover

__all__ = ["McapBagWriter", "MessageDefinitionError", "PlaybackSchedule", "RecordingError", "RecoveryError",
           "RecoveryReport", "WriterOptions", "message_definition", "recover", "type_description_hash"]
