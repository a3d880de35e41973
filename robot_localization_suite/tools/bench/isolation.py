"""Each run in a fresh child process, and the memory it used.

A (bag, localizer) run happens in a ``spawn``-ed child so that its peak RSS is its own
and a crash or hang in one localizer cannot take the table down. Functions and
arguments sent to a child must be picklable (module-level). Why ``VmHWM`` and not
``ru_maxrss``: ``docs/benchmark.md``.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import resource
import sys
import traceback
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["call_guarded", "own_peak_rss_mb", "rss_mb"]

# Child processes get this long beyond --max-seconds to build, replay and hand back their result.
_CHILD_GRACE_S = 600.0
# Environment of a child run without -v: no precomputation progress bars in the output (core/progress.py).
_QUIET_CHILD_ENV = {"TQDM_DISABLE": "1"}


def rss_mb() -> float:
    """Resident memory of this process now [MB] (psutil)."""
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def _child_main(conn: Any, func: Callable[..., Any], args: tuple, kwargs: dict) -> None:
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    try:
        result = func(*args, **kwargs)
        result.peak_rss_mb = own_peak_rss_mb()
        conn.send(("ok", result))
    except BaseException as exc:  # noqa: BLE001 - everything goes back to the parent as text
        conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"))
    finally:
        conn.close()


def own_peak_rss_mb() -> float:
    """Peak resident memory [MB] of this process image.

    ``VmHWM`` of ``/proc/self/status`` belongs to the address space made by ``exec``, so a
    spawned child reports its own peak; ``ru_maxrss`` would keep the parent's size from the
    ``fork`` before the ``exec`` (Linux keeps it across exec). Elsewhere ``ru_maxrss`` it is.
    """
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except OSError:
        pass
    scale = 1024.0 if sys.platform != "darwin" else 1024.0**2
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale, 1)


def _run_isolated(
    func: Callable[..., Any], args: tuple, kwargs: dict, timeout: float, env: Mapping[str, str] | None = None
) -> tuple[str, Any]:
    """Run ``func(*args, **kwargs)`` in a fresh spawned process; ``("ok", result)`` or ``("error", text)``.

    ``env``: variables added to the child's environment (a spawned child copies this
    process's environment when it starts; it is set just for that and restored).
    """
    context = mp.get_context("spawn")
    receiver, sender = context.Pipe(duplex=False)
    process = context.Process(target=_child_main, args=(sender, func, args, kwargs), daemon=True)
    saved = {name: os.environ.get(name) for name in env or {}}
    try:
        os.environ.update(env or {})
        process.start()
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    sender.close()
    answered = False
    try:
        if receiver.poll(timeout):
            outcome = receiver.recv()
            answered = True
        else:
            outcome = ("error", f"no result within {timeout:.0f} s; child stopped")
    except EOFError:
        process.join(5.0)
        outcome = ("error", f"child process died (exit code {process.exitcode})")
    finally:
        # A child that answered exits by itself (and releases its semaphores); a stuck one is killed.
        process.join(30.0 if answered else 0.0)
        if process.is_alive():
            process.kill()
        process.join()
        receiver.close()
    return outcome



def call_guarded(
    func: Callable[..., Any],
    args: tuple,
    kwargs: dict,
    *,
    isolate: bool,
    max_seconds: float | None,
    child_progress: bool,
) -> tuple[str, Any]:
    """``func(*args, **kwargs)`` in a spawned child (``isolate``) or here; never raises.

    Returns ``("ok", result)`` or ``("error", text)``. A child gets ``max_seconds`` plus
    a grace period, and runs with ``TQDM_DISABLE=1`` unless ``child_progress``.
    """
    if isolate:
        timeout = (max_seconds or 24 * 3600.0) + _CHILD_GRACE_S
        return _run_isolated(func, args, kwargs, timeout, env=None if child_progress else _QUIET_CHILD_ENV)
    try:
        return "ok", func(*args, **kwargs)
    except Exception as exc:  # noqa: BLE001 - one localizer must not stop the table
        return "error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"
