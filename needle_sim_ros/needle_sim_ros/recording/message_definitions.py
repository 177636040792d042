"""Message definitions (MCAP schemas, encoding ``ros2msg``) and type hashes of ROS 2 types, as rosbag2 writes them.

The schema of ``pkg/msg/Type`` is ``share/pkg/msg/Type.msg`` followed, for each type it depends on (depth first,
each once, one file's dependencies sorted), by ``"\\n" + "=" * 80 + "\\nMSG: dep_pkg/DepType\\n"`` and its text; a
field type without package is the file's package. Files come from the ament index (AMENT_PREFIX_PATH), the type
hash (``RIHS01_...``, REP 2011) from the ``Type.json`` next to the .msg.
"""
from __future__ import annotations

import functools
import json
import re
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

SCHEMA_ENCODING = "ros2msg"
DELIMITER = "=" * 80 + "\n"
_PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
                         "int32", "uint32", "int64", "uint64", "string", "wstring"})
_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_TYPE_NAME = re.compile(r"^([a-zA-Z][a-zA-Z0-9_]*)/(?:([a-zA-Z][a-zA-Z0-9_]*)/)?([a-zA-Z][a-zA-Z0-9_]*)$")


class MessageDefinitionError(LookupError):
    """A message type's definition is not installed (or its name is malformed)."""


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """``'pkg/msg/Type'`` or ``'pkg/Type'`` -> ``('pkg', 'msg', 'Type')``."""
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise MessageDefinitionError(f"message type name '{type_name}' is not of the form pkg/msg/Type")
    package, namespace, name = match.groups()
    return package, namespace or "msg", name


def _interface_file(type_name: str, suffix: str) -> Path:
    package, namespace, name = split_type_name(type_name)
    try:
        share = Path(get_package_share_directory(package))
    except PackageNotFoundError:
        raise MessageDefinitionError(f"package '{package}' of type '{type_name}' is not in any AMENT_PREFIX_PATH "
                                     "prefix (source the workspace's setup file)") from None
    path = share / namespace / f"{name}{suffix}"
    if not path.is_file():
        raise MessageDefinitionError(f"no {suffix} file for '{type_name}' at {path}")
    return path


def _dependencies(text: str, package: str) -> list[str]:
    return sorted({field_type if "/" in field_type else f"{package}/{field_type}"
                   for field_type in _FIELD_TYPE.findall(text) if field_type not in _PRIMITIVES})


@functools.lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    return _interface_file(type_name, ".msg").read_text()


@functools.lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """Full ros2msg schema text of ``type_name`` (with its dependencies) as rosbag2 records it."""
    seen: set[str] = set()

    def expand(name: str) -> str:
        text = _msg_text(name)
        parts = [text]
        for dependency in _dependencies(text, split_type_name(name)[0]):
            if dependency not in seen:
                seen.add(dependency)
                parts.append("\n" + DELIMITER + f"MSG: {dependency}\n" + expand(dependency))
        return "".join(parts)

    return expand(type_name)


@functools.lru_cache(maxsize=None)
def type_description_hash(type_name: str) -> str:
    """REP 2011 hash ``RIHS01_<hex>`` of the installed type, or '' when the type has no .json description."""
    package, namespace, name = split_type_name(type_name)
    try:
        description = json.loads(_interface_file(type_name, ".json").read_text())
    except MessageDefinitionError:
        return ""
    wanted = f"{package}/{namespace}/{name}"
    return next((h["hash_string"] for h in description.get("type_hashes", []) if h.get("type_name") == wanted), "")
