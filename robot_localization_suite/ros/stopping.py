"""A stop that cannot hang: the kernel sends this process a signal once a deadline has passed (nodes, rls_soak).

rclpy holds the GIL while the middleware destroys a node or shuts a context down (checked with gdb:
``PyGILState_Check()`` is 1 in ``rmw_destroy_node`` and ``rcl_shutdown``), and that teardown now and then
never returns (a DDS participant deletion that waits forever; eProsima/Fast-DDS#235, ros2/rclpy#456). No
Python thread can run then, so the deadline is a POSIX timer (``timer_create`` with ``SIGEV_SIGNAL``): the
kernel delivers the signal whatever the interpreter is doing, and with its default action it ends the process.
"""

from __future__ import annotations

import ctypes
import faulthandler
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from types import TracebackType

__all__ = ["SignalDeadline", "stopping", "STOP_SIGNALS", "SLOW_STOP_REPORT_S", "STOP_DEADLINE_S"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
SLOW_STOP_REPORT_S = 2.5  # a stop slower than this prints every thread's stack (where it hangs)
STOP_DEADLINE_S = 4.0  # then the stop signal ends it (before ros2 launch's SIGTERM at 5 s, rls_run's at 10 s)

_CLOCK_MONOTONIC = 1
_SIGEV_SIGNAL = 0
_SIGEVENT_SIZE = 64  # sizeof(struct sigevent) on Linux, every architecture


class _SigEvent(ctypes.Structure):
    _fields_ = [
        ("sigev_value", ctypes.c_void_p),
        ("sigev_signo", ctypes.c_int),
        ("sigev_notify", ctypes.c_int),
        ("_rest", ctypes.c_byte * (_SIGEVENT_SIZE - ctypes.sizeof(ctypes.c_void_p) - 2 * ctypes.sizeof(ctypes.c_int))),
    ]


class _TimeSpec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [("it_interval", _TimeSpec), ("it_value", _TimeSpec)]


def _libc() -> ctypes.CDLL | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.timer_create  # noqa: B018 - glibc >= 2.34 has it in libc
    except (OSError, AttributeError):
        try:
            libc = ctypes.CDLL("librt.so.1", use_errno=True)
        except OSError:
            return None
    return libc


class SignalDeadline:
    """``with SignalDeadline(4.0, signal.SIGINT):`` the process gets SIGINT if the block is still running
    after 4 s (from a kernel timer, so also while C code holds the GIL); leaving the block disarms it.

    Where POSIX timers are not available (not Linux) it does nothing: ``armed`` says which.
    """

    def __init__(self, seconds: float, signum: int = signal.SIGINT) -> None:
        if not seconds > 0.0:
            raise ValueError(f"a deadline needs a positive number of seconds, not {seconds!r}")
        self.seconds = float(seconds)
        self.signum = int(signum)
        self._libc = _libc()
        self._timer = ctypes.c_void_p()
        self.armed = False

    def __enter__(self) -> SignalDeadline:
        if self._libc is None:
            return self
        event = _SigEvent(sigev_signo=self.signum, sigev_notify=_SIGEV_SIGNAL)
        if self._libc.timer_create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(self._timer)) != 0:
            return self
        whole = int(self.seconds)
        spec = _ITimerSpec(it_value=_TimeSpec(whole, int(round((self.seconds - whole) * 1e9))))
        if self._libc.timer_settime(self._timer, 0, ctypes.byref(spec), None) != 0:
            self._libc.timer_delete(self._timer)
            return self
        self.armed = True
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 trace: TracebackType | None) -> None:
        if self.armed and self._libc is not None:
            self._libc.timer_delete(self._timer)  # deleting an armed timer disarms it
            self.armed = False


@contextmanager
def stopping(signum: int = signal.SIGINT) -> Iterator[None]:
    """Around a process's clean-up: a further SIGINT or SIGTERM ends the process (the default action); a
    clean-up still running after ``SLOW_STOP_REPORT_S`` prints every thread's stack to stderr, and one
    still running after ``STOP_DEADLINE_S`` is ended by ``signum`` (the signal that asked for the stop),
    as a second Ctrl-C would: the middleware's teardown can hang holding the GIL (above)."""
    for number in STOP_SIGNALS:
        signal.signal(number, signal.SIG_DFL)
    faulthandler.dump_traceback_later(SLOW_STOP_REPORT_S)
    try:
        with SignalDeadline(STOP_DEADLINE_S, signum):
            yield
    finally:
        faulthandler.cancel_dump_traceback_later()
