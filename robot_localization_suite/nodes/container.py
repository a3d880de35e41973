"""Several localizer nodes in one process, as a ROS 2 component container holds components.

``rls_run`` starts one of these for each ``container: NAME`` of a runfile::

    python -m robot_localization_suite.nodes.container NAME SPECS_JSON

``SPECS_JSON`` is a list of node specifications (the fields of ``launch.runner.NodeSpec``). numba,
LLVM, rclpy and the message packages are then loaded once for all of them (docs/footprint.md has
the figures). Each node keeps what it has in a process of its own: its name, its parameters (its
params file and ``-p`` overrides, as node-local ``--ros-args``), its remappings, its topics and its
lifecycle services. A :class:`ContainerExecutor` (a multi-threaded executor) spins them; each node's
callbacks run in its own mutually exclusive callback group (rclpy's default group of the node), so
one node's long update never blocks another's. A node whose construction or callback raises is
logged with its traceback, removed from the executor and destroyed; the others keep running. A node
that goes through its ``shutdown`` transition leaves the container; the process ends when no node
is left, with status 1 when one of them failed.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import threading
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import (
    ConditionReachedException,
    ExternalShutdownException,
    MultiThreadedExecutor,
    ShutdownException,
    TimeoutException,
)
from rclpy.node import Node

from ..ros.stopping import stopping
from .common import init_ros

__all__ = ["Container", "ContainerExecutor", "main"]

PACKAGE = "robot_localization_suite"


class ContainerExecutor(MultiThreadedExecutor):
    """rclpy's multi-threaded executor, except that a callback's exception is handed to ``on_failure(node, exc)``.

    rclpy's own re-raises it from ``spin_once``, which would end every node of the process. This
    replaces its ``_spin_once_impl`` (rclpy 7.1, Jazzy) to remember which node each callback belongs to.
    """

    def __init__(self, on_failure: Callable[[Node | None, BaseException], None], num_threads: int | None = None,
                 **kwargs: Any) -> None:
        super().__init__(num_threads=num_threads, **kwargs)
        self._on_failure = on_failure
        self._owners: dict[Any, Node] = {}

    def busy(self) -> bool:
        """Whether a callback handed to a worker thread has not finished."""
        return any(not future.done() for future in self._futures)

    def _spin_once_impl(self, timeout_sec: Any = None, wait_condition: Callable[[], bool] = lambda: False) -> None:
        try:
            ready: tuple[Any, Any, Node] = self.wait_for_ready_callbacks(timeout_sec, None, wait_condition)
            handler, node = ready[0], ready[2]
        except (ExternalShutdownException, ShutdownException, TimeoutException, ConditionReachedException):
            pass
        else:
            self._executor.submit(handler)
            self._futures.append(handler)
            self._owners[handler] = node
        for future in self._futures[:]:
            if future.done():
                self._futures.remove(future)
                owner = self._owners.pop(future, None)
                try:
                    future.result()
                except Exception as exc:  # noqa: BLE001 - one node's failure must not end the others
                    self._on_failure(owner, exc)


class Container:
    """The nodes of one process and their executor.

    Args:
        name: the container's name (in its log lines).
        log: ``log(text)`` for the container's own lines (default: stderr).
    """

    def __init__(self, name: str, *, log: Callable[[str], None] | None = None, context: Any = None) -> None:
        self.name = name
        self.log = log or (lambda text: print(f"container {name}: {text}", file=sys.stderr, flush=True))
        self.nodes: dict[str, Node] = {}
        self.failed: list[str] = []
        self._lock = threading.Lock()
        self.executor = ContainerExecutor(self._failed, context=context)

    def add(self, name: str, make: Callable[[], Node]) -> bool:
        """Build a node with ``make()`` and spin it; False (logged, the others untouched) when it raises."""
        try:
            node = make()
        except Exception as exc:  # noqa: BLE001 - a node that cannot start must not stop the others
            self._report(name, exc, "could not start")
            return False
        with self._lock:
            self.nodes[node.get_name()] = node
        self.executor.add_node(node)
        self.log(f"loaded {node.get_name()}")
        return True

    def _report(self, name: str, exc: BaseException, what: str) -> None:
        self.failed.append(name)
        details = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__, limit=6)).rstrip()
        self.log(f"{name} {what}: {type(exc).__name__}: {exc}: stopped it, the other nodes keep running\n{details}")

    def _failed(self, node: Node | None, exc: BaseException) -> None:
        if node is None:
            self.log(f"a callback of no node raised {type(exc).__name__}: {exc}")
            return
        name = self._take(node)
        if name is None:
            return  # a callback that was under way as its node was stopped for an earlier failure
        self._report(name, exc, "raised")
        self._destroy(name, node)

    def remove(self, node: Node) -> None:
        """Stop spinning ``node`` and destroy it."""
        name = self._take(node)
        if name is not None:
            self._destroy(name, node)

    def _take(self, node: Node) -> str | None:
        """Drop ``node`` from the nodes held; its name, or None if it is no longer held.

        By identity, not ``node.get_name()``: a second failing callback of a node another thread is destroying
        raised InvalidHandle there (test_container, once in a fresh-clone run)."""
        with self._lock:
            name = next((key for key, held in self.nodes.items() if held is node), None)
            if name is not None:
                del self.nodes[name]
        return name

    def _destroy(self, name: str, node: Node) -> None:
        self.executor.remove_node(node)
        try:
            node.destroy_node()
        except Exception as exc:  # noqa: BLE001 - the node is gone either way
            self.log(f"{name}: destroying it raised {type(exc).__name__}: {exc}")

    def spin(self, ok: Callable[[], bool] = lambda: True, period_s: float = 0.2) -> None:
        """Spin until ``ok()`` is false or no node is left; nodes that asked to exit (shutdown) leave."""
        while ok() and self.nodes:
            self.executor.spin_once(timeout_sec=period_s)
            for node in list(self.nodes.values()):
                if getattr(node, "exit_requested", False):
                    self.log(f"{node.get_name()} shut down: removed")
                    self.remove(node)

    def close(self) -> None:
        for node in list(self.nodes.values()):
            self.remove(node)
        self.executor.shutdown(timeout_sec=2.0)


def node_factory(spec: dict[str, Any]) -> Callable[[], Node]:
    """What builds one node of ``spec`` (a ``NodeSpec`` as a dict): its module's ``create_node`` with its own arguments."""
    from ..launch.runner import node_spec_from_dict

    node_spec = node_spec_from_dict(spec, 0)
    module = importlib.import_module(node_spec.module)
    create = getattr(module, "create_node", None)
    if create is None:
        raise ValueError(f"{node_spec.executable} cannot run in a container (its module has no create_node)")
    arguments = node_spec.ros_arguments()
    return lambda: create(cli_args=arguments, use_global_arguments=False)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m robot_localization_suite.nodes.container",
        description="Several localizer nodes in one process (rls_run starts it for a runfile's 'container: NAME').")
    parser.add_argument("name", help="the container's name")
    parser.add_argument("specs", help="JSON list of node specifications (executable, name, params_file, parameters, "
                                      "remaps)")
    options = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    specs = json.loads(options.specs)
    stop = init_ros()
    container = Container(options.name)
    try:
        for spec in specs:
            name = spec.get("name", spec.get("executable", "?"))
            try:
                make = node_factory(spec)
            except Exception as exc:  # noqa: BLE001 - reported like a node that raises
                container._report(name, exc, "could not start")
                continue
            container.add(name, make)
        container.spin(lambda: rclpy.ok() and not stop.requested)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # The context shut down while a callback was publishing: a normal stop.
        if rclpy.ok():
            raise
    finally:
        code = 1 if container.failed else 0
        if container.executor.busy():
            # A callback still running (a kernel compiling, an update of seconds) would hold the process
            # until it ends (destroying its node waits for it, the worker threads are joined at exit).
            container.log("a callback is still running: exiting without waiting for it")
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        with stopping(stop.signum):
            container.close()
            rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
