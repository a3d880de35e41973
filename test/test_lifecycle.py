"""LifecycleManager when a transition's request or answer is lost (Fast DDS, ros2/rmw_fastrtps#842).

A node of the test's own offers ``/mute/change_state`` and ``/mute/get_state``. Each change_state
request it receives follows the next step of a script: lost on the way in (never taken), made with its
answer lost, answered as a lifecycle node answers, or refused. The manager must learn from
``get_state`` what happened and ask again when a request was lost, instead of waiting out its timeout.
"""

from __future__ import annotations

import math
import threading
import time

import pytest

from robot_localization_suite.launch.lifecycle import LifecycleManager

rclpy = pytest.importorskip("rclpy")

UNCONFIGURED, INACTIVE = 1, 2


class MuteNode:
    """A lifecycle service whose ``configure`` requests follow ``script``, one step per request (the last repeats).

    Steps: ``"lost"`` (the request never reaches the node: no answer, no transition), ``"made_lost"`` (the
    transition is made, its answer lost), ``"answer"`` (as ``rclpy.lifecycle`` answers: made from
    unconfigured, refused as an invalid transition otherwise), ``"refuse"`` (the transition fails and says so),
    ``"late_made_lost"`` (taken only when the next request comes, then made with its answer lost: a request
    that was late, not lost). A lost answer is a callback held until the test ends.
    """

    def __init__(self, script: list[str]) -> None:
        from lifecycle_msgs.srv import ChangeState, GetState
        from rclpy.callback_groups import ReentrantCallbackGroup
        from rclpy.executors import MultiThreadedExecutor

        self.state = UNCONFIGURED
        self.script = script
        self.requests = 0
        self.holding, self.lock = 0, threading.Lock()
        self.release = threading.Event()
        self.later_request, self.late_made = threading.Event(), threading.Event()
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("mute", context=self.context)
        group = ReentrantCallbackGroup()
        self.node.create_service(ChangeState, "/mute/change_state", self._change, callback_group=group)
        self.node.create_service(GetState, "/mute/get_state", self._get, callback_group=group)
        self.executor = MultiThreadedExecutor(num_threads=8, context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _change(self, request, response):  # noqa: ANN001, ANN202
        step = self.script[min(self.requests, len(self.script) - 1)]
        self.requests += 1
        if step == "late_made_lost":
            self.later_request.wait(60.0)
            self.state = INACTIVE
            self.late_made.set()
            return self._held(response)
        if "late_made_lost" in self.script:  # the late request goes first
            self.later_request.set()
            self.late_made.wait(10.0)
        if step in ("lost", "made_lost"):
            if step == "made_lost":
                self.state = INACTIVE
            return self._held(response)
        if step == "answer":
            response.success = self.state == UNCONFIGURED
            self.state = INACTIVE
        else:
            response.success = False
        return response

    def _held(self, response):  # noqa: ANN001, ANN202
        with self.lock:
            self.holding += 1
        self.release.wait(60.0)
        with self.lock:
            self.holding -= 1
        return response

    def _get(self, request, response):  # noqa: ANN001, ANN202
        from lifecycle_msgs.msg import State

        labels = {UNCONFIGURED: "unconfigured", INACTIVE: "inactive"}
        response.current_state = State(id=self.state, label=labels[self.state])
        return response

    def close(self) -> None:
        self.release.set()
        deadline = time.monotonic() + 2.0
        while self.holding and time.monotonic() < deadline:  # the held answers go out before the node is destroyed
            time.sleep(0.05)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def configure(script: list[str], domain_id: int, timeout_s: float = 8.0,
              cancel_after_s: float = math.inf) -> tuple[bool, float, list[str], int]:
    """(success, seconds waited, the manager's lines, requests the node received) of one configure."""
    mute = MuteNode(script)
    lines: list[str] = []
    manager = LifecycleManager(["mute"], domain_id=domain_id, log=lines.append, state_check_s=0.5)
    try:
        started = time.monotonic()
        ok = manager.change_state("mute", "configure", timeout_s,
                                  cancelled=lambda: time.monotonic() - started > cancel_after_s)
        waited = time.monotonic() - started
    finally:
        mute.close()
        manager.close()
    return ok, waited, lines, mute.requests


def test_a_transition_whose_answer_is_lost_is_known_by_the_nodes_state(ros_domain_id: int) -> None:
    ok, waited, lines, requests = configure(["made_lost"], ros_domain_id)
    assert ok and waited < 8.0, lines  # known from get_state, not from the (lost) answer
    assert any("its answer lost" in line and "'inactive'" in line for line in lines), lines
    assert requests == 1, lines  # a node that made it is not asked again


def test_a_lost_request_is_sent_again_and_its_answer_counts(ros_domain_id: int) -> None:
    ok, waited, lines, requests = configure(["lost", "answer"], ros_domain_id)
    assert ok and waited < 8.0, lines
    assert any("asking again" in line and "'unconfigured'" in line for line in lines), lines
    assert requests == 2 and any("configure done" in line for line in lines), lines


def test_a_refusal_whose_answer_was_lost_is_reported_when_asked_again(ros_domain_id: int) -> None:
    ok, waited, lines, requests = configure(["lost", "refuse"], ros_domain_id)
    assert not ok and waited < 8.0, lines  # a failure, known long before the timeout
    assert any("configure FAILED" in line for line in lines), lines


def test_a_repeated_request_refused_because_the_first_was_made_late_counts_as_done(ros_domain_id: int) -> None:
    # the first request is taken only after the node first reports 'unconfigured' (it is made, its answer
    # lost); the repeated one then finds the node inactive and is refused as an invalid transition
    ok, waited, lines, requests = configure(["late_made_lost", "answer"], ros_domain_id)
    assert ok and waited < 8.0 and requests == 2, lines
    assert any("an earlier one had already been made" in line or "its answer lost" in line for line in lines), lines


def test_a_node_that_never_takes_the_request_is_not_made_up_a_success(ros_domain_id: int) -> None:
    ok, waited, lines, requests = configure(["lost"], ros_domain_id)
    assert not ok and any("did not answer within 8 s" in line for line in lines), lines
    # asked again at intervals doubling from the check interval (0.5 s): not once per check
    assert 2 <= requests <= 5, (requests, lines)


def test_a_run_that_stops_while_waiting_says_so_not_that_the_node_timed_out(ros_domain_id: int) -> None:
    # rls_run cancels the wait when another node exits; the line must not blame this node's timeout
    ok, waited, lines, _ = configure(["lost"], ros_domain_id, timeout_s=60.0, cancel_after_s=1.0)
    assert not ok and waited < 10.0, lines
    assert any("the run is stopping" in line for line in lines), lines
    assert not any("did not answer" in line for line in lines), lines
