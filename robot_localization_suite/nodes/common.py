"""What every node shares: declared parameters with descriptions, ``--help``, and ``main()``.

Each node lists its parameters once as :class:`ParamSpec` values; the same
list declares them on the node (with description and range, so
``ros2 param describe`` shows them), prints them for ``--help``, and documents
the defaults that ``config/<node>.yaml`` repeats.
"""

from __future__ import annotations

import argparse
import sys
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

__all__ = ["ParamSpec", "declare_parameters", "run_node", "guarded", "LASER_MOUNT_PARAMS"]


@dataclass(frozen=True)
class ParamSpec:
    """A ROS parameter: name, default (its type is the parameter's type), description, range."""

    name: str
    default: Any
    description: str
    minimum: float | None = None
    maximum: float | None = None

    def descriptor(self) -> ParameterDescriptor:
        descriptor = ParameterDescriptor(description=self.description)
        if self.minimum is not None or self.maximum is not None:
            lo = self.minimum if self.minimum is not None else -1e12
            hi = self.maximum if self.maximum is not None else 1e12
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                descriptor.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
            elif isinstance(self.default, float):
                descriptor.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
        return descriptor

    def help_line(self) -> str:
        bounds = ""
        if self.minimum is not None or self.maximum is not None:
            bounds = f" [{'' if self.minimum is None else self.minimum}..{'' if self.maximum is None else self.maximum}]"
        return f"  {self.name} (default {self.default!r}){bounds}: {self.description}"


LASER_MOUNT_PARAMS = (
    ParamSpec("laser_x", 0.0, "laser position in the base frame, x [m] (tf2 is not available)"),
    ParamSpec("laser_y", 0.0, "laser position in the base frame, y [m]"),
    ParamSpec("laser_yaw", 0.0, "laser heading in the base frame [rad]", -3.1416, 3.1416),
)


def declare_parameters(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare every parameter on ``node`` and return their values by name."""
    values = {}
    for spec in specs:
        node.declare_parameter(spec.name, spec.default, spec.descriptor())
        values[spec.name] = node.get_parameter(spec.name).value
    return values


def guarded(node: Node, callback: Callable[[Any], Any], what: str) -> Callable[[Any], Any]:
    """Wrap a callback so that an unexpected error is logged (throttled) instead of killing the node."""

    def wrapper(*args: Any) -> Any:
        try:
            return callback(*args)
        except Exception as exc:  # noqa: BLE001 - a node must survive any bad input
            node.get_logger().error(
                f"{what} failed: {type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}",
                throttle_duration_sec=5.0,
            )
            return None

    return wrapper


def _help(executable: str, description: str, specs: Sequence[ParamSpec], topics: str) -> argparse.ArgumentParser:
    epilog = "topics:\n" + topics + "\n\nparameters (set with --ros-args -p NAME:=VALUE or --params-file FILE):\n"
    epilog += "\n".join(spec.help_line() for spec in specs)
    parser = argparse.ArgumentParser(
        prog=f"ros2 run robot_localization_suite {executable}",
        description=description,
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    return parser


def run_node(
    executable: str,
    description: str,
    specs: Sequence[ParamSpec],
    topics: str,
    make_node: Callable[[argparse.Namespace], Node],
    argv: Sequence[str] | None = None,
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None,
) -> int:
    """The ``main()`` of every node: ``--help``, init, spin, clean shutdown."""
    argv = list(sys.argv if argv is None else argv)
    from rclpy.utilities import remove_ros_args

    parser = _help(executable, description, specs, topics)
    if add_arguments is not None:
        add_arguments(parser)
    options = parser.parse_args(remove_ros_args(argv)[1:])
    rclpy.init(args=argv)
    node = None
    try:
        node = make_node(options)
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SystemExit as exc:
        return int(exc.code or 0)
    except Exception:
        # SIGINT/SIGTERM shut the context down while a callback was publishing
        # ("publisher's context is invalid"): that is a normal stop, not a crash.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
