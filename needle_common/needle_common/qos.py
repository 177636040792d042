"""Offered QoS profiles of a recorded topic in rosbag2's YAML form (bag metadata version 9, ROS 2 Jazzy).

rosbag2 stores, per topic, the list of QoS profiles offered by the recorded publishers: in MCAP as the channel
metadata value ``offered_qos_profiles`` (a YAML document holding a list) and in metadata.yaml as that list. Version 9
spells policies as the rmw strings (``keep_last``, ``reliable``, ``transient_local``, ``automatic`` ...) and durations
as ``{sec, nsec}``; versions <= 8 used the rmw enum integers, which :func:`parse_offered_qos_profiles` also reads.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Sequence

import yaml

DURATION_INFINITE_NS = 2**63 - 1  # RMW_DURATION_INFINITE = {sec: 9223372036, nsec: 854775807}
DURATION_UNSPECIFIED_NS = 0

HISTORY = ("system_default", "keep_last", "keep_all", "unknown")
RELIABILITY = ("system_default", "reliable", "best_effort", "unknown", "best_available")
DURABILITY = ("system_default", "transient_local", "volatile", "unknown", "best_available")
LIVELINESS = ("system_default", "automatic", "manual_by_node", "manual_by_topic", "unknown", "best_available")
POLICIES = {"history": HISTORY, "reliability": RELIABILITY, "durability": DURABILITY, "liveliness": LIVELINESS}

# Infinity as reported by Foxy-era RMW implementations, read as infinite (as rosbag2 does).
_LEGACY_INFINITE = {(0x7FFFFFFF, 0xFFFFFFFF), (0x7FFFFFFF, 0x7FFFFFFF), divmod(0x7FFFFFFFFFFFFFFF, 10**9)}

# libyaml's safe loader and dumper where PyYAML has them (~10x faster, same documents): a recording's channels
_LOADER, _DUMPER = getattr(yaml, "CSafeLoader", yaml.SafeLoader), getattr(yaml, "CSafeDumper", yaml.SafeDumper)


@dataclass(frozen=True)
class OfferedQos:
    """One QoS profile (rmw_qos_profile_t) with policies as rmw strings and durations in nanoseconds."""

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline_ns: int = DURATION_UNSPECIFIED_NS
    lifespan_ns: int = DURATION_UNSPECIFIED_NS
    liveliness: str = "system_default"
    liveliness_lease_duration_ns: int = DURATION_UNSPECIFIED_NS
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        for name, allowed in POLICIES.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"QoS {name} '{getattr(self, name)}' is not one of {', '.join(allowed)}")
        if self.depth < 0:
            raise ValueError(f"QoS depth must be >= 0, got {self.depth}")

    def as_dict(self) -> dict[str, Any]:
        """rosbag2 version-9 mapping of this profile (rosbag2's key order: the fields'; durations as sec, nsec)."""
        mapping: dict[str, Any] = {}
        for spec in fields(self):
            value = type(spec.default)(getattr(self, spec.name))
            mapping[spec.name.removesuffix("_ns")] = (dict(zip(("sec", "nsec"), divmod(value, 10**9)))
                                                      if spec.name.endswith("_ns") else value)
        return mapping

    @classmethod
    def from_dict(cls, item: dict[str, Any]) -> "OfferedQos":
        """Read a profile written by any rosbag2 version (policy strings or rmw enum integers)."""
        values: dict[str, Any] = {}
        for spec in fields(cls):
            value = item[spec.name.removesuffix("_ns")]
            if spec.name in POLICIES:
                names = POLICIES[spec.name]
                if isinstance(value, int):
                    value = names[value] if 0 <= value < len(names) else None
                values[spec.name] = value if value in names else "unknown"
            elif spec.name.endswith("_ns"):
                sec, nsec = int(value["sec"]), int(value["nsec"])
                values[spec.name] = DURATION_INFINITE_NS if (sec, nsec) in _LEGACY_INFINITE else min(
                    sec * 10**9 + nsec, DURATION_INFINITE_NS)
            else:
                values[spec.name] = type(spec.default)(value)
        return cls(**values)


def offered_qos_profiles_yaml(profiles: Sequence[OfferedQos]) -> str:
    """Channel metadata value ``offered_qos_profiles``: a YAML list of version-9 profiles ('' for none)."""
    if not profiles:
        return ""
    return yaml.dump([p.as_dict() for p in profiles], Dumper=_DUMPER, sort_keys=False,
                     default_flow_style=False).rstrip("\n")


def parse_offered_qos_profiles(text: str) -> list[OfferedQos]:
    """Inverse of :func:`offered_qos_profiles_yaml`, also for rosbag2 versions <= 8; raises ValueError."""
    if not text or not text.strip():
        return []
    try:
        items = yaml.load(text, Loader=_LOADER)  # noqa: S506 - a safe loader
        return [OfferedQos.from_dict(item) for item in items]
    except (yaml.YAMLError, TypeError, KeyError, AttributeError) as error:
        raise ValueError(f"offered_qos_profiles is not a list of QoS profiles: {error}") from None
