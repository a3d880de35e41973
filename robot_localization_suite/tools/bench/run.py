"""The benchmark over bags x localizers: plan the pairs, run each, summarize, write the files.

:func:`run_benchmark` replays every bag through every localizer (``summary.json``,
``summary.md``, plots); :func:`run_global_fixes` asks for single-scan global fixes
instead. Each pair is a task (:func:`replay_task`, :func:`global_fix_task`) for an executor
(``executor.py``: a child process per run, one after another or on Dask), scored here when it
comes back (:func:`finish_replay`, :func:`finish_global_fixes`).
"""

from __future__ import annotations

import functools
import logging
import os
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from ...core import metrics
from ...core.grid_map import GridMap
from .coverage import CoverageCache, OutputScores, global_fix_scores, replay_scores, run_coverage_fields
from .executor import Executor, SequentialExecutor, Task
from .global_fixes import global_fix_localizer
from .reference import IMAGE_TOPIC, SCAN_TOPIC, TRUTH_TOPIC, BagReference, load_reference, map_candidates, resolve_map
from .replay import replay_localizer
from .specs import LocalizerSpec
from .summary import summarize_global_fixes, summarize_run
from .tables import one_line, write_summary

__all__ = ["run_benchmark", "run_global_fixes", "replay_task", "finish_replay", "global_fix_task", "finish_global_fixes",
           "tqdm_write"]

LOG = logging.getLogger("rls_bench")


def _plan(
    references: Sequence[BagReference], specs: Sequence[LocalizerSpec], *, honour_skips: bool, mode: str
) -> Iterator[tuple[BagReference, LocalizerSpec, str | None]]:
    """Yield ``(reference, spec for that bag, skip_reason or None)`` for every pair."""
    for reference in references:
        for spec in specs:
            reason = spec.skip_reason(reference.name, mode) if honour_skips else None
            if spec.uses_camera and not reference.has_camera:
                yield reference, spec, f"no {IMAGE_TOPIC} in the bag"
            elif not spec.uses_camera and not reference.has_scan:
                yield reference, spec, f"no {SCAN_TOPIC} in the bag"
            elif reason:
                yield reference, spec, reason
            else:
                yield reference, spec.for_bag(reference.name, reference.odometry_noise, reference.laser_mounts), None


def replay_task(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    *,
    mode: str,
    isolate: bool,
    max_seconds: float | None,
    progress: bool,
    record_dir: Path | None = None,
) -> Task:
    """The run of one bag through one localizer, as a task for an executor (``executor.py``); with ``record_dir``
    the run is also recorded there as one MCAP (``replay.py``)."""
    kwargs = {"mode": mode, "max_seconds": max_seconds, "sample_rss": not isolate, "progress": progress,
              "record_dir": record_dir}
    return Task(f"{reference.name}/{spec.name}", replay_localizer, (reference, spec, grid_map), kwargs,
                bag=reference.path)


def finish_replay(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    map_source: str,
    status: str,
    result: Any,
    seconds: float,
    *,
    mode: str,
    coverage: CoverageCache,
    plot_dir: Path | None = None,
    plot_name: str | None = None,
    tum_dir: Path | None = None,
    say: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any], OutputScores | None]:
    """A finished run's ``summary.json`` fields and per-output scores, its plots and TUM files.

    ``status``/``result`` as :func:`.isolation.call_guarded` returns them; ``seconds``: the
    run's wall time. A failed run gives ``{"mode", "error"}`` and no scores. ``say``: where the
    one-line result goes (default: stderr).
    """
    if status != "ok":
        LOG.error("[%s/%s] failed: %s", reference.name, spec.name, result)
        return {"mode": mode, "error": str(result).splitlines()[0], **_sweep_fields(spec)}, None
    fields, series = summarize_run(result, reference)
    scan_coverage = None if spec.uses_camera else coverage.get(reference, grid_map, map_source, spec.mount)
    scores = replay_scores(result, series, scan_coverage)
    if scores is not None and scan_coverage is not None:
        fields.update(run_coverage_fields(scores))
    fields["map"] = map_source
    fields.update(_spec_fields(spec))
    fields["wall_s"] = round(seconds, 1)
    line = f"rls_bench: {reference.name} / {spec.name}: {one_line(fields)}"
    (say or functools.partial(print, file=sys.stderr, flush=True))(line)
    if plot_dir is not None:
        from .plots import plot_run  # matplotlib only when plots are asked for

        plot_run(plot_dir, plot_name or spec.name, grid_map, reference, result, series)
    if tum_dir is not None:
        from .trajectories import export_run

        fields.update(export_run(tum_dir, reference, result, series, name=plot_name or spec.name))
    return fields, scores


def _sweep_fields(spec: LocalizerSpec) -> dict[str, Any]:
    return {"sweep": dict(spec.sweep)} if spec.sweep else {}


def _spec_fields(spec: LocalizerSpec) -> dict[str, Any]:
    """What a run reports of its spec: the params file, the declared odometry noise it took, the sweep point."""
    fields: dict[str, Any] = {} if spec.params is None else {"params": spec.params}
    if spec.odometry_noise:
        fields["odometry_noise"] = "declared by the bag: " + ", ".join(f"{p}={v:g}" for p, v in spec.odometry_noise.items())
    if spec.mount_from_bag:
        m = spec.mount
        fields["laser_mount"] = (f"the bag's /tf_static: ({m.x:g} m, {m.y:g} m, {m.yaw:g} rad"
                                 f"{', upside down' if m.upside_down else ''})")
    return {**fields, **_sweep_fields(spec)}


def global_fix_task(reference: BagReference, spec: LocalizerSpec, grid_map: GridMap | None, *, every: int,
                    isolate: bool, max_seconds: float | None) -> Task:
    """The global fixes of one localizer on one bag, as a task for an executor."""
    kwargs = {"every": every, "max_seconds": max_seconds, "sample_rss": not isolate}
    return Task(f"{reference.name}/{spec.name}/global_fixes", global_fix_localizer, (reference, spec, grid_map),
                kwargs, bag=reference.path)


def finish_global_fixes(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    map_source: str,
    status: str,
    result: Any,
    *,
    every: int,
    coverage: CoverageCache,
    say: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any] | None, OutputScores | None]:
    """Fields and per-fix scores of finished global fixes (``status``/``result`` of the task).

    Fields None: the localizer has no ``global_fix``. A failed run gives ``{"mode", "error"}``.
    """
    if status != "ok":
        return {"mode": "global_fixes", "error": str(result).splitlines()[0]}, None
    if not result.supported:
        return None, None
    if result.error:
        return {"mode": "global_fixes", "error": result.error}, None
    fields = summarize_global_fixes(result, reference, every=every, map_source=map_source)
    fields.update(_spec_fields(spec))
    scan_coverage = coverage.get(reference, grid_map, map_source, spec.mount)
    scores = global_fix_scores(result, scan_coverage)
    if scan_coverage is not None:
        fields.update(run_coverage_fields(scores))
    (say or functools.partial(print, file=sys.stderr, flush=True))(
        f"rls_bench: {reference.name} / {spec.name}: global_correct_rate {fields['global_correct_rate']}, "
        f"fix {fields['fix_ms_median']} ms")
    return fields, scores


def run_benchmark(
    bags: Sequence[str | os.PathLike[str]],
    specs: Sequence[LocalizerSpec],
    out_dir: str | os.PathLike[str],
    *,
    mode: str = "global",
    map_yaml: str | os.PathLike[str] | None = None,
    isolate: bool = True,
    max_seconds: float | None = None,
    plots: bool = True,
    honour_skips: bool = False,
    progress: bool = False,
    child_progress: bool = False,
    executor: Executor | None = None,
    export_tum: str | os.PathLike[str] | None = None,
    record: str | os.PathLike[str] | None = None,
    remap: Mapping[str, str] | None = None,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Replay every bag through every localizer; write ``summary.json``, ``summary.md`` and plots.

    ``executor``: where the runs happen (``executor.py``; default: one after another, each in
    a child process unless not ``isolate``, with ``max_seconds`` and ``child_progress``);
    ``progress``: a replay progress bar per run when they run one after another;
    ``child_progress``: the localizers' own precomputation bars in child runs (off:
    ``TQDM_DISABLE=1`` for the child). Specs that carry ``sweep`` values add the sweep
    table and plots (``sweeps.py``). ``export_tum``: each run's estimates and the ground
    truth in TUM format there (``trajectories.py``). ``record``: each run as one MCAP that Foxglove opens,
    ``<record>/<bag>_<localizer>_<mode>/`` (``replay.py``; on a cluster, on the worker's file system).
    ``remap``: bag topic -> the benchmark's name for it, in every bag (``load_reference``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if executor is None:
        executor = SequentialExecutor(isolate, max_seconds, child_progress)
    references = [load_reference(b, remap) for b in bags]
    summary: dict[str, dict[str, dict[str, Any]]] = {r.name: {} for r in references}
    maps: dict[str, tuple[GridMap | None, str]] = {}
    for reference in references:
        maps[reference.name] = resolve_map(reference, map_yaml)
        if reference.ground_truth is None:
            what = (f"has no {TRUTH_TOPIC}" if not reference.truth_messages else
                    f"has no finite pose among its {reference.truth_messages} {TRUTH_TOPIC} messages")
            LOG.warning("bag %s %s: reporting timing only", reference.name, what)
            print(f"rls_bench: bag {reference.name} {what}; reporting timing only", file=sys.stderr)
    planned: list[tuple[BagReference, LocalizerSpec]] = []
    for reference, spec, skip in _plan(references, specs, honour_skips=honour_skips, mode=mode):
        if skip is not None:
            summary[reference.name][spec.name] = {"mode": mode, "skipped": skip}
            continue
        grid_map, map_source = maps[reference.name]
        if grid_map is None and not spec.uses_camera:
            refused = f" (its /map was refused: {reference.map_refused})" if reference.map_refused else ""
            error = (f"no map{refused}: give --map, a /map in the bag, "
                     f"or one of {', '.join(str(p) for p in map_candidates(reference.name))}")
            print(f"rls_bench: bag {reference.name}, {spec.name}: {error}", file=sys.stderr)
            summary[reference.name][spec.name] = {"mode": mode, "error": error}
            continue
        summary[reference.name][spec.name] = {}  # the table keeps the planned order, whatever finishes first
        planned.append((reference, spec))
    tasks = [replay_task(reference, spec, maps[reference.name][0], mode=mode, isolate=executor.isolate,
                         max_seconds=max_seconds, progress=progress and not executor.parallel,
                         record_dir=None if record is None else Path(record).resolve())
             for reference, spec in planned]
    coverage = CoverageCache()
    say = tqdm_write if executor.parallel else None
    outcomes = executor.run(tasks)
    samples: dict[str, dict[str, metrics.RmseSample]] = {reference.name: {} for reference in references}
    for position in range(len(planned)):
        if not executor.parallel:  # lazily, one at a time: announce the run about to start
            print(f"rls_bench: {planned[position][0].name} / {planned[position][1].name} ({mode}) ...",
                  file=sys.stderr, flush=True)
        index, status, result, seconds = next(outcomes)
        reference, spec = planned[index]
        grid_map, map_source = maps[reference.name]
        summary[reference.name][spec.name], scores = finish_replay(
            reference, spec, grid_map, map_source, status, result, seconds, mode=mode, coverage=coverage,
            plot_dir=out / "plots" / reference.name if plots else None,
            tum_dir=Path(export_tum) / mode / reference.name if export_tum is not None else None, say=say)
        if scores is not None and scores.rmse is not None:
            samples[reference.name][spec.name] = scores.rmse
    for bag, runs in samples.items():  # every run of a bag over the same outputs (docs/benchmark.md)
        for name, shared in metrics.shared_rmse(runs).items():
            summary[bag][name].update(shared)
    write_summary(out, summary, title=f"rls_bench ({mode} mode)")
    if any(spec.sweep for spec in specs):
        from .sweeps import write_sweep

        write_sweep(out, summary, mode=mode, plots=plots)
    return summary


def tqdm_write(line: str) -> None:
    """A run's one-line result above the Dask progress bar."""
    from tqdm import tqdm

    tqdm.write(line, file=sys.stderr)


def run_global_fixes(
    bags: Sequence[str | os.PathLike[str]],
    specs: Sequence[LocalizerSpec],
    out_dir: str | os.PathLike[str],
    *,
    every: int = 10,
    map_yaml: str | os.PathLike[str] | None = None,
    isolate: bool = True,
    max_seconds: float | None = None,
    honour_skips: bool = False,
    child_progress: bool = False,
    executor: Executor | None = None,
    remap: Mapping[str, str] | None = None,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Single-scan global fixes of every localizer that offers ``global_fix``; write the summary.

    ``executor``, ``child_progress``, ``remap``: as in :func:`run_benchmark`.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if executor is None:
        executor = SequentialExecutor(isolate, max_seconds, child_progress)
    references = [load_reference(b, remap) for b in bags]
    summary: dict[str, dict[str, dict[str, Any]]] = {r.name: {} for r in references}
    planned: list[tuple[BagReference, LocalizerSpec, GridMap | None, str]] = []
    for reference, spec, skip in _plan(references, specs, honour_skips=honour_skips, mode="global_fixes"):
        if skip is not None or spec.uses_camera:
            continue
        planned.append((reference, spec, *resolve_map(reference, map_yaml)))
        summary[reference.name][spec.name] = {}  # the planned order, whatever finishes first
    tasks = [global_fix_task(reference, spec, grid_map, every=every, isolate=executor.isolate,
                             max_seconds=max_seconds) for reference, spec, grid_map, _ in planned]
    coverage = CoverageCache()
    outcomes = executor.run(tasks)
    for position in range(len(planned)):
        if not executor.parallel:
            print(f"rls_bench: {planned[position][0].name} / {planned[position][1].name} (global fixes, every "
                  f"{every}) ...", file=sys.stderr, flush=True)
        index, status, result, _ = next(outcomes)
        reference, spec, grid_map, map_source = planned[index]
        fields, _ = finish_global_fixes(reference, spec, grid_map, map_source, status, result, every=every,
                                        coverage=coverage, say=tqdm_write if executor.parallel else None)
        if fields is None:
            del summary[reference.name][spec.name]  # no global_fix: no row
        else:
            summary[reference.name][spec.name] = fields
    write_summary(out, summary, title=f"rls_bench --global-fixes (every {every}th scan)")
    return summary
