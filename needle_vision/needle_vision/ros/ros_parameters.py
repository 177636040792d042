"""Declaring node parameters from their specs: descriptor (description, range), value check, clear error.

Every parameter of a node is one :class:`needle_vision.parameters.ParamSpec` (the ROS-free declaration layer shared
by all executables). :func:`declare_all` declares them with a ``ParameterDescriptor`` (so ``ros2 param describe``
shows the description and range), reads the values given by ``--params-file``/overrides, and checks them; a bad
value raises :class:`ParameterError` whose message names the parameter, which the node's ``main`` turns into a
fatal log line and exit status 2.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.node import Node

from needle_vision.parameters import ParameterError, ParamSpec


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS descriptor of a spec: description (with choices), read-only unless dynamic, scalar range."""
    text = spec.description + (f" Choices: {', '.join(map(str, spec.choices))}." if spec.choices else "")
    result = ParameterDescriptor(name=spec.name, description=text, read_only=not spec.dynamic)
    if spec.low is not None and spec.high is not None and not spec.is_list:
        if spec.value_type is int:
            result.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=0)]
        elif spec.value_type is float:
            result.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high),
                                                              step=0.0)]
    return result


def declare_all(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare and validate every parameter; returns {name: value}. Raises ParameterError on a bad value."""
    values = {}
    for spec in specs:
        try:
            parameter = node.declare_parameter(spec.name, spec.default, descriptor(spec))
        except (InvalidParameterValueException, ParameterException, TypeError) as error:
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
                return SetParametersResult(successful=False,
                                           reason=f"parameter '{parameter.name}' cannot change at run time")
            try:
                changed[parameter.name] = spec.validate(parameter.value)
            except ParameterError as error:
                return SetParametersResult(successful=False, reason=str(error))
        try:
            apply(changed)
        except ValueError as error:  # e.g. a load the model cannot carry
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
