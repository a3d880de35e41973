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
# Transition label -> the lifecycle_msgs/State id it ends in (unconfigured 1, inactive 2, active 3, finalized 4).
GOAL_STATES = {"configure": 2, "cleanup": 1, "activate": 3, "deactivate": 2, "shutdown": 4}
# Transition label -> the state it starts from (shutdown has several, so it is never asked again).
START_STATES = {"configure": 1, "cleanup": 2, "activate": 2, "deactivate": 3}


class LifecycleManager:
    """Service clients for the lifecycle of ``nodes``, in a rclpy context of their own.

    A transition's request or answer can be lost: a service may answer before its response writer has matched
    the client's reader (Fast DDS, ros2/rmw_fastrtps#842, many nodes starting at once), and a request can go
    missing the same way. While waiting, the node's state is asked every ``state_check_s``: a node in the
    transition's goal state has made it; one still in the state it starts from is asked again.

    Args:
        nodes: node names (their services are ``/<name>/change_state``, ``/<name>/get_state``).
        domain_id: the nodes' ``ROS_DOMAIN_ID`` (this process joins it on loopback DDS).
        log: receives one line per transition.
        state_check_s: seconds between ``get_state`` checks while a transition's answer is awaited.
    """

    def __init__(self, nodes: Sequence[str], *, domain_id: int | None = None,
                 log: Callable[[str], None] = print, state_check_s: float = 5.0) -> None:
        import rclpy
        from lifecycle_msgs.srv import ChangeState, GetState
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
        self._state_clients = {name: self._node.create_client(GetState, f"/{name}/get_state") for name in self.nodes}
        self._request_type = ChangeState.Request
        self._state_request_type = GetState.Request
        self.state_check_s = state_check_s
        self._lock = threading.Lock()

    def change_state(self, name: str, transition: str, timeout_s: float,
                     cancelled: Callable[[], bool] = lambda: False) -> bool:
        """Ask ``name`` for ``transition`` and wait for its answer: True when it succeeded.

        While no answer comes, the node's state is checked every ``state_check_s``: in the goal state, the
        transition was made and its answer lost; still in the state it starts from, the request itself was lost
        (or never taken), so it is sent again, at intervals doubling from ``state_check_s``. A repeated request
        that the node refuses because an earlier one already moved it on counts by the state it reports.
        """
        from lifecycle_msgs.msg import Transition

        client = self._clients[name]
        deadline = time.monotonic() + timeout_s
        while not client.wait_for_service(timeout_sec=0.2):
            if cancelled():
                self.log(f"{name}: stopped waiting for /{name}/change_state: the run is stopping")
                return False
            if time.monotonic() > deadline:
                self.log(f"{name}: no lifecycle service /{name}/change_state within {timeout_s:g} s")
                return False
        request = self._request_type(transition=Transition(id=TRANSITIONS[transition], label=transition))
        started = time.monotonic()
        with self._lock:
            sent: list[Any] = [client.call_async(request)]
            try:
                answer = self._await_answer(name, transition, request, sent, (started, deadline, timeout_s),
                                            cancelled)
                if isinstance(answer, bool):
                    return answer
                ok = answer is not None and bool(answer.success)
                if not ok and len(sent) > 1 and self._reached(name, GOAL_STATES[transition], deadline):
                    self.log(f"{name}: {transition} done in {time.monotonic() - started:.2f} s (a repeated request "
                             "was refused: an earlier one had already been made)")
                    return True
            finally:
                for future in sent:
                    if not future.done():
                        client.remove_pending_request(future)
        self.log(f"{name}: {transition} {'done' if ok else 'FAILED'} in {time.monotonic() - started:.2f} s")
        return ok

    def _await_answer(self, name: str, transition: str, request: Any, sent: list[Any],
                      times: tuple[float, float, float], cancelled: Callable[[], bool]) -> Any:
        """Spin until one of ``sent`` answers (its response), or a verdict from the node's state (a bool).

        ``times`` is (started, deadline, timeout_s) of the transition.
        """
        started, deadline, timeout_s = times
        state: Any = None
        next_check = started + self.state_check_s
        last_sent, resend_after = started, self.state_check_s
        while not any(future.done() for future in sent):
            now = time.monotonic()
            if cancelled():
                self.log(f"{name}: stopped waiting for {transition} after {now - started:.1f} s: the run is stopping")
                return False
            if now > deadline:
                self.log(f"{name}: {transition} did not answer within {timeout_s:g} s "
                         f"(asked {len(sent)} time{'s' if len(sent) > 1 else ''})")
                return False
            self._executor.spin_once(timeout_sec=0.1)
            if state is not None and state.done():
                current = state.result().current_state
                if current.id == GOAL_STATES[transition]:
                    self.log(f"{name}: {transition} done in {now - started:.2f} s, its answer lost "
                             f"(the node reports {current.label!r})")
                    return True
                if current.id == START_STATES.get(transition) and now - last_sent >= resend_after:
                    self.log(f"{name}: no answer to {transition} after {now - started:.1f} s and the node still "
                             f"reports {current.label!r}: asking again")
                    sent.append(self._clients[name].call_async(request))
                    last_sent, resend_after = now, 2.0 * resend_after
                state = None
            if state is None and time.monotonic() >= next_check:
                state = self._state_clients[name].call_async(self._state_request_type())
                next_check = time.monotonic() + self.state_check_s
        return next(future for future in sent if future.done()).result()

    def _reached(self, name: str, state_id: int, deadline: float) -> bool:
        """Whether ``name`` reports ``state_id``, asked once (False when it does not answer in time)."""
        future = self._state_clients[name].call_async(self._state_request_type())
        until = min(deadline, time.monotonic() + 2.0 * self.state_check_s)
        while not future.done() and time.monotonic() < until:
            self._executor.spin_once(timeout_sec=0.1)
        if not future.done():
            self._state_clients[name].remove_pending_request(future)
            return False
        return bool(future.result().current_state.id == state_id)

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
