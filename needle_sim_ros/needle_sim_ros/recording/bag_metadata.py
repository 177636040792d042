"""rosbag2 bag metadata (version 9, Jazzy): the ``rosbag2`` MCAP metadata record and a bag directory's metadata.yaml.

The record's key ``serialized_metadata`` holds the BagMetadata as YAML, metadata.yaml the same mapping under
``rosbag2_bagfile_information``. Times are ``{nanoseconds_since_epoch}``/``{nanoseconds}``; a topic's
``offered_qos_profiles`` is the list of its publishers' profiles.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Sequence

import yaml

METADATA_VERSION = 9
METADATA_RECORD_NAME = "rosbag2"
METADATA_RECORD_KEY = "serialized_metadata"
# libyaml's loader and dumper where PyYAML has them (same text, a quarter of the pure-Python time)
_LOADER, _DUMPER = getattr(yaml, "CSafeLoader", yaml.SafeLoader), getattr(yaml, "CSafeDumper", yaml.SafeDumper)


@dataclass(frozen=True)
class TopicSummary:
    """A recorded topic and its message count. ``offered_qos_profiles`` is the channel's YAML text."""

    name: str
    type_name: str
    serialization_format: str
    offered_qos_profiles: str
    type_description_hash: str
    message_count: int


@dataclass(frozen=True)
class FileSummary:
    """One storage file of the bag (path relative to the bag directory) and its message time range [ns]."""

    path: str
    starting_time_ns: int
    duration_ns: int
    message_count: int


def bag_metadata(topics: Sequence[TopicSummary], files: Sequence[FileSummary],
                 custom_data: dict[str, str] | None = None) -> dict[str, Any]:
    """BagMetadata mapping (keys in rosbag2's order) of a bag made of ``files``."""
    counted = [f for f in files if f.message_count]
    start = min((f.starting_time_ns for f in counted), default=0)
    end = max((f.starting_time_ns + f.duration_ns for f in counted), default=0)
    return {
        "version": METADATA_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": end - start},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": sum(f.message_count for f in files),
        "topics_with_message_count": [{
            "topic_metadata": {
                "name": t.name,
                "type": t.type_name,
                "serialization_format": t.serialization_format,
                "offered_qos_profiles": yaml.load(t.offered_qos_profiles, _LOADER) or [],
                "type_description_hash": t.type_description_hash,
            },
            "message_count": t.message_count,
        } for t in topics],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [f.path for f in files],
        "files": [{
            "path": f.path,
            "starting_time": {"nanoseconds_since_epoch": f.starting_time_ns},
            "duration": {"nanoseconds": f.duration_ns},
            "message_count": f.message_count,
        } for f in files],
        "custom_data": dict(custom_data) if custom_data else None,
        "ros_distro": os.environ.get("ROS_DISTRO", "jazzy"),
    }


def metadata_record_text(metadata: dict[str, Any]) -> str:
    """Value of ``serialized_metadata`` in the ``rosbag2`` MCAP metadata record."""
    return yaml.dump(metadata, Dumper=_DUMPER, sort_keys=False)


def metadata_yaml_text(metadata: dict[str, Any]) -> str:
    """Content of a bag directory's metadata.yaml."""
    return yaml.dump({"rosbag2_bagfile_information": metadata}, Dumper=_DUMPER, sort_keys=False)
