"""Whether a precomputation progress bar (tqdm) is shown: the caller's setting, unless the environment says no.

tqdm (>= 4.66) reads ``TQDM_DISABLE`` only as the *default* of its ``disable``
argument, so a bar created with ``disable=not show`` and ``show`` True ignores
it. A localizer's bars are switched by its own setting (``progress``,
``show_progress``) so that an interactive ``ros2 run`` shows them; a process
whose output is a log (``rls_bench``'s child runs set ``TQDM_DISABLE=1`` for
them) must be able to silence every bar at once without knowing each
localizer's setting. Passing ``disable=progress_disabled(show)`` gives both.
The variable is read at each call, so it may be set after tqdm was imported.

:class:`ReportingBar` is a tqdm bar whose progress a node reads from another thread
(:func:`current_progress`) to report it in its diagnostics while it precomputes.
"""

from __future__ import annotations

import os
import threading
from typing import Any

from tqdm.auto import tqdm

__all__ = ["PROGRESS_DISABLE_ENV", "ReportingBar", "current_progress", "progress_disabled"]

# Re-entrant: a bar's __del__ (tqdm closes on garbage collection) can run inside the locked region of
# another bar's close in the same thread; with a plain Lock that thread waited on itself (test_hybrid hung).
_LOCK = threading.RLock()
_OPEN_BARS: list[ReportingBar] = []

#: tqdm's own switch, honoured here too (any value but "", "0", "false", "no", "off").
PROGRESS_DISABLE_ENV = "TQDM_DISABLE"


def progress_disabled(show: bool) -> bool:
    """tqdm's ``disable`` for a bar the caller wants shown when ``show`` is True.

    True when ``show`` is False or ``$TQDM_DISABLE`` is set to a true value.
    """
    value = os.environ.get(PROGRESS_DISABLE_ENV, "").strip().lower()
    return (not show) or value not in ("", "0", "false", "no", "off")


class ReportingBar(tqdm):
    """A tqdm bar whose progress another thread can read (:func:`current_progress`), shown or not.

    A node runs its precomputation in a worker thread and reports the percentage in its
    diagnostics; tqdm does not count while disabled, so the bar keeps its own count.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.done = 0.0
        with _LOCK:
            _OPEN_BARS.append(self)

    def update(self, n: float | None = 1) -> bool | None:
        self.done += 1.0 if n is None else float(n)
        return super().update(n)

    def close(self) -> None:
        with _LOCK:  # by identity: tqdm compares bars by their screen position
            _OPEN_BARS[:] = [bar for bar in _OPEN_BARS if bar is not self]
        super().close()


def current_progress() -> float | None:
    """The fraction done [0, 1] of the open bars, nested ones within their parent's current step; None if none is open."""
    with _LOCK:
        bars = [bar for bar in _OPEN_BARS if bar.total]
    if not bars:
        return None
    fraction = 0.0
    for bar in reversed(bars):  # innermost first: a nested bar is one step of the bar that opened before it
        fraction = min(1.0, (bar.done + fraction) / float(bar.total))
    return fraction
