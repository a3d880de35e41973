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

from ..core.settings import Parameter, Settings, parameters

__all__ = ["descriptor", "declare_settings"]

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


def declare_settings(node: Node, *classes: type[Settings]) -> dict[str, Any]:
    """Declare every parameter of ``classes`` on ``node``; their values (ROS names and units) by name."""
    values: dict[str, Any] = {}
    for cls in classes:
        for param in parameters(cls):
            node.declare_parameter(param.name, param.default, descriptor(param))
            values[param.name] = node.get_parameter(param.name).value
    return values
