"""Precomputation off the executor: one job at a time in a worker thread (issue 14, "Never blocked").

A localizer node hands its slow work to :class:`BackgroundWork` (a new map's setup, IR's index and
PIL's learning for the scanner of the first scan) so that its executor keeps answering services
and publishing diagnostics meanwhile. The node drops sensor inputs while a job runs and reports
``INITIALIZING`` with :meth:`BackgroundWork.percent`, read from the job's progress bars
(:func:`~robot_localization_suite.core.progress.current_progress`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from ..core.errors import LocalizationSuiteError
from ..core.progress import current_progress

__all__ = ["BackgroundWork"]


class BackgroundWork:
    """One job at a time in a daemon thread; :meth:`poll` (from the executor) reports how it ended.

    Args:
        log: ``log(level, text)`` with level ``"info"``, ``"warn"`` or ``"error"``.
    """

    def __init__(self, log: Callable[[str, str], None]) -> None:
        self._log = log
        self._thread: threading.Thread | None = None
        self._what = ""
        self._started = 0.0
        self._error: BaseException | None = None
        self._then: Callable[[], None] | None = None

    @property
    def busy(self) -> bool:
        """Whether a job has started and :meth:`poll` has not yet seen it end."""
        return self._thread is not None

    @property
    def what(self) -> str:
        return self._what

    def percent(self) -> float | None:
        """Percent done of the running job, from its progress bars; None when it has none open."""
        fraction = current_progress() if self.busy else None
        return None if fraction is None else round(100.0 * fraction, 1)

    def elapsed_s(self) -> float:
        return time.monotonic() - self._started if self.busy else 0.0

    def start(self, what: str, job: Callable[[], None], then: Callable[[], None] | None = None) -> None:
        """Run ``job`` in a worker thread; ``then`` runs in :meth:`poll` after it succeeded.

        Raises:
            RuntimeError: a job is running already (callers check :attr:`busy`).
        """
        if self._thread is not None:
            raise RuntimeError(f"cannot start {what!r}: {self._what!r} is still running")
        self._what, self._started, self._error, self._then = what, time.monotonic(), None, then

        def run() -> None:
            try:
                job()
            except BaseException as exc:  # noqa: BLE001 - reported by poll() on the executor's thread
                self._error = exc

        self._thread = threading.Thread(target=run, name=f"rls-{what}", daemon=True)
        self._log("info", f"{what}: started in the background (inputs are dropped until it ends)")
        self._thread.start()

    def poll(self) -> bool:
        """Report a job that has ended and run its ``then``; True when one ended in this call."""
        thread = self._thread
        if thread is None or thread.is_alive():
            return False
        thread.join()
        self._thread = None
        seconds = time.monotonic() - self._started
        if self._error is None:
            self._log("info", f"{self._what}: done in {seconds:.1f} s")
            if self._then is not None:
                self._then()
        elif isinstance(self._error, (LocalizationSuiteError, ValueError)):
            self._log("error", f"{self._what}: failed after {seconds:.1f} s: {self._error}")
        else:
            self._log("error", f"{self._what}: failed after {seconds:.1f} s: "
                      f"{type(self._error).__name__}: {self._error}")
        return True

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until the running job ends (tests, shutdown); True when none is running any more."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
        return self._thread is None or not self._thread.is_alive()
