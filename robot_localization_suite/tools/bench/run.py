"""The benchmark over bags x localizers: plan the pairs, run each, summarize, write the files.

:func:`run_benchmark` replays every bag through every localizer (``summary.json``,
``summary.md``, plots); :func:`run_global_fixes` asks for single-scan global fixes
instead. Each pair runs in a child process unless ``isolate`` is false.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ...core.grid_map import GridMap
from .coverage import CoverageCache, OutputScores, global_fix_scores, replay_scores, run_coverage_fields
from .global_fixes import global_fix_localizer
from .isolation import call_guarded
from .reference import IMAGE_TOPIC, SCAN_TOPIC, TRUTH_TOPIC, BagReference, load_reference, map_candidates, resolve_map
from .replay import replay_localizer
from .specs import LocalizerSpec
from .summary import summarize_global_fixes, summarize_run
from .tables import one_line, write_summary

__all__ = ["run_benchmark", "run_global_fixes", "replay_pair", "global_fix_pair"]

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
                yield reference, spec.for_bag(reference.name), None


def replay_pair(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    map_source: str,
    *,
    mode: str,
    isolate: bool,
    max_seconds: float | None,
    progress: bool,
    child_progress: bool,
    coverage: CoverageCache,
    plot_dir: Path | None = None,
    plot_name: str | None = None,
) -> tuple[dict[str, Any], OutputScores | None]:
    """One replay (child process unless not ``isolate``): its ``summary.json`` fields and per-output scores.

    The coverage fields come from ``coverage`` (computed once per bag and map). A failed run
    gives ``{"mode", "error"}`` and no scores. ``plot_dir``: write the plots there, named
    ``plot_name`` (default: the localizer's name).
    """
    print(f"rls_bench: {reference.name} / {spec.name} ({mode}) ...", file=sys.stderr, flush=True)
    kwargs = {"mode": mode, "max_seconds": max_seconds, "sample_rss": not isolate, "progress": progress}
    started = time.perf_counter()
    status, result = call_guarded(replay_localizer, (reference, spec, grid_map), kwargs, isolate=isolate,
                                  max_seconds=max_seconds, child_progress=child_progress)
    if status != "ok":
        LOG.error("[%s/%s] failed: %s", reference.name, spec.name, result)
        return {"mode": mode, "error": str(result).splitlines()[0]}, None
    fields, series = summarize_run(result, reference)
    scan_coverage = None if spec.uses_camera else coverage.get(reference, grid_map, map_source, spec.mount)
    scores = replay_scores(result, series, scan_coverage)
    if scores is not None and scan_coverage is not None:
        fields.update(run_coverage_fields(scores))
    fields["map"] = map_source
    if spec.params is not None:
        fields["params"] = spec.params
    fields["wall_s"] = round(time.perf_counter() - started, 1)
    print(f"rls_bench: {reference.name} / {spec.name}: {one_line(fields)}", file=sys.stderr, flush=True)
    if plot_dir is not None:
        from .plots import plot_run  # matplotlib only when plots are asked for

        plot_run(plot_dir, plot_name or spec.name, grid_map, reference, result, series)
    return fields, scores


def global_fix_pair(
    reference: BagReference,
    spec: LocalizerSpec,
    grid_map: GridMap | None,
    map_source: str,
    *,
    every: int,
    isolate: bool,
    max_seconds: float | None,
    child_progress: bool,
    coverage: CoverageCache,
) -> tuple[dict[str, Any] | None, OutputScores | None]:
    """Single-scan global fixes of one localizer on one bag: fields and per-fix scores.

    Fields None: the localizer has no ``global_fix``. A failed run gives ``{"mode", "error"}``.
    """
    print(f"rls_bench: {reference.name} / {spec.name} (global fixes, every {every}) ...", file=sys.stderr,
          flush=True)
    kwargs = {"every": every, "max_seconds": max_seconds, "sample_rss": not isolate}
    status, result = call_guarded(global_fix_localizer, (reference, spec, grid_map), kwargs, isolate=isolate,
                                  max_seconds=max_seconds, child_progress=child_progress)
    if status != "ok":
        return {"mode": "global_fixes", "error": str(result).splitlines()[0]}, None
    if not result.supported:
        return None, None
    if result.error:
        return {"mode": "global_fixes", "error": result.error}, None
    fields = summarize_global_fixes(result, reference, every=every, map_source=map_source)
    if spec.params is not None:
        fields["params"] = spec.params
    scan_coverage = coverage.get(reference, grid_map, map_source, spec.mount)
    scores = global_fix_scores(result, scan_coverage)
    if scan_coverage is not None:
        fields.update(run_coverage_fields(scores))
    print(f"rls_bench: {reference.name} / {spec.name}: global_correct_rate {fields['global_correct_rate']}, "
          f"fix {fields['fix_ms_median']} ms", file=sys.stderr, flush=True)
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
) -> dict[str, dict[str, dict[str, Any]]]:
    """Replay every bag through every localizer; write ``summary.json``, ``summary.md`` and plots.

    ``progress``: a replay progress bar per run; ``child_progress``: the localizers'
    own precomputation bars in child runs (off: ``TQDM_DISABLE=1`` for the child).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    references = [load_reference(b) for b in bags]
    summary: dict[str, dict[str, dict[str, Any]]] = {r.name: {} for r in references}
    maps: dict[str, tuple[GridMap | None, str]] = {}
    for reference in references:
        maps[reference.name] = resolve_map(reference, map_yaml)
        if reference.ground_truth is None:
            LOG.warning("bag %s has no %s: reporting timing only", reference.name, TRUTH_TOPIC)
            print(f"rls_bench: bag {reference.name} has no {TRUTH_TOPIC}; reporting timing only", file=sys.stderr)
    coverage = CoverageCache()
    for reference, spec, skip in _plan(references, specs, honour_skips=honour_skips, mode=mode):
        if skip is not None:
            summary[reference.name][spec.name] = {"mode": mode, "skipped": skip}
            continue
        grid_map, map_source = maps[reference.name]
        if grid_map is None and not spec.uses_camera:
            summary[reference.name][spec.name] = {"mode": mode, "error": "no map: give --map, a /map in the bag, "
                                                  f"or one of {', '.join(str(p) for p in map_candidates(reference.name))}"}
            continue
        summary[reference.name][spec.name], _ = replay_pair(
            reference, spec, grid_map, map_source, mode=mode, isolate=isolate, max_seconds=max_seconds,
            progress=progress, child_progress=child_progress, coverage=coverage,
            plot_dir=out / "plots" / reference.name if plots else None)
    write_summary(out, summary, title=f"rls_bench ({mode} mode)")
    return summary


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
) -> dict[str, dict[str, dict[str, Any]]]:
    """Single-scan global fixes of every localizer that offers ``global_fix``; write the summary.

    ``child_progress``: as in :func:`run_benchmark`.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    references = [load_reference(b) for b in bags]
    summary: dict[str, dict[str, dict[str, Any]]] = {r.name: {} for r in references}
    coverage = CoverageCache()
    for reference, spec, skip in _plan(references, specs, honour_skips=honour_skips, mode="global_fixes"):
        if skip is not None or spec.uses_camera:
            continue
        grid_map, map_source = resolve_map(reference, map_yaml)
        fields, _ = global_fix_pair(reference, spec, grid_map, map_source, every=every, isolate=isolate,
                                    max_seconds=max_seconds, child_progress=child_progress, coverage=coverage)
        if fields is not None:
            summary[reference.name][spec.name] = fields
    write_summary(out, summary, title=f"rls_bench --global-fixes (every {every}th scan)")
    return summary
