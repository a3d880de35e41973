"""ROS parameters from settings classes: declarations with descriptors and ranges, read back as values.

The table comes from :func:`robot_localization_suite.core.settings.parameters`; this module only
turns each :class:`~robot_localization_suite.core.settings.Parameter` into a
``ParameterDescriptor`` (description with unit, ``FloatingPointRange`` / ``IntegerRange``,
``read_only``) so that ``ros2 param describe`` shows what ``--help`` shows.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from ..core.settings import Parameter, Settings, parameters, unknown_params

__all__ = ["descriptor", "declare_settings", "parameter_values"]

# ROS ranges need both ends: an open side is this far out.
_UNBOUNDED = 1e12


def descriptor(param: Parameter) -> ParameterDescriptor:
    """The descriptor of one parameter: description (with unit and choices), range, read-only flag."""
    text = param.setting.doc
    if param.unit:
        text += f" [{param.unit}]"
    if param.setting.choices:
        text += f" (one of: {', '.join(param.setting.choices)})"
    result = ParameterDescriptor(description=text, read_only=param.setting.read_only)
    if param.low is None and param.high is None or param.kind is bool or param.kind is str:
        return result
    low = -_UNBOUNDED if param.low is None else param.low
    high = _UNBOUNDED if param.high is None else param.high
    if param.kind is int:
        result.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
    else:
        result.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
    return result


# Declared by rclpy itself, never "unknown".
_ROS_OWN = ("use_sim_time", "start_type_description_service")


def declare_settings(node: Node, *classes: type[Settings]) -> list[str]:
    """Declare every parameter of ``classes`` on ``node``, each with its descriptor; the overrides it has not.

    A node made with ``automatically_declare_parameters_from_overrides`` holds every override of
    its params files and ``-p`` as an untyped parameter. Each of ours is checked (type, range,
    choices: one message naming it) and declared again with its descriptor and value (an integer
    for a number is taken as the number); every other override is undeclared and returned, sorted,
    so that the node can say it does not use them (``core.settings.unknown_params``).

    Raises:
        SettingsError: an override of the wrong type or out of range, naming the parameter and the value.
    """
    declared: dict[str, Any] = dict(node.get_parameters_by_prefix(""))  # name -> rclpy Parameter
    overrides = {name: param.value for name, param in declared.items()
                 if name not in _ROS_OWN and not name.startswith("qos_overrides.")}
    for cls in classes:
        for param in parameters(cls):
            if param.name in overrides:
                param.from_ros(overrides[param.name])  # raises SettingsError naming the bad value
                value = overrides[param.name]
                node.undeclare_parameter(param.name)
                if param.kind is float:
                    value = float(value)
                node.declare_parameter(param.name, value, descriptor(param), ignore_override=True)
            else:
                node.declare_parameter(param.name, param.default, descriptor(param))
    unknown = set(overrides)
    for cls in classes:
        unknown &= set(unknown_params(cls, overrides))
    for name in unknown:
        node.undeclare_parameter(name)
    return sorted(unknown)


def parameter_values(node: Node, *classes: type[Settings]) -> dict[str, Any]:
    """The current values of the parameters of ``classes`` (ROS names and units) by name."""
    return {param.name: node.get_parameter(param.name).value for cls in classes for param in parameters(cls)}
