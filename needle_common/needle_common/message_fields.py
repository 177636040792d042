"""A message's fields by name, whatever form it arrives in: an rclpy message, one decoded from a bag (attributes),
or a mapping of its fields (a YAML or JSON document, a test's dict)."""
from __future__ import annotations

from typing import Any, Callable, Mapping


def field_getter(message: Mapping[str, Any] | Any) -> Callable[[str], Any]:
    """``get(name)``: the field's value, None where the message has no such field."""
    if isinstance(message, Mapping):
        return message.get
    return lambda name: getattr(message, name, None)
