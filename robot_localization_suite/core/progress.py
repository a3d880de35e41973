"""Whether a precomputation progress bar (tqdm) is shown: the caller's setting, unless the environment says no.

tqdm (>= 4.66) reads ``TQDM_DISABLE`` only as the *default* of its ``disable``
argument, so a bar created with ``disable=not show`` and ``show`` True ignores
it. A localizer's bars are switched by its own setting (``progress``,
``show_progress``) so that an interactive ``ros2 run`` shows them; a process
whose output is a log (``rls_bench``'s child runs set ``TQDM_DISABLE=1`` for
them) must be able to silence every bar at once without knowing each
localizer's setting. Passing ``disable=progress_disabled(show)`` gives both.
The variable is read at each call, so it may be set after tqdm was imported.
"""

from __future__ import annotations

import os

__all__ = ["PROGRESS_DISABLE_ENV", "progress_disabled"]

#: tqdm's own switch, honoured here too (any value but "", "0", "false", "no", "off").
PROGRESS_DISABLE_ENV = "TQDM_DISABLE"


def progress_disabled(show: bool) -> bool:
    """tqdm's ``disable`` for a bar the caller wants shown when ``show`` is True.

    True when ``show`` is False or ``$TQDM_DISABLE`` is set to a true value.
    """
    value = os.environ.get(PROGRESS_DISABLE_ENV, "").strip().lower()
    return (not show) or value not in ("", "0", "false", "no", "off")
