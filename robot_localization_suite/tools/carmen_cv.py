"""Cross-validation splits of a CARMEN log: K time blocks, each a bag with a map built from the other K - 1.

    carmen_to_bag LOG OUT_DIR --blocks K [--name NAME]

Layout of OUT_DIR, the choices and the measured coverage: docs/benchmark.md
("Honest maps: cross-validation splits"). ``load_cv_index`` reads a split back.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from ..core import metrics
from ..core.edt import distance_to_marked
from ..core.grid_map import GridMap
from .carmen_log import CarmenLogError, _report_to_stderr
from .carmen_to_bag import (
    ConversionSettings,
    PreparedLog,
    _clear,
    _report_warning_to_stderr,
    build_log_map,
    prepare_log,
    write_bag,
)

__all__ = [
    "MIN_BLOCK_SCANS",
    "NEAR_PATH_M",
    "CrossValidationError",
    "CvBlock",
    "CvSplit",
    "default_name",
    "block_ranges",
    "block_stem",
    "check_block_map",
    "split_log",
    "load_cv_index",
]

MIN_BLOCK_SCANS = 20  # a shorter block is skipped: too few outputs to rate a localizer on
NEAR_PATH_M = 1.0  # a block's map must have a free cell within this of at least one of its true poses [m]
INDEX_FORMAT = "rls-carmen-cv/1"
MAP_IMAGE_FORMAT = "png"
STATUS_OK, STATUS_SKIPPED, STATUS_REFUSED = "ok", "skipped", "refused"


class CrossValidationError(CarmenLogError):
    """A block of a split cannot be used: its map has no free cell, or none near the block's path."""


@dataclass(frozen=True)
class CvBlock:
    """One block of a split and what became of it.

    Attributes:
        block, blocks: ``k`` of ``K`` (1-based).
        scan_range: ``[first, last + 1)``, indices into the log's front-laser scans.
        time_range: stamps [s] of its first and last scan.
        status: ``ok`` (bag and map written), ``skipped`` (too short) or ``refused`` (unusable map).
        reason: why it was skipped or refused ("" when ok).
        bag, map_yaml: absolute paths (None unless ok); the bag's ``/map`` is the map at ``map_yaml``.
        map_cells: ``(width, height)`` of its map.
        path_near_free: share of its true poses with a free map cell within ``NEAR_PATH_M``.
        coverage_median, coverage_median_same_map: median ``metrics.map_coverage`` of its scans on
            its own map and on the whole-log map.
    """

    block: int
    blocks: int
    scan_range: tuple[int, int]
    time_range: tuple[float, float]
    status: str
    reason: str = ""
    bag: Path | None = None
    map_yaml: Path | None = None
    map_cells: tuple[int, int] | None = None
    path_near_free: float | None = None
    coverage_median: float | None = None
    coverage_median_same_map: float | None = None

    @property
    def scan_count(self) -> int:
        return self.scan_range[1] - self.scan_range[0]

    @property
    def label(self) -> str:
        first, stop = self.scan_range
        return f"block {self.block} of {self.blocks} ({f'scans {first}-{stop - 1}' if stop > first else 'no scan'})"


@dataclass(frozen=True)
class CvSplit:
    """A written split: its blocks, the whole-log map and the index file (absolute paths)."""

    name: str
    log: Path
    index: Path
    full_map_yaml: Path
    scans: int
    stamp_source: str
    blocks: tuple[CvBlock, ...]
    settings: dict[str, Any]
    wall_s: float = 0.0

    def written(self) -> list[CvBlock]:
        """The blocks with a bag and a map."""
        return [b for b in self.blocks if b.status == STATUS_OK]

    def summary(self) -> str:
        lines = [f"{self.name}: {self.scans} scans in {len(self.blocks)} blocks, stamps: {self.stamp_source}, "
                 f"{self.wall_s:.1f} s",
                 "block  scans  time [s]           map cells    coverage median (own map / whole-log map)"]
        for b in self.blocks:
            if b.status != STATUS_OK:
                lines.append(f"{b.block:>5}  {b.scan_count:>5}  {b.status}: {b.reason}")
                continue
            cells = f"{b.map_cells[0]} x {b.map_cells[1]}" if b.map_cells else "-"
            lines.append(f"{b.block:>5}  {b.scan_count:>5}  {b.time_range[0]:>8.1f}-{b.time_range[1]:<8.1f}  "
                         f"{cells:<11}  {_fmt(b.coverage_median)} / {_fmt(b.coverage_median_same_map)}")
        lines.append(f"index {self.index}")
        return "\n".join(lines)


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def default_name(log_path: str | os.PathLike[str]) -> str:
    """``intel-corrected.log.gz`` -> ``intel``: the file name without ``.gz``, ``.log`` and ``-corrected``."""
    name = Path(log_path).name
    for suffix in (".gz", ".log", "-corrected"):
        name = name.removesuffix(suffix)
    return name


def block_ranges(count: int, blocks: int) -> list[range]:
    """``blocks`` contiguous scan-index ranges covering ``count`` scans; the first ``count % blocks`` one longer."""
    if blocks < 2:
        raise ValueError(f"a cross-validation split needs at least 2 blocks, got {blocks!r}")
    bounds = np.cumsum([0] + [count // blocks + (1 if k < count % blocks else 0) for k in range(blocks)])
    return [range(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def block_stem(name: str, block: int, blocks: int) -> str:
    """File stem of block ``block`` of ``blocks``: ``<name>_cv<k>of<K>``."""
    return f"{name}_cv{block}of{blocks}"


def check_block_map(grid_map: GridMap, poses: NDArray[np.float64], label: str) -> float:
    """Share of ``poses`` with a free cell within ``NEAR_PATH_M``; raises if the map is of no use to them.

    Raises:
        CrossValidationError: the map has no free cell, or none within ``NEAR_PATH_M`` of any pose.
    """
    free = grid_map.free_mask
    if not free.any():
        raise CrossValidationError(f"{label}: its map (from the other blocks) has no free cell")
    distance = distance_to_marked(free)
    cells = grid_map.world_to_cell(np.asarray(poses)[:, :2])
    inside = grid_map.in_bounds(cells)
    near = np.zeros(inside.shape, dtype=bool)
    near[inside] = distance[cells[inside, 1], cells[inside, 0]] * grid_map.resolution <= NEAR_PATH_M
    if not near.any():
        raise CrossValidationError(
            f"{label}: its map (from the other blocks) has no free cell within {NEAR_PATH_M:g} m of any of its "
            f"{len(near)} true poses: the other blocks never saw where it drives"
        )
    return float(near.mean())


def _scan_coverage(prepared: PreparedLog, scans: range, grid_map: GridMap) -> NDArray[np.float64]:
    """``metrics.map_coverage`` of the scans ``scans`` at their true poses (raw readings, NaN-padded)."""
    beams = max(prepared.scans[i].ranges.size for i in scans)
    ranges = np.full((len(scans), beams), np.nan)
    angles = np.zeros((len(scans), beams))
    for row, i in enumerate(scans):
        size = prepared.scans[i].ranges.size
        ranges[row, :size] = prepared.scans[i].ranges
        angles[row, :size] = prepared.angles(i)
    return metrics.map_coverage(grid_map, prepared.poses[scans.start : scans.stop], angles, ranges,
                                range_max=prepared.max_range)


def _median(values: NDArray[np.float64]) -> float | None:
    finite = values[np.isfinite(values)]
    return round(float(np.median(finite)), 4) if finite.size else None


def _outputs(out_dir: Path, name: str, blocks: int) -> list[Path]:
    stems = [f"{name}_full"] + [block_stem(name, k, blocks) for k in range(1, blocks + 1)]
    paths = [out_dir / f"{name}_cv.yaml"]
    for stem in stems:
        paths += [out_dir / f"{stem}.yaml", out_dir / f"{stem}.{MAP_IMAGE_FORMAT}"]
        if stem != f"{name}_full":
            paths.append(out_dir / stem)
    return paths


def _report_block_problem(message: str) -> None:
    print(f"carmen_to_bag: {message}", file=sys.stderr)


def split_log(
    log_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    blocks: int,
    *,
    name: str | None = None,
    settings: ConversionSettings | None = None,
    overwrite: bool = False,
    on_skip: Callable[[int, str], None] | None = _report_to_stderr,
    on_warning: Callable[[str], None] | None = _report_warning_to_stderr,
    on_problem: Callable[[str], None] | None = _report_block_problem,
) -> CvSplit:
    """Cut a log into ``blocks`` time blocks; write each block's bag and the map of the other blocks.

    A block shorter than ``MIN_BLOCK_SCANS`` is skipped, a block whose map fails
    :func:`check_block_map` refused; both are reported through ``on_problem`` and recorded in
    the index, and the other blocks go on. Block bags are zstd-compressed MCAP.

    Raises:
        CarmenLogError: the log cannot be read, or an output exists and ``overwrite`` is false.
        ValueError: fewer than 2 blocks, or a name that is not a plain file name.
    """
    started = time.perf_counter()
    settings = settings or ConversionSettings()
    name = name or default_name(log_path)
    if not name or Path(name).name != name:
        raise ValueError(f"--name must be a plain file name, got {name!r}")
    if blocks < 2:
        raise ValueError(f"a cross-validation split needs at least 2 blocks, got {blocks!r}")
    out_dir = Path(out_dir)
    if not overwrite:
        existing = [p for p in _outputs(out_dir, name, blocks) if p.exists()]
        if existing:
            raise CarmenLogError(f"output {str(existing[0])!r} exists (use --overwrite)")
    prepared = prepare_log(log_path, settings, on_skip=on_skip, on_warning=on_warning)
    count = len(prepared.scans)
    full_map = build_log_map(prepared, settings)
    out_dir.mkdir(parents=True, exist_ok=True)
    full_yaml = out_dir / f"{name}_full.yaml"
    _clear(full_yaml, overwrite=True)
    full_map.save(full_yaml, image_format=MAP_IMAGE_FORMAT)

    results = []
    for k, scans in enumerate(block_ranges(count, blocks), start=1):
        times = (float(prepared.stamps[scans.start]), float(prepared.stamps[scans.stop - 1])) if scans else (0.0, 0.0)
        block = CvBlock(k, blocks, (scans.start, scans.stop), times, STATUS_SKIPPED)
        if len(scans) < MIN_BLOCK_SCANS:
            reason = f"{len(scans)} scans, fewer than {MIN_BLOCK_SCANS}: skipped, nothing written"
            results.append(replace(block, reason=reason))
            if on_problem is not None:
                on_problem(f"{block.label}: {reason}")
            continue
        others = np.r_[0 : scans.start, scans.stop : count]
        grid_map = build_log_map(prepared, settings, others.tolist())
        try:
            near = check_block_map(grid_map, prepared.poses[scans.start : scans.stop], block.label)
        except CrossValidationError as exc:
            results.append(replace(block, status=STATUS_REFUSED, reason=str(exc).removeprefix(f"{block.label}: ")))
            if on_problem is not None:
                on_problem(f"{exc}; refused, nothing written")
            continue
        stem = block_stem(name, k, blocks)
        for path in (out_dir / stem, out_dir / f"{stem}.yaml", out_dir / f"{stem}.{MAP_IMAGE_FORMAT}"):
            _clear(path, overwrite=True)
        write_bag(out_dir / stem, prepared, grid_map, scans=scans, compress=True)
        map_yaml = grid_map.save(out_dir / f"{stem}.yaml", image_format=MAP_IMAGE_FORMAT)
        results.append(replace(
            block,
            status=STATUS_OK,
            bag=(out_dir / stem).resolve(),
            map_yaml=map_yaml.resolve(),
            map_cells=(grid_map.width, grid_map.height),
            path_near_free=round(near, 4),
            coverage_median=_median(_scan_coverage(prepared, scans, grid_map)),
            coverage_median_same_map=_median(_scan_coverage(prepared, scans, full_map)),
        ))

    split = CvSplit(
        name=name,
        log=Path(log_path).resolve(),
        index=(out_dir / f"{name}_cv.yaml").resolve(),
        full_map_yaml=full_yaml.resolve(),
        scans=count,
        stamp_source=prepared.stamp_source,
        blocks=tuple(results),
        settings=_settings_fields(settings, prepared),
        wall_s=round(time.perf_counter() - started, 2),
    )
    _write_index(split)
    return split


def _settings_fields(settings: ConversionSettings, prepared: PreparedLog) -> dict[str, Any]:
    return {
        "seed": settings.seed,
        "alphas": list(settings.alphas),
        "resolution": settings.resolution,
        "period": settings.period,
        "max_range": round(prepared.max_range, 6),
        "map_max_range": settings.map_max_range,
        "min_block_scans": MIN_BLOCK_SCANS,
        "near_path_m": NEAR_PATH_M,
        "coverage_tolerance_m": round(metrics.COVERAGE_TOLERANCE_CELLS * settings.resolution, 6),
    }


def _relative(path: Path | None, base: Path) -> str | None:
    return None if path is None else os.path.relpath(path, base)


def _write_index(split: CvSplit) -> None:
    base = split.index.parent
    entries = []
    for b in split.blocks:
        entries.append({
            "block": b.block,
            "status": b.status,
            "reason": b.reason,
            "bag": _relative(b.bag, base),
            "map": _relative(b.map_yaml, base),
            "scan_range": list(b.scan_range),
            "time_range": [round(t, 6) for t in b.time_range],
            "scan_count": b.scan_count,
            "map_cells": list(b.map_cells) if b.map_cells else None,
            "path_near_free": b.path_near_free,
            "coverage_median": b.coverage_median,
            "coverage_median_same_map": b.coverage_median_same_map,
        })
    document = {
        "format": INDEX_FORMAT,
        "name": split.name,
        "log": str(split.log),
        "scans": split.scans,
        "stamp_source": split.stamp_source,
        "split": "contiguous blocks of equal scan counts by scan index; scan_range is [first, last + 1)",
        "maps": "each block's map is built from the scans of every other block (its bag's /map is that map); "
                "full_map from all scans",
        "full_map": _relative(split.full_map_yaml, base),
        "settings": split.settings,
        "wall_s": split.wall_s,
        "block_count": len(split.blocks),
        "blocks": entries,
    }
    split.index.write_text(yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=120))


def load_cv_index(path: str | os.PathLike[str]) -> CvSplit:
    """Read the index ``<name>_cv.yaml`` of a split; paths come back absolute.

    Raises:
        CarmenLogError: the file is missing, not an index, or names a missing bag or map.
    """
    path = Path(path).resolve()
    if not path.is_file():
        raise CarmenLogError(f"CV index {str(path)!r} does not exist")
    try:
        document = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise CarmenLogError(f"CV index {str(path)!r} is not valid YAML: {exc}") from exc
    if not isinstance(document, dict) or document.get("format") != INDEX_FORMAT:
        raise CarmenLogError(f"CV index {str(path)!r} is not a {INDEX_FORMAT!r} index")
    base = path.parent

    def resolve(relative: str | None) -> Path | None:
        if relative is None:
            return None
        found = (base / relative).resolve()
        if not found.exists():
            raise CarmenLogError(f"CV index {str(path)!r} names a missing file {str(found)!r}")
        return found

    try:
        blocks = tuple(
            CvBlock(
                block=int(e["block"]),
                blocks=int(document["block_count"]),
                scan_range=(int(e["scan_range"][0]), int(e["scan_range"][1])),
                time_range=(float(e["time_range"][0]), float(e["time_range"][1])),
                status=str(e["status"]),
                reason=str(e.get("reason") or ""),
                bag=resolve(e.get("bag")),
                map_yaml=resolve(e.get("map")),
                map_cells=(int(e["map_cells"][0]), int(e["map_cells"][1])) if e.get("map_cells") else None,
                path_near_free=e.get("path_near_free"),
                coverage_median=e.get("coverage_median"),
                coverage_median_same_map=e.get("coverage_median_same_map"),
            )
            for e in document["blocks"]
        )
        full_map = resolve(str(document["full_map"]))
        fields = (str(document["name"]), Path(document["log"]), int(document["scans"]), str(document["stamp_source"]))
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CarmenLogError(f"CV index {str(path)!r} is malformed: {type(exc).__name__} {exc}") from exc
    assert full_map is not None  # resolve() returns None only for None
    return CvSplit(
        name=fields[0],
        log=fields[1],
        index=path,
        full_map_yaml=full_map,
        scans=fields[2],
        stamp_source=fields[3],
        blocks=blocks,
        settings=dict(document["settings"]),
        wall_s=float(document.get("wall_s", 0.0)),
    )
