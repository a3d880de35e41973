"""``rls_bench --cv``: every block of a cross-validation split on its honest map and on the whole-log map.

Each localizer replays each block bag twice, on the map built from the other blocks
(``honest``) and on the whole-log map (``same_map``): the same scans, two maps. Figures come
per block and pooled per log (all the blocks' outputs together). Splits: ``carmen_to_bag
--blocks``; how this run works: ``docs/benchmark.md``, "Cross-validation runs".
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ...core.errors import LocalizationSuiteError
from ...core.grid_map import GridMap, load_map_yaml
from ..carmen_cv import INDEX_FORMAT, MIN_BLOCK_SCANS, STATUS_OK, block_stem
from .coverage import CoverageCache, OutputScores, pooled_fields
from .executor import Executor, SequentialExecutor
from .reference import SCAN_TOPIC, TRUTH_TOPIC, BagReference, load_reference
from .run import finish_global_fixes, finish_replay, global_fix_task, replay_task, tqdm_write
from .specs import LocalizerSpec

__all__ = ["MAP_KINDS", "CvBlockRun", "CvLog", "find_split_indexes", "read_split", "cv_modes", "run_cv"]

MAP_KINDS = ("honest", "same_map")
MODES = ("global", "tracking", "global_fixes")


@dataclass(frozen=True)
class CvBlockRun:
    """A block as the runner sees it: its bag and its two maps, or why it is skipped."""

    log: str
    name: str
    scans: int | None
    bag: Path | None = None
    maps: Mapping[str, Path] = field(default_factory=dict)  # MAP_KINDS -> map YAML
    skipped: str | None = None
    coverage_median: float | None = None
    coverage_median_same_map: float | None = None


@dataclass(frozen=True)
class CvLog:
    """One split: the log's name, its index, the whole-log map, its blocks."""

    name: str
    index: Path
    full_map: Path | None
    blocks: tuple[CvBlockRun, ...]


class CvIndexError(LocalizationSuiteError):
    """A ``--cv`` argument is not a split index, nor a directory holding one."""


def find_split_indexes(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """The index files ``<name>_cv.yaml``: each path an index, or a directory holding indexes."""
    found: list[Path] = []
    for path in map(Path, paths):
        if path.is_dir():
            indexes = sorted(path.glob("*_cv.yaml"))
            if not indexes:
                raise CvIndexError(f"--cv: no split index (*_cv.yaml) in {str(path)!r}; make one with "
                                   "carmen_to_bag LOG DIR --blocks K")
            found += indexes
        elif path.is_file():
            found.append(path)
        else:
            raise CvIndexError(f"--cv: {str(path)!r} does not exist")
    return list(dict.fromkeys(p.resolve() for p in found))


def _existing(base: Path, relative: Any, what: str) -> tuple[Path | None, str | None]:
    if not relative:
        return None, f"the index names no {what}"
    path = (base / str(relative)).resolve()
    return (path, None) if path.exists() else (None, f"{what} {str(path)!r} is missing")


def read_split(index: str | os.PathLike[str]) -> CvLog:
    """Read a split index, tolerantly: a block whose bag or a map is missing, that the split
    skipped or refused, or with fewer than ``MIN_BLOCK_SCANS`` scans, comes back skipped with
    the reason (``carmen_cv.load_cv_index`` would refuse the whole index instead).

    Raises:
        CvIndexError: the file is not a split index.
    """
    path = Path(index).resolve()
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise CvIndexError(f"--cv: cannot read {str(path)!r}: {exc}") from exc
    if not isinstance(document, dict) or document.get("format") != INDEX_FORMAT or "blocks" not in document:
        raise CvIndexError(f"--cv: {str(path)!r} is not a {INDEX_FORMAT!r} split index")
    name = str(document.get("name") or path.name.removesuffix("_cv.yaml"))
    full_map, full_problem = _existing(path.parent, document.get("full_map"), "whole-log map")
    blocks = []
    for number, entry in enumerate(document["blocks"] or [], start=1):
        if not isinstance(entry, dict):
            blocks.append(CvBlockRun(name, f"{name} block {number}", None, skipped="malformed index entry"))
            continue
        stem = Path(str(entry.get("bag") or block_stem(name, entry.get("block", number), document.get("block_count", 0)))).name
        scans = entry.get("scan_count") if isinstance(entry.get("scan_count"), int) else None
        bag, bag_problem = _existing(path.parent, entry.get("bag"), "bag")
        honest, map_problem = _existing(path.parent, entry.get("map"), "map")
        reason: str | None
        if entry.get("status") != STATUS_OK:
            reason = f"{entry.get('status')} by the split: {entry.get('reason') or 'no reason given'}"
        elif scans is not None and scans < MIN_BLOCK_SCANS:
            reason = f"{scans} scans, fewer than {MIN_BLOCK_SCANS}"
        else:
            reason = bag_problem or map_problem or full_problem
        maps = {"honest": honest, "same_map": full_map} if reason is None and honest and full_map else {}
        block = CvBlockRun(name, stem, scans, bag if maps else None, maps, None if maps else reason or "no map",
                           entry.get("coverage_median"), entry.get("coverage_median_same_map"))
        blocks.append(block)
    return CvLog(name, path, full_map, tuple(blocks))


def cv_modes(mode: str, *, with_tracking: bool, with_global_fixes: bool, global_fixes_only: bool) -> list[str]:
    """The modes of a ``--cv`` run, as the normal run's options ask for them."""
    if global_fixes_only:
        return ["global_fixes"]
    modes = [mode]
    if with_tracking and mode == "global":
        modes.append("tracking")
    if with_global_fixes:
        modes.append("global_fixes")
    return modes


def _open_block(block: CvBlockRun, maps_cache: dict[Path, GridMap]) -> tuple[BagReference | None, dict[str, GridMap],
                                                                            str | None]:
    """The block's reference and maps, or the reason it cannot run."""
    if block.skipped is not None or block.bag is None:
        return None, {}, block.skipped or "no bag"
    try:
        reference = load_reference(block.bag)
        for path in block.maps.values():
            if path not in maps_cache:
                maps_cache[path] = load_map_yaml(path)
    except LocalizationSuiteError as exc:
        return None, {}, f"cannot read: {exc}"
    scans = reference.sensor_counts.get(SCAN_TOPIC, 0)
    if scans < MIN_BLOCK_SCANS:
        return None, {}, f"{scans} scans in the bag, fewer than {MIN_BLOCK_SCANS}"
    if reference.ground_truth is None:
        return None, {}, f"no {TRUTH_TOPIC} in the bag"
    return reference, {kind: maps_cache[path] for kind, path in block.maps.items()}, None


def _left_out_reason(entry: Mapping[str, Any]) -> str:
    if "skipped" in entry:
        return f"skipped: {entry['skipped']}"
    for kind in MAP_KINDS:
        if "error" in entry.get(kind, {}):
            return f"{kind}: error"
    return "no outputs to score"


def _pool(logs: Sequence[CvLog], specs: Sequence[LocalizerSpec], runs: Mapping[str, Any],
          scores: Mapping[tuple[str, str, str], OutputScores]) -> dict[str, dict[str, Any]]:
    """Per log and localizer: both maps' pooled fields over the blocks where both runs scored."""
    pooled: dict[str, dict[str, Any]] = {}
    for log in logs:
        pooled[log.name] = {}
        for spec in specs:
            entries = {b.name: runs[b.name][spec.name] for b in log.blocks if spec.name in runs.get(b.name, {})}
            if not entries:
                continue  # e.g. no global_fix
            used = [name for name in entries if all((name, spec.name, kind) in scores for kind in MAP_KINDS)]
            reasons = {name: _left_out_reason(entry) for name, entry in entries.items() if name not in used}
            skipped = {entry.get("skipped") for entry in entries.values()}
            if not used and len(skipped) == 1 and None not in skipped:
                pooled[log.name][spec.name] = {"skipped": skipped.pop()}  # e.g. the localizer's bench_skip
                continue
            fields: dict[str, Any] = {"blocks": len(used), "left_out": reasons}
            for kind in MAP_KINDS:
                fields[kind] = pooled_fields([scores[(name, spec.name, kind)] for name in used])
            fields["truncated_runs"] = sum(bool(entries[name][kind].get("truncated"))
                                           for name in used for kind in MAP_KINDS)
            pooled[log.name][spec.name] = fields
    return pooled


def run_cv(
    indexes: Sequence[str | os.PathLike[str]],
    specs: Sequence[LocalizerSpec],
    out_dir: str | os.PathLike[str],
    *,
    modes: Sequence[str] = ("global",),
    every: int = 10,
    isolate: bool = True,
    max_seconds: float | None = None,
    plots: bool = True,
    honour_skips: bool = True,
    progress: bool = False,
    child_progress: bool = False,
    executor: Executor | None = None,
) -> dict[str, Any]:
    """Run every laser localizer over every block of the splits, honest map and whole-log map, in ``modes``.

    ``indexes``: split index files or directories holding them (:func:`find_split_indexes`).

    Writes ``summary.json``, ``summary.md`` and the plots (``plots/<mode>/<block>/<localizer>_<map>_*.png``)
    into ``out_dir`` and returns the summary: ``splits`` (the blocks read), and per mode
    ``pooled`` (log -> localizer -> ``honest`` / ``same_map`` fields) and ``blocks``
    (block -> localizer -> ``honest`` / ``same_map`` run fields). Skipped blocks and failed runs
    are entries with their reason; the other blocks go on. ``executor``: where the runs happen
    (default: one after another, as :func:`.run.run_benchmark`).
    """
    from .cv_tables import write_cv_summary

    unknown = [m for m in modes if m not in MODES]
    if unknown:
        raise ValueError(f"--cv modes must be among {', '.join(MODES)}, got {', '.join(unknown)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    logs = [read_split(i) for i in find_split_indexes(indexes)]
    specs = [s for s in specs if not s.uses_camera]  # the splits hold no camera images
    if not specs:
        raise ValueError("--cv: no laser localizer selected (the splits hold scans, no images)")
    summary: dict[str, Any] = {"splits": {}, "modes": list(modes), "every": every}
    runs: dict[str, dict[str, dict[str, Any]]] = {mode: {} for mode in modes}
    scores: dict[str, dict[tuple[str, str, str], OutputScores]] = {mode: {} for mode in modes}
    coverage = CoverageCache()
    maps_cache: dict[Path, GridMap] = {}
    # Every run is planned first, then handed to the executor as one list, then scored as it comes back.
    planned: list[tuple[str, str, LocalizerSpec, str, BagReference, GridMap, str]] = []
    for log in logs:
        summary["splits"][log.name] = {"index": str(log.index), "full_map": str(log.full_map), "blocks": {}}
        for block in log.blocks:
            reference, maps, reason = _open_block(block, maps_cache)
            summary["splits"][log.name]["blocks"][block.name] = {
                "scans": block.scans, "coverage_median": block.coverage_median,
                "coverage_median_same_map": block.coverage_median_same_map,
                **({"skipped": reason} if reason else {})}
            if reason is not None:
                print(f"rls_bench: --cv {block.name}: skipped: {reason}", file=sys.stderr, flush=True)
            for mode in modes:
                entries = runs[mode].setdefault(block.name, {})
                for spec in specs:
                    skip = reason or (spec.skip_reason(block.name, mode) if honour_skips else None)
                    if skip is not None or reference is None:
                        entries[spec.name] = {"skipped": skip}
                        continue
                    entries[spec.name] = {}  # the planned order; dropped if it stays empty (no global_fix)
                    run_spec = spec.for_bag(block.name, reference.odometry_noise, reference.laser_mounts)
                    planned += [(mode, block.name, run_spec, kind, reference, maps[kind], str(block.maps[kind]))
                                for kind in MAP_KINDS]
    if executor is None:
        executor = SequentialExecutor(isolate, max_seconds, child_progress)
    tasks = [global_fix_task(reference, run_spec, grid_map, every=every, isolate=executor.isolate,
                             max_seconds=max_seconds) if mode == "global_fixes"
             else replay_task(reference, run_spec, grid_map, mode=mode, isolate=executor.isolate,
                              max_seconds=max_seconds, progress=progress and not executor.parallel)
             for mode, _, run_spec, _, reference, grid_map, _ in planned]
    say = tqdm_write if executor.parallel else None
    outcomes = executor.run(tasks)
    for position in range(len(planned)):
        mode, block_name, run_spec, kind, reference, grid_map, source = planned[position]
        if not executor.parallel:
            print(f"rls_bench: {block_name} / {run_spec.name} ({mode}, {kind}) ...", file=sys.stderr, flush=True)
        index, status, result, seconds = next(outcomes)
        mode, block_name, run_spec, kind, reference, grid_map, source = planned[index]
        fields: dict[str, Any] | None
        if mode == "global_fixes":
            fields, scored = finish_global_fixes(reference, run_spec, grid_map, source, status, result, every=every,
                                                 coverage=coverage, say=say)
        else:
            fields, scored = finish_replay(
                reference, run_spec, grid_map, source, status, result, seconds, mode=mode, coverage=coverage,
                plot_dir=out / "plots" / mode / block_name if plots else None, plot_name=f"{run_spec.name}_{kind}",
                say=say)
        if fields is not None:
            runs[mode][block_name][run_spec.name][kind] = fields
        if scored is not None:
            scores[mode][(block_name, run_spec.name, kind)] = scored
    for mode in modes:
        for entries in runs[mode].values():
            for name in [name for name, entry in entries.items() if not entry]:
                del entries[name]  # a localizer without global_fix: no entry, as before
    for mode in modes:
        summary[mode] = {"pooled": _pool(logs, specs, runs[mode], scores[mode]), "blocks": runs[mode]}
    write_cv_summary(out, summary)
    return summary
