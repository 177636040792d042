"""Playback timing: bag (log) time <-> wall time at a rate factor, as ``ros2 bag play --rate`` does; the types the
suite's nodes expect on the topics of a recording (``BagReader.type_mismatches(EXPECTED_TYPES)``)."""
from __future__ import annotations

from dataclasses import dataclass

# Types the nodes and tools of the suite expect on the topics of a recording (absolute names as recorded).
EXPECTED_TYPES = {
    "/base_pose": "geometry_msgs/msg/PoseStamped", "/base_twist": "geometry_msgs/msg/TwistStamped",
    "/tip_load": "geometry_msgs/msg/WrenchStamped", "/wrench": "geometry_msgs/msg/WrenchStamped",
    "/left/image_raw": "sensor_msgs/msg/Image", "/right/image_raw": "sensor_msgs/msg/Image",
    "/left/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/right/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/left/camera_info": "sensor_msgs/msg/CameraInfo", "/right/camera_info": "sensor_msgs/msg/CameraInfo",
    "/needle/shape": "needle_interfaces/msg/NeedleShape", "/needle/measured_shape": "needle_interfaces/msg/NeedleShape",
    "/shape_error": "needle_interfaces/msg/ShapeError", "/clock": "rosgraph_msgs/msg/Clock",
    "/ground_truth/shape": "needle_interfaces/msg/NeedleShape",
    "/ground_truth/wrench": "geometry_msgs/msg/WrenchStamped",
}


@dataclass(frozen=True)
class PlaybackSchedule:
    """``wall = wall_start + (bag - bag_start) / rate`` (times in ns; rate > 0, 2 = twice as fast)."""

    bag_start_ns: int
    wall_start_ns: int
    rate: float = 1.0

    def __post_init__(self) -> None:
        if not self.rate > 0.0:
            raise ValueError(f"rate must be > 0, got {self.rate}")

    def wall_time_ns(self, bag_time_ns: int) -> int:
        """When a message logged at ``bag_time_ns`` is due."""
        return self.wall_start_ns + round((bag_time_ns - self.bag_start_ns) / self.rate)

    def bag_time_ns(self, wall_time_ns: int) -> int:
        """Playback (simulated) time at ``wall_time_ns``, published on /clock."""
        return self.bag_start_ns + round((wall_time_ns - self.wall_start_ns) * self.rate)
