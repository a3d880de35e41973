"""What every node shares: ``--help`` from its settings, a guarded callback, and ``main()``'s shape."""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..core.errors import LocalizationSuiteError
from ..core.settings import Settings, help_text
from ..ros.stopping import STOP_SIGNALS, stopping

__all__ = ["run_node", "guarded", "help_parser", "invocation", "init_ros", "StopRequest"]


class StopRequest:
    """Set by SIGINT or SIGTERM; the spin loop ends at its next turn (at most 0.2 s, or when a callback returns).

    No exception is raised into running code (one raised inside numba's compiler crashed a node);
    after the first signal a second one ends the process at once (the default action).
    """

    def __init__(self) -> None:
        self.signal: str | None = None

    def __call__(self, signum: int, _frame: Any) -> None:
        self.signal = signal.Signals(signum).name
        for number in STOP_SIGNALS:
            signal.signal(number, signal.SIG_DFL)

    @property
    def requested(self) -> bool:
        return self.signal is not None

    @property
    def signum(self) -> int:
        """The signal that asked for the stop; SIGINT when none did (a shutdown transition, an error)."""
        return int(signal.Signals[self.signal]) if self.signal else int(signal.SIGINT)


def init_ros(args: Sequence[str] | None = None) -> StopRequest:
    """``rclpy.init`` with Python's own stop: SIGINT and SIGTERM set the returned ``StopRequest``.

    rclpy's handlers shut the context down from a thread of their own, concurrently with the main
    thread destroying the nodes; here the main thread leaves its spin loop, then does both, in order
    (README, "Running several nodes").
    """
    rclpy.init(args=list(args) if args is not None else None, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopRequest()
    for number in STOP_SIGNALS:
        signal.signal(number, stop)
    return stop


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


def invocation(executable: str) -> str:
    """How this executable is started where it runs: ``ros2 run`` only where there is a ``ros2``."""
    if shutil.which("ros2"):
        return f"ros2 run robot_localization_suite {executable}"
    started = sys.argv[0] if sys.argv else ""
    if not started or started.endswith(".py") or started == "-m":  # python -m robot_localization_suite.nodes.X
        return f"{sys.executable} -m robot_localization_suite.nodes.{executable}"
    return executable if shutil.which(executable) == started else started


def help_parser(executable: str, description: str, settings: Sequence[type[Settings]], topics: str) -> argparse.ArgumentParser:
    """``--help``: the description, the topics and every parameter (default, unit, range, meaning)."""
    epilog = "topics:\n" + topics + "\n\nparameters (set with --ros-args -p NAME:=VALUE or --params-file FILE):\n"
    epilog += help_text(*settings)
    return argparse.ArgumentParser(
        prog=invocation(executable),
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

    try:
        options = parser.parse_args(remove_ros_args(argv)[1:])
    except RuntimeError as exc:  # rcl's RCLInvalidROSArgsError: a -p value that is no YAML, an unknown flag
        print(f"{parser.prog}: {str(exc).split(', at /')[0]}", file=sys.stderr)
        return 2
    stop = init_ros(argv)
    node = None
    try:
        node = make_node(options)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # A lifecycle node's shutdown transition ends the process once its reply is sent.
        while rclpy.ok() and not stop.requested and not getattr(node, "exit_requested", False):
            executor.spin_once(timeout_sec=0.2)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SystemExit as exc:
        return int(exc.code or 0)
    except LocalizationSuiteError as exc:
        # A parameter of the wrong type or out of range: one line, as argparse reports a bad option.
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return 2
    except Exception:
        # The context shut down while a callback was publishing ("publisher's context is
        # invalid"): that is a normal stop, not a crash.
        if rclpy.ok():
            raise
    finally:
        with stopping(stop.signum):
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
    return 0
