"""Where the runs happen: one after another on this machine, or as tasks of a Dask cluster.

A :class:`Task` is one (bag, localizer, parameter set) run: a picklable function and its
arguments. :class:`SequentialExecutor` runs the tasks one at a time through
:func:`.isolation.call_guarded` (a spawned child per run, or in this process);
:class:`DaskExecutor` submits them to a Dask ``distributed`` cluster, where each task still
runs in a fresh spawned child of its worker (same isolation, same peak RSS, same timeout).
Both yield ``(task index, status, result, seconds)`` and never raise for a failed run. Dask
is imported only when a :class:`DaskExecutor` starts (the optional ``scale`` extra). How
and why: ``docs/benchmark.md``, "Dask, sweeps, trajectories out".
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import logging
import os
import re
import shutil
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from .isolation import call_guarded

__all__ = ["Task", "Executor", "SequentialExecutor", "DaskExecutor", "dask_available"]

# How long the client tries to reach an existing scheduler before giving up [s].
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class Task:
    """One run: ``func(*args, **kwargs)``; ``bag``: the bag directory it reads (shipped with ``--ship-bags``)."""

    label: str
    func: Callable[..., Any]
    args: tuple
    kwargs: dict[str, Any] = field(default_factory=dict)
    bag: Path | None = None


Outcome = tuple[int, str, Any, float]


class Executor(Protocol):
    """Runs tasks; yields ``(index, "ok", result, seconds)`` or ``(index, "error", text, seconds)`` per task."""

    isolate: bool
    parallel: bool

    def run(self, tasks: Sequence[Task]) -> Iterator[Outcome]: ...


@dataclass
class SequentialExecutor:
    """Today's path: the tasks in order, each in a spawned child (``isolate``) or in this process."""

    isolate: bool = True
    max_seconds: float | None = None
    child_progress: bool = False
    parallel: bool = False

    def run(self, tasks: Sequence[Task]) -> Iterator[Outcome]:
        for index, task in enumerate(tasks):
            started = time.perf_counter()
            status, result = call_guarded(task.func, task.args, task.kwargs, isolate=self.isolate,
                                          max_seconds=self.max_seconds, child_progress=self.child_progress)
            yield index, status, result, time.perf_counter() - started


def dask_available() -> bool:
    """Whether ``dask.distributed`` can be imported (the ``scale`` extra is installed)."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        return False
    return True


def _pack_bag(path: Path) -> bytes:
    """A bag directory as an uncompressed tar archive (what ``--ship-bags`` sends to the workers)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as archive:
        archive.add(path, arcname=path.name)
    return buffer.getvalue()


def _unpack_bag(blob: bytes) -> Path:
    """The shipped bag on this worker: unpacked once into the temp directory, keyed by its content."""
    digest = hashlib.sha256(blob).hexdigest()[:16]
    root = Path(tempfile.gettempdir()) / f"rls_bench_bags_{os.getuid()}" / digest
    with tarfile.open(fileobj=io.BytesIO(blob), mode="r") as archive:
        names = archive.getnames()
        top = names[0].split("/")[0]
        if not (root / top / "metadata.yaml").is_file():
            partial = root.with_name(f"{digest}.{os.getpid()}.tmp")
            archive.extractall(partial, filter="data")
            partial.mkdir(parents=True, exist_ok=True)
            try:
                partial.replace(root)
            except OSError:  # another task of this worker's host got there first
                shutil.rmtree(partial, ignore_errors=True)
    return root / top


def _relocate(args: tuple, old: Path, new: Path) -> tuple:
    """``args`` with every dataclass whose ``path`` is ``old`` (the bag's reference) pointing at ``new``."""
    return tuple(dataclasses.replace(a, path=new)
                 if dataclasses.is_dataclass(a) and not isinstance(a, type) and getattr(a, "path", None) == old
                 else a for a in args)


def _dask_task(func: Callable[..., Any], args: tuple, kwargs: dict[str, Any], max_seconds: float | None,
               child_progress: bool, bag: Path | None, blob: bytes | None) -> tuple[str, Any, float]:
    """What a Dask worker runs for one task: loopback DDS, the shipped bag if any, then a spawned child."""
    import multiprocessing

    from ...launch.dds import use_loopback

    started = time.perf_counter()
    use_loopback()  # the worker of an existing cluster may not have been started by rls_bench
    if multiprocessing.current_process().daemon:
        return ("error", "the Dask worker is a daemon process and cannot start the run's child process: start "
                "the workers with DASK_DISTRIBUTED__WORKER__DAEMON=False", time.perf_counter() - started)
    if blob is not None and bag is not None:
        args = _relocate(args, bag, _unpack_bag(blob))
    status, result = call_guarded(func, args, kwargs, isolate=True, max_seconds=max_seconds,
                                  child_progress=child_progress)
    return status, result, time.perf_counter() - started


def _serves_dashboard(dask_scheduler: Any = None) -> bool:
    """On the scheduler: whether it has a dashboard (an HTTP service and bokeh to draw its pages)."""
    import importlib.util

    services = getattr(dask_scheduler, "services", {})
    return "dashboard" in services and importlib.util.find_spec("bokeh") is not None


class _WorkerDeaths(logging.Handler):
    """The nannies' "Worker process PID was killed by signal N" lines, by PID.

    The nannies of a ``LocalCluster`` run in this process: their log says how a worker
    process ended, which the ``KilledWorker`` of its task does not.
    """

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.by_pid: dict[int, str] = {}

    def emit(self, record: logging.LogRecord) -> None:
        match = re.match(r"Worker process (\d+) (was killed|exited)", record.getMessage())
        if match:
            self.by_pid[int(match[1])] = record.getMessage()

    def cause(self, exc: BaseException, wait_s: float = 3.0) -> str | None:
        """How the worker behind ``exc`` (a ``KilledWorker``) ended, if its nanny said so within ``wait_s``."""
        pid = getattr(getattr(exc, "last_worker", None), "pid", None)
        deadline = time.monotonic() + wait_s
        while pid is not None and pid not in self.by_pid and time.monotonic() < deadline:
            time.sleep(0.05)  # the nanny notices the exit about when the scheduler does
        return self.by_pid.get(pid) if pid is not None else None


@dataclass
class DaskExecutor:
    """Tasks on a Dask cluster: a ``LocalCluster`` (``scheduler`` None) or an existing one at ``scheduler``.

    The cluster starts at the first :meth:`run` (and is reused by later ones); :meth:`close`
    stops what was started here. A ``LocalCluster`` has ``workers`` process workers
    (default: the CPU count) of one thread each, on 127.0.0.1, with DDS kept on loopback
    in every worker (:func:`...launch.dds.use_loopback` before they start). Without
    ``ship_bags`` the workers read each bag at the path the client gives (a shared path).
    """

    scheduler: str | None = None
    workers: int | None = None
    ship_bags: bool = False
    max_seconds: float | None = None
    child_progress: bool = False  # also: the cluster's log lines (rls_bench -v)
    progress: bool = True
    isolate: bool = True
    parallel: bool = True
    _client: Any = None
    _cluster: Any = None
    _shipped: dict[Path, Any] = field(default_factory=dict)
    _deaths: _WorkerDeaths = field(default_factory=_WorkerDeaths)

    def connect(self) -> Any:
        """The Dask client, connecting (or starting the LocalCluster) on first use."""
        if self._client is not None:
            return self._client
        import dask
        from distributed import Client, LocalCluster

        from ...launch.dds import use_loopback

        if self.scheduler is not None:
            try:
                self._client = Client(self.scheduler, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError) as exc:
                raise ValueError(f"cannot reach the Dask scheduler at {self.scheduler} "
                                 f"(within {CONNECT_TIMEOUT_S:.0f} s): {exc}") from exc
        else:
            use_loopback()  # inherited by the worker processes and their children
            n = self.workers or os.cpu_count() or 1
            # Workers start the run's child process: they must not be daemons. A worker that dies fails its
            # task at once (no re-run elsewhere: a run that kills its worker would kill the next one too).
            with dask.config.set({"distributed.worker.daemon": False, "distributed.scheduler.allowed-failures": 0}):
                if not self.child_progress:  # -v: the cluster's own log lines too
                    logging.getLogger("distributed").setLevel(logging.ERROR)
                nannies = logging.getLogger("distributed.nanny")
                nannies.setLevel(logging.INFO)
                nannies.addHandler(self._deaths)
                nannies.propagate = self.child_progress
                self._cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                             dashboard_address="127.0.0.1:0", memory_limit=0,
                                             silence_logs=logging.ERROR)
                self._client = Client(self._cluster)
        # A scheduler without bokeh serves no dashboard pages (and still has a dashboard_link): name it only then.
        link = self._client.dashboard_link if self._client.run_on_scheduler(_serves_dashboard) else None
        where = self.scheduler or f"LocalCluster of {self.workers or os.cpu_count() or 1} process workers"
        print(f"rls_bench: Dask: {where}" + (f", dashboard {link}" if link else ""), file=sys.stderr, flush=True)
        return self._client

    def ship(self, bags: Sequence[Path]) -> None:
        """Send these bag directories to the cluster (once each: later runs reuse what was sent)."""
        client = self.connect()
        for bag in dict.fromkeys(bags):
            if bag not in self._shipped:
                self._shipped[bag] = client.scatter(_pack_bag(bag), hash=True)

    def run(self, tasks: Sequence[Task]) -> Iterator[Outcome]:
        from distributed import as_completed
        from tqdm import tqdm

        client = self.connect()
        if self.ship_bags:
            self.ship([t.bag for t in tasks if t.bag is not None])
        futures = {}
        for index, task in enumerate(tasks):
            future = client.submit(_dask_task, task.func, task.args, task.kwargs, self.max_seconds,
                                   self.child_progress, task.bag, self._shipped.get(task.bag) if task.bag else None,
                                   pure=False, key=f"rls_bench-{index}-{task.label}-{os.urandom(4).hex()}")
            futures[future] = index
        bar = tqdm(total=len(tasks), desc="rls_bench", unit="run", disable=not self.progress or None)
        try:
            for future in as_completed(list(futures)):
                index = futures[future]
                try:
                    status, result, seconds = future.result()
                except Exception as exc:  # noqa: BLE001 - a lost worker fails its run, not the table
                    cause = self._deaths.cause(exc) if type(exc).__name__ == "KilledWorker" else None
                    text = f"{cause}: {exc}" if cause else str(exc)
                    status, result, seconds = "error", f"Dask worker failed: {type(exc).__name__}: {text}", 0.0
                bar.update(1)
                yield index, status, result, seconds
        finally:
            bar.close()

    def close(self) -> None:
        """Disconnect; stop the ``LocalCluster`` if this executor started one."""
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()
            nannies = logging.getLogger("distributed.nanny")
            nannies.removeHandler(self._deaths)
            nannies.propagate = True
        self._client = self._cluster = None
        self._shipped.clear()
