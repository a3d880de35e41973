"""Global proposals for the hybrid localizer: single-scan global fixes asked for in the update or in a worker.

A :class:`ProposalSource` is any ``global_fix(scan)`` (PIL, IR, or a test's fake): ranked laser
poses from one scan, no prior. A query runs either inside the update (cheap: PIL, when its answer
is wanted at once) or in the source's own worker thread (slow: IR always), at most one query of
a source in flight, its result taken at a later update: a worker never blocks the update. A source that raises is skipped: the error is counted,
logged at its 1st, 10th, 100th... occurrence (a throttle without a clock) and reported in the
estimate's details (``/diagnostics``). Notes: docs/hybrid.md.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import weakref
from collections.abc import Callable
from concurrent import futures
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from ..localizer import Estimate
from ..scan import Scan

__all__ = ["ProposalSource", "Proposal", "ProposalRunner", "Worker", "power_of_ten"]

_LOG = logging.getLogger(__name__)
T = TypeVar("T")


@dataclass(frozen=True)
class ProposalSource:
    """A global fix the hybrid asks for candidates.

    Attributes:
        name: for details and logs (``pil``, ``ir``).
        fix: ``global_fix(scan)``: an estimate whose ``candidates`` are ranked best first.
        background: always run in a worker thread (one query in flight); otherwise the caller says where.
    """

    name: str
    fix: Callable[[Scan], Estimate]
    background: bool = False


@dataclass(frozen=True)
class Proposal:
    """The ranked candidates ``(K, 3)`` (laser poses) one source gave for the scan at ``stamp``."""

    source: str
    stamp: float
    candidates: NDArray[np.float64]


@dataclass
class _SourceState:
    source: ProposalSource
    errors: int = 0
    last_error: str = ""
    queries: int = 0
    future: Future[Estimate] | None = None
    future_stamp: float = 0.0
    future_generation: int = 0
    worker: Worker | None = None


class ProposalRunner:
    """Runs the sources: the ones in the update at once, the background ones in their worker.

    Args:
        sources: the proposal sources.
        log: ``log(level, text)``; default: this module's logger.
    """

    def __init__(self, sources: list[ProposalSource], log: Callable[[str, str], None] | None = None, *,
                 wait: bool = False) -> None:
        self._states = {source.name: _SourceState(source) for source in sources}
        self.wait = wait  # collect() waits for the queries in flight (reproducible replay)
        self._log = log or (lambda level, text: _LOG.warning(text) if level == "warn" else _LOG.info(text))
        self._generation = 0

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._states)

    def forget(self) -> None:
        """Results of queries already asked for are dropped (a new map)."""
        self._generation += 1

    def in_flight(self, name: str) -> bool:
        state = self._states[name]
        return state.future is not None

    def ask(self, name: str, scan: Scan, background: bool | None = None) -> list[Proposal]:
        """Query ``name`` with ``scan``: in the update (its proposal; none when it failed) or in its worker when
        that is free (none now; :meth:`collect` takes the result later). ``background`` None: as the source says.

        One query of a source at a time: asked in the update while its worker runs one (for an older scan),
        the update waits for that one, then asks about this scan; asked in the worker, nothing happens.
        """
        state = self._states[name]
        in_update = not (state.source.background if background is None else background or state.source.background)
        found: list[Proposal] = []
        if state.future is not None:
            if not in_update:
                return found
            future, state.future = state.future, None
            found.extend(self._result(state, future, state.future_stamp))
        state.queries += 1
        if in_update:
            try:
                estimate = state.source.fix(scan)
            except Exception as exc:  # noqa: BLE001 - a failing source is skipped, the tracking goes on
                self._failed(state, exc)
                return found
            proposal = self._proposal(state, scan.stamp, estimate)
            return found + ([proposal] if proposal is not None else [])
        state.future_stamp, state.future_generation = scan.stamp, self._generation
        if state.worker is None:
            state.worker = Worker(f"rls-hybrid-{name}")
        state.future = state.worker.submit(lambda: state.source.fix(scan))
        return found

    def collect(self) -> list[Proposal]:
        """The results of background queries that have ended since the last call (failures are skipped); with
        ``wait``, of every query in flight, waiting for those still running."""
        found = []
        for state in self._states.values():
            future = state.future
            if future is not None and (self.wait or future.done()):
                state.future = None
                found.extend(self._result(state, future, state.future_stamp))
        return found

    def settle(self, deadline: float) -> None:
        """Wait until the background queries in flight have ended, or until ``deadline`` (``time.monotonic()``)."""
        running = [state.future for state in self._states.values() if state.future is not None]
        if running:
            futures.wait(running, timeout=max(0.0, deadline - time.monotonic()))

    def _result(self, state: _SourceState, future: Future[Estimate], stamp: float) -> list[Proposal]:
        """The proposal of a background query (waiting for it to end); none when it failed or is of an old map."""
        try:
            estimate = future.result()
        except Exception as exc:  # noqa: BLE001 - as in ask()
            self._failed(state, exc)
            return []
        if state.future_generation != self._generation:
            return []
        proposal = self._proposal(state, stamp, estimate)
        return [proposal] if proposal is not None else []

    def details(self) -> dict[str, object]:
        """Per source: queries, errors and the last error (for ``/diagnostics``)."""
        out: dict[str, object] = {}
        for name, state in self._states.items():
            out[f"{name}_queries"] = state.queries
            out[f"{name}_in_flight"] = state.future is not None
            if state.errors:
                out[f"{name}_errors"] = state.errors
                out[f"{name}_last_error"] = state.last_error
        return out

    def close(self) -> None:
        """Drop the queries in flight (each finishes in its worker; its result is not used) and end the workers."""
        for state in self._states.values():
            state.future = None
            if state.worker is not None:
                state.worker.close()

    @staticmethod
    def _proposal(state: _SourceState, stamp: float, estimate: Estimate) -> Proposal | None:
        poses = np.asarray(estimate.candidates, dtype=np.float64).reshape(-1, 3)
        candidates: NDArray[np.float64] = poses[np.all(np.isfinite(poses), axis=1)]
        return Proposal(state.source.name, float(stamp), candidates) if len(candidates) else None

    def _failed(self, state: _SourceState, exc: Exception) -> None:
        state.errors += 1
        state.last_error = f"{type(exc).__name__}: {exc}"
        if power_of_ten(state.errors):
            self._log("warn", f"proposal source {state.source.name} failed ({state.errors} times so far), skipped: "
                      f"{state.last_error}")


class Worker:
    """One daemon thread running the work handed to it, in order; handing work over never waits for a thread.

    A thread started per query made the update wait until the new thread ran (``Thread.start`` waits for
    it): about 0.5 ms per query on an idle machine, more under load. Daemon: work still running never holds
    up the process' exit. The thread ends with :meth:`close` or when the worker is collected.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._queue: queue.SimpleQueue[tuple[Callable[[], Any], Future[Any]] | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        weakref.finalize(self, self._queue.put, None)

    def submit(self, work: Callable[[], T]) -> Future[T]:
        """``work()`` in the worker's thread, after the work handed over before it."""
        future: Future[T] = Future()
        future.set_running_or_notify_cancel()
        if self._thread is None:
            self._thread = threading.Thread(target=_serve, args=(self._queue,), name=self.name, daemon=True)
            self._thread.start()
        self._queue.put((work, future))
        return future

    def close(self) -> None:
        """End the thread once the work handed over has run (a later :meth:`submit` starts a new one)."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread = None


def _serve(work_queue: queue.SimpleQueue[tuple[Callable[[], Any], Future[Any]] | None]) -> None:
    while (item := work_queue.get()) is not None:
        work, future = item
        try:
            future.set_result(work())
        except BaseException as exc:  # noqa: BLE001 - handed to whoever takes the result
            future.set_exception(exc)


def power_of_ten(count: int) -> bool:
    """1, 10, 100...: when a repeated failure is logged (a throttle without a clock)."""
    while count >= 10 and count % 10 == 0:
        count //= 10
    return count == 1
