"""A node in its own rclpy context and executor, spun on demand: the probes of tools and tests.

A process that starts localizer nodes as other processes and watches them over DDS
(``live_check``, the DDS tests) needs a node of its own that neither shares nor shuts down
the default context.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

__all__ = ["ContextNode"]


class ContextNode:
    """``self.node`` in a fresh ``rclpy.Context`` with a single-threaded executor.

    rclpy does not take SIGINT over for a context of its own: the caller stops on Ctrl-C.
    """

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.rclpy: Any = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        """Spin until ``done()`` or ``timeout`` [s]; whether ``done()`` came true."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
            if done():
                return True
        return False

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)
