"""A node's stop cannot hang (ros/stopping.py): a clean-up stuck in C code
that holds the GIL, as the middleware's teardown can be, is ended by the stop signal after the deadline."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import pytest

from robot_localization_suite.ros.stopping import SLOW_STOP_REPORT_S, STOP_DEADLINE_S, SignalDeadline

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="POSIX timers (timer_create)")


def _run(code: str, timeout: float) -> tuple[subprocess.CompletedProcess[str], float]:
    start = time.monotonic()
    run = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                         timeout=timeout)
    return run, time.monotonic() - start


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_clean_up_stuck_holding_the_gil_is_ended_by_the_stop_signal_after_the_deadline(signum: int) -> None:
    # pause() through PyDLL keeps the GIL: no Python thread (no threading.Timer) could end this.
    run, elapsed = _run(f"""
        import ctypes
        from robot_localization_suite.ros.stopping import stopping
        print("stopping", flush=True)
        with stopping({int(signum)}):
            ctypes.PyDLL(None).pause()
        print("never here", flush=True)
    """, timeout=STOP_DEADLINE_S + 60.0)
    assert run.returncode == -signum, run.stderr
    assert run.stdout.splitlines() == ["stopping"]
    assert elapsed >= STOP_DEADLINE_S
    # Where it hung was printed first (faulthandler), naming the line.
    assert f"Timeout (0:00:{SLOW_STOP_REPORT_S:09.6f})!" in run.stderr, run.stderr
    assert 'File "<string>", line 6 in <module>' in run.stderr, run.stderr


def test_a_clean_up_that_ends_in_time_disarms_the_deadline() -> None:
    run, _ = _run("""
        import time
        from robot_localization_suite.ros.stopping import SignalDeadline
        with SignalDeadline(0.3) as deadline:
            print("armed", deadline.armed, flush=True)
        time.sleep(1.0)
        print("still here", flush=True)
    """, timeout=60.0)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines() == ["armed True", "still here"]


def test_a_deadline_needs_positive_seconds() -> None:
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="positive number of seconds"):
            SignalDeadline(bad)
