"""Bring lifecycle nodes up through their ``lifecycle_msgs`` services, as nav2's lifecycle manager does.

``rls_run`` (runfile ``autostart: true``, the default) and ``rls_demo`` use :class:`LifecycleManager`
on the localizer nodes they start: every node configured in order, then every node activated,
each transition a ``ChangeState`` call on ``/<node>/change_state``. With ``autostart: false`` they
leave that to another manager (nav2's ``lifecycle_manager``, ``ros2 lifecycle set``, a test).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from .dds import use_loopback

__all__ = ["LifecycleManager", "TRANSITIONS"]

# Transition label -> lifecycle_msgs/Transition id; "shutdown" has one id per state, the label names all.
TRANSITIONS = {"configure": 1, "cleanup": 2, "activate": 3, "deactivate": 4, "shutdown": 5}


class LifecycleManager:
    """Service clients for the lifecycle of ``nodes``, in a rclpy context of their own.

    Args:
        nodes: node names (their services are ``/<name>/change_state``, ``/<name>/get_state``).
        domain_id: the nodes' ``ROS_DOMAIN_ID`` (this process joins it on loopback DDS).
        log: receives one line per transition.
    """

    def __init__(self, nodes: Sequence[str], *, domain_id: int | None = None,
                 log: Callable[[str], None] = print) -> None:
        import rclpy
        from lifecycle_msgs.srv import ChangeState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.nodes = list(nodes)
        self.log = log
        use_loopback(domain_id)
        self._rclpy = rclpy
        self._context = rclpy.Context()
        # The caller stops the nodes on Ctrl-C: rclpy must not take SIGINT over.
        rclpy.init(context=self._context, signal_handler_options=SignalHandlerOptions.NO)
        self._node = rclpy.create_node("rls_lifecycle_manager", context=self._context)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._clients = {name: self._node.create_client(ChangeState, f"/{name}/change_state") for name in self.nodes}
        self._request_type = ChangeState.Request
        self._lock = threading.Lock()

    def change_state(self, name: str, transition: str, timeout_s: float,
                     cancelled: Callable[[], bool] = lambda: False) -> bool:
        """Ask ``name`` for ``transition`` and wait for its answer: True when it succeeded."""
        from lifecycle_msgs.msg import Transition

        client = self._clients[name]
        deadline = time.monotonic() + timeout_s
        while not client.wait_for_service(timeout_sec=0.2):
            if cancelled() or time.monotonic() > deadline:
                self.log(f"{name}: no lifecycle service /{name}/change_state within {timeout_s:g} s")
                return False
        request = self._request_type(transition=Transition(id=TRANSITIONS[transition], label=transition))
        started = time.monotonic()
        with self._lock:
            future: Any = client.call_async(request)
            while not future.done():
                if cancelled() or time.monotonic() > deadline:
                    self.log(f"{name}: {transition} did not answer within {timeout_s:g} s")
                    return False
                self._executor.spin_once(timeout_sec=0.1)
        ok = bool(future.result().success)
        self.log(f"{name}: {transition} {'done' if ok else 'FAILED'} in {time.monotonic() - started:.2f} s")
        return ok

    def startup(self, timeout_s: float = 600.0, cancelled: Callable[[], bool] = lambda: False) -> bool:
        """Configure every node, then activate every node (nav2's order); False at the first failure."""
        for transition in ("configure", "activate"):
            for name in self.nodes:
                if cancelled() or not self.change_state(name, transition, timeout_s, cancelled):
                    return False
        return True

    def close(self) -> None:
        self._executor.shutdown(timeout_sec=1.0)
        self._node.destroy_node()
        if self._context.ok():
            self._rclpy.shutdown(context=self._context)
