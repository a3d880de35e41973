"""LifecycleManager when a transition's answer is lost (Fast DDS, ros2/rmw_fastrtps#842).

A node of the test's own offers ``/mute/change_state``, which makes the transition but whose answer
never arrives (the callback is held until the test ends), and ``/mute/get_state``. The manager must
learn from ``get_state`` that the node made it, instead of waiting out its timeout.
"""

from __future__ import annotations

import threading
import time

import pytest

from robot_localization_suite.launch.lifecycle import LifecycleManager

rclpy = pytest.importorskip("rclpy")


class MuteNode:
    """``change_state`` whose answer never comes; ``get_state`` that reports the state reached (or not)."""

    def __init__(self, reaches: bool) -> None:
        from lifecycle_msgs.msg import State
        from lifecycle_msgs.srv import ChangeState, GetState
        from rclpy.callback_groups import ReentrantCallbackGroup
        from rclpy.executors import MultiThreadedExecutor

        self.state = State(id=State.PRIMARY_STATE_UNCONFIGURED, label="unconfigured")
        self.reaches = reaches
        self.release = threading.Event()
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("mute", context=self.context)
        group = ReentrantCallbackGroup()
        self.node.create_service(ChangeState, "/mute/change_state", self._change, callback_group=group)
        self.node.create_service(GetState, "/mute/get_state", self._get, callback_group=group)
        self.executor = MultiThreadedExecutor(num_threads=2, context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _change(self, request, response):  # noqa: ANN001, ANN202
        from lifecycle_msgs.msg import State

        if self.reaches:
            self.state = State(id=State.PRIMARY_STATE_INACTIVE, label="inactive")
        self.release.wait(60.0)  # the answer that gets lost
        response.success = self.reaches
        return response

    def _get(self, request, response):  # noqa: ANN001, ANN202
        response.current_state = self.state
        return response

    def close(self) -> None:
        self.release.set()
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.mark.parametrize("reaches", [True, False])
def test_a_transition_whose_answer_is_lost_is_known_by_the_nodes_state(reaches: bool, ros_domain_id: int) -> None:
    mute = MuteNode(reaches)
    lines: list[str] = []
    manager = LifecycleManager(["mute"], domain_id=ros_domain_id, log=lines.append, state_check_s=0.5)
    try:
        started = time.monotonic()
        ok = manager.change_state("mute", "configure", 8.0)
        waited = time.monotonic() - started
    finally:
        mute.close()
        manager.close()
    if reaches:
        assert ok and waited < 8.0, lines  # known from get_state, not from the (lost) answer
        assert any("its answer lost" in line and "'inactive'" in line for line in lines), lines
    else:  # the node is still unconfigured: no success is made up, the timeout stands
        assert not ok and any("did not answer within 8 s" in line for line in lines), lines
