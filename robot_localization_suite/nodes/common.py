"""What every node shares: ``--help`` from its settings, a guarded callback, and ``main()``'s shape."""

from __future__ import annotations

import argparse
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from ..core.settings import Settings, help_text

__all__ = ["run_node", "guarded", "help_parser"]


def guarded(node: Node, callback: Callable[..., Any], what: str) -> Callable[..., Any]:
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


def help_parser(executable: str, description: str, settings: Sequence[type[Settings]], topics: str) -> argparse.ArgumentParser:
    """``--help``: the description, the topics and every parameter (default, unit, range, meaning)."""
    epilog = "topics:\n" + topics + "\n\nparameters (set with --ros-args -p NAME:=VALUE or --params-file FILE):\n"
    epilog += help_text(*settings)
    return argparse.ArgumentParser(
        prog=f"ros2 run robot_localization_suite {executable}",
        description=description,
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def run_node(
    parser: argparse.ArgumentParser,
    make_node: Callable[[argparse.Namespace], Node],
    argv: Sequence[str] | None = None,
) -> int:
    """The ``main()`` of every node: ``--help``, init, spin, clean shutdown."""
    argv = list(sys.argv if argv is None else argv)
    from rclpy.utilities import remove_ros_args

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
