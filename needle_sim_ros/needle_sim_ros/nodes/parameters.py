"""Declaring node parameters from a table: descriptor (description, range), value check, clear error.

Every parameter of a node is one :class:`ParamSpec`. :func:`declare_all` declares them with a
``ParameterDescriptor`` (so ``ros2 param describe`` shows the description and range), reads the values given by
``--params-file``/overrides, and checks them; a bad value raises :class:`ParameterError` whose message names the
parameter, which the node's ``main`` turns into a fatal log line and a non-zero exit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.node import Node


class ParameterError(ValueError):
    """A parameter value is invalid; the message names the parameter."""


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: name, default (its type is the parameter's type), meaning and valid values.

    ``low``/``high`` bound numbers (and every element of number arrays); ``choices`` lists valid strings;
    ``length`` fixes an array's length; ``check`` is an extra predicate with the message shown when it fails.
    ``dynamic`` parameters may be changed while the node runs.
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: Sequence[str] | None = None
    length: int | None = None
    check: tuple[Callable[[Any], bool], str] | None = None
    dynamic: bool = False
    allow_infinite: bool = False

    def descriptor(self) -> ParameterDescriptor:
        text = self.description + (f" Choices: {', '.join(self.choices)}." if self.choices else "")
        descriptor = ParameterDescriptor(name=self.name, description=text, read_only=not self.dynamic)
        scalar = self.default[0] if isinstance(self.default, (list, tuple)) and self.default else self.default
        if self.low is not None and self.high is not None and not isinstance(scalar, bool):
            if isinstance(scalar, int) and not isinstance(self.default, (list, tuple)):
                descriptor.integer_range = [IntegerRange(from_value=int(self.low), to_value=int(self.high), step=0)]
            elif isinstance(scalar, float) and not isinstance(self.default, (list, tuple)):
                descriptor.floating_point_range = [FloatingPointRange(from_value=float(self.low), to_value=float(self.high), step=0.0)]
        return descriptor

    def validate(self, value: Any) -> Any:
        """Return the value if valid, else raise ParameterError naming the parameter."""
        def fail(reason: str) -> None:
            raise ParameterError(f"parameter '{self.name}' = {value!r}: {reason} ({self.description})")

        values = list(value) if hasattr(value, "__len__") and not isinstance(value, str) else [value]
        if self.length is not None and len(values) != self.length:
            fail(f"expected {self.length} values, got {len(values)}")
        for v in values:
            if isinstance(v, float) and (math.isnan(v) or (math.isinf(v) and not self.allow_infinite)):
                fail("must be finite")
            if self.low is not None and isinstance(v, (int, float)) and not isinstance(v, bool) and v < self.low:
                fail(f"must be >= {self.low}")
            if self.high is not None and isinstance(v, (int, float)) and not isinstance(v, bool) and v > self.high:
                fail(f"must be <= {self.high}")
        if self.choices is not None and value not in self.choices:
            fail(f"must be one of {', '.join(self.choices)}")
        if self.check is not None and not self.check[0](value):
            fail(self.check[1])
        return value


def declare_all(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare and validate every parameter; returns {name: value}. Raises ParameterError on a bad value."""
    values = {}
    for spec in specs:
        try:
            parameter = node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except (InvalidParameterValueException, ParameterException) as error:
            raise ParameterError(f"parameter '{spec.name}': {error} ({spec.description})") from error
        values[spec.name] = spec.validate(parameter.value)
    return values


def guard_dynamic_updates(node: Node, specs: Sequence[ParamSpec], apply: Callable[[dict[str, Any]], None]) -> None:
    """Accept run-time changes of ``dynamic`` parameters only, validated like at start, then call ``apply``."""
    by_name = {spec.name: spec for spec in specs}

    def on_set(parameters) -> SetParametersResult:
        changed = {}
        for parameter in parameters:
            spec = by_name.get(parameter.name)
            if spec is None or not spec.dynamic:
                return SetParametersResult(successful=False, reason=f"parameter '{parameter.name}' cannot change at run time")
            try:
                changed[parameter.name] = spec.validate(parameter.value)
            except ParameterError as error:
                return SetParametersResult(successful=False, reason=str(error))
        apply(changed)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
