"""Declaring node parameters from their specs: descriptor (description, range), value check, clear error.

Every parameter of a node is one :class:`needle_common.parameters.ParamSpec` (the ROS-free declaration layer shared
by all executables). :func:`declare_all` declares them with a ``ParameterDescriptor`` (so ``ros2 param describe``
shows the description and range), reads the values given by ``--params-file``/overrides, and checks them; a bad
value raises :class:`ParameterError` whose message names the parameter, which the node's ``main`` turns into a
fatal log line and exit status 2.
"""
from __future__ import annotations

from typing import Any, Callable, Collection, Sequence

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from needle_common.parameters import ParameterError, ParamSpec


def qos_profile(name: str, depth: int = 10) -> QoSProfile:
    """A QOS_CHOICES parameter's profile: ``sensor_data`` (best effort, volatile) or ``reliable``; keeps ``depth``."""
    if name == "sensor_data":
        return QoSProfile(depth=depth, reliability=qos_profile_sensor_data.reliability,
                          durability=qos_profile_sensor_data.durability, history=qos_profile_sensor_data.history)
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)


def descriptor(spec: ParamSpec, read_only: bool | None = None) -> ParameterDescriptor:
    """The ROS descriptor of a spec: description (with choices), read-only (default: unless dynamic), scalar range."""
    text = spec.description + (f" Choices: {', '.join(map(str, spec.choices))}." if spec.choices else "")
    result = ParameterDescriptor(name=spec.name, description=text,
                                 read_only=not spec.dynamic if read_only is None else read_only)
    if spec.low is not None and spec.high is not None and not spec.is_list:
        if spec.value_type is int:
            result.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=0)]
        elif spec.value_type is float:
            result.floating_point_range = [FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high),
                                                              step=0.0)]
    return result


def declare_all(node: Node, specs: Sequence[ParamSpec], lifecycle_fixed: Collection[str] | None = None
                ) -> dict[str, Any]:
    """Declare and validate every parameter; returns {name: value}. Raises ParameterError on a bad value.

    ``lifecycle_fixed`` (a managed node): the structural parameters its construction used; the others are not
    read-only, :func:`guard_dynamic_updates` takes them while the node is unconfigured (configure reads them)."""
    values = {}
    for spec in specs:
        read_only = None if lifecycle_fixed is None else not spec.dynamic and spec.name in lifecycle_fixed
        try:
            parameter = node.declare_parameter(spec.name, spec.default, descriptor(spec, read_only))
        except (InvalidParameterValueException, ParameterException, TypeError) as error:
            raise ParameterError(f"parameter '{spec.name}': {error} ({spec.description})") from error
        values[spec.name] = spec.validate(parameter.value)
    return values


def guard_dynamic_updates(node: Node, specs: Sequence[ParamSpec], apply: Callable[[dict[str, Any]], None],
                          unconfigured: Callable[[], bool] | None = None, fixed: Collection[str] = ()) -> None:
    """Accept run-time changes of ``dynamic`` parameters, validated like at start, then call ``apply``. A managed
    node (``unconfigured`` given) also takes its structural parameters not in ``fixed`` while ``unconfigured()``:
    they take effect at configure."""
    by_name = {spec.name: spec for spec in specs}

    def refusal(name: str) -> str | None:
        """Why the parameter cannot change now (None: it can)."""
        spec = by_name.get(name)
        if spec is not None and spec.dynamic:
            return None
        if spec is None or unconfigured is None or name in fixed:
            return f"parameter '{name}' cannot change at run time"
        if not unconfigured():
            return (f"parameter '{name}' is structural: it can change only while the node is unconfigured "
                    "(lifecycle: deactivate, cleanup, set it, configure)")
        return None

    def on_set(parameters) -> SetParametersResult:
        changed = {}
        for parameter in parameters:
            spec = by_name.get(parameter.name)
            if (reason := refusal(parameter.name)) is not None:
                return SetParametersResult(successful=False, reason=reason)
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
