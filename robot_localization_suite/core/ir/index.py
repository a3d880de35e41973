"""Precomputation and the two-level index of the IR initialiser (Aycard & Brouard, sections IV-A-2, IV-B-1, IV-B-2).

For every candidate position ``(x, y)`` of a regular grid over the free space
of the map this stores one 360-degree *ray fan* of byte-quantised ranges
(rotated to serve every heading), the *patterns* seen from the position (runs
of consecutive hits between no-return readings, section IV-B-1), and the
paper's two-level index (section IV-B-2): *hit -> pattern* and
*pattern -> position* (with frequencies), as sparse matrices.

A first-level *hit* is what a live scan yields before its pose is known:
``(anchor side, offset, range bin)``, the quantised range of the beam
``offset`` beams inside a pattern, counted from the no-return reading that
delimits it (``side`` 0: from its start; 1: from its end).

Everything here is deterministic; the cache file is keyed by the map
fingerprint and a hash of every setting that changes its content, and the
``ir/`` cache directory is kept within a size budget (:mod:`..cache`).

Notes (why a fan per position, which beams are indexed, the cache rules): docs/ir.md.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import sys
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .. import edt, grid_map, raycast
from ..cache import (
    cache_budget_bytes,
    default_cache_dir,
    load_cached,
    npz_member_memmap,
    prune_cache,
    source_digest,
)
from ..errors import CacheError
from ..grid_map import GridMap
from ..progress import ReportingBar, progress_disabled
from ..raycast import RayCaster
from . import patterns as _patterns_module
from .patterns import (
    NO_RETURN,
    count_fan_runs,
    count_view_runs,
    fill_fan_runs,
    fill_terms_all_valid,
    fill_view_runs,
    fill_view_terms,
)
from .settings import MAX_HIT_CODE

__all__ = [
    "HitIndex",
    "FanModel",
    "pattern_blocks",
    "IndexSettings",
    "IRIndex",
    "candidate_positions",
    "cast_fans",
    "default_cache_dir",
]

_LOG = logging.getLogger(__name__)

#: Bump when the cache layout or the meaning of a stored array changes.
CACHE_VERSION = 7


def _cache_meta(fan: FanModel, settings: IndexSettings) -> dict[str, Any]:
    """What a cached index was built from: the layout version, the code that builds it (the ray caster, the
    distance transform, the map's masks, the patterns and this module), the fan and the settings."""
    code = source_digest(raycast, edt, grid_map, _patterns_module, sys.modules[__name__])
    return {"version": CACHE_VERSION, "code": code, "fan": fan.__dict__, "settings": settings.__dict__}


# Lattice points tested at once when the candidate positions are chosen (bounds the temporaries).
_LATTICE_POINTS_AT_ONCE = 1 << 20
# Arrays smaller than this are read into memory even when an index is memory-mapped [bytes].
_MAP_AT_LEAST = 1 << 20


@dataclass(frozen=True)
class FanModel:
    """The 360-degree ray fan cast at every position: the scanner model as the index sees it.

    Attributes:
        rays: number of rays over 360 degrees (``M``).
        max_range: longest range stored [m]; farther hits are no-returns.
        range_resolution: quantisation step of the stored ranges [m].
    """

    rays: int
    max_range: float
    range_resolution: float

    def __post_init__(self) -> None:
        if self.rays < 8:
            raise ValueError(f"a ray fan needs at least 8 rays, got {self.rays!r}")
        if not (np.isfinite(self.range_resolution) and self.range_resolution > 0.0):
            raise ValueError(f"range_resolution must be positive, got {self.range_resolution!r}")
        if not (np.isfinite(self.max_range) and 0.0 < self.max_range <= MAX_HIT_CODE * self.range_resolution + 1e-9):
            raise ValueError(
                f"max_range must be in (0, {MAX_HIT_CODE * self.range_resolution:.2f}] m for one-byte codes "
                f"at {self.range_resolution} m, got {self.max_range!r}"
            )

    @property
    def ray_step(self) -> float:
        """Angle between neighbouring rays [rad]."""
        return 2.0 * math.pi / self.rays

    def serves(self, needed: FanModel) -> bool:
        """Whether an index of this fan serves scans that would ask for ``needed``: the same ranges, and rays
        within 2 % as many (a scan is resampled onto the fan's rays by nearest beam, so a beam more or less,
        as an RPLIDAR's count varies from scan to scan, changes no reading by more than half a beam)."""
        return (self.range_resolution == needed.range_resolution
                and abs(self.max_range - needed.max_range) <= 1e-6
                and abs(self.rays - needed.rays) <= max(1, int(0.02 * self.rays)))

    def angles(self) -> NDArray[np.float64]:
        """Ray angles ``(M,)`` [rad] relative to the map x axis, ray 0 along +x."""
        return np.arange(self.rays, dtype=np.float64) * self.ray_step

    def quantise(self, ranges: NDArray[np.floating]) -> NDArray[np.uint8]:
        """Byte codes of ranges [m]: nearest step, NO_RETURN for inf / NaN / beyond ``max_range``."""
        ranges = np.asarray(ranges, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            hit = np.isfinite(ranges) & (ranges <= self.max_range) & (ranges >= 0.0)
        codes = np.full(ranges.shape, NO_RETURN, dtype=np.uint8)
        codes[hit] = np.minimum(np.rint(ranges[hit] / self.range_resolution), MAX_HIT_CODE).astype(np.uint8)
        return codes

    def code_of(self, metres: float) -> int:
        """Largest hit code at or below ``metres``."""
        return int(min(MAX_HIT_CODE, math.floor(metres / self.range_resolution + 1e-9)))


@dataclass(frozen=True)
class IndexSettings:
    """Everything that changes the content of an index (and so its cache key).

    Attributes:
        grid_resolution: spacing of the candidate positions [m] (paper: 5 cm).
        max_positions: the lattice is widened until at most this many positions remain (0: no limit).
        min_clearance: positions closer than this to an obstacle or unknown cell are
            left out [m] (a robot body keeps its laser off walls; 0 keeps every free cell).
        unknown_blocks: whether unknown cells stop the precomputed rays.
        pattern_max_range: readings beyond this count as no-returns when patterns
            are cut [m] (paper: its laser's 5.5 m range, section II); 0: the fan's range.
        pattern_range_bin: range bin of a first-level hit [m].
        pattern_terms_per_end: beams indexed from each anchored end of a pattern.
        min_pattern_beams: shorter runs of hits are not patterns (noise, legs).
        split_at_jump: also delimit patterns where consecutive ranges differ by more
            than this [m]; 0 follows the paper (no-returns only).
        pattern_views: ``circle``: patterns of the whole fan; ``two_240``: of two 240-degree views
            facing 0 and 180 degrees (paper IV-B-1).

    No defaults and no checks here: :class:`~.settings.IRSettings` holds and checks them
    and builds this from its fields of the same names (``IRSettings().index_settings()``),
    so that the two can never disagree.
    """

    grid_resolution: float
    max_positions: int
    min_clearance: float
    unknown_blocks: bool
    pattern_max_range: float
    pattern_range_bin: float
    pattern_terms_per_end: int
    min_pattern_beams: int
    split_at_jump: float
    pattern_views: str


#: Half the field of view of each of the paper's two views (IV-B-1: a 240-degree scanner at 0 and 180 degrees).
_VIEW_HALF_WIDTH = math.radians(120.0)


def view_rays(fan: FanModel) -> NDArray[np.int64]:
    """Ray indices ``(2, V)`` of the paper's two 240-degree views, facing 0 and 180 degrees, in the fan."""
    half = int(math.floor(_VIEW_HALF_WIDTH / fan.ray_step + 1e-9))
    offsets = np.arange(-half, half + 1)
    return np.stack([offsets % fan.rays, (offsets + int(round(fan.rays / 2))) % fan.rays]).astype(np.int64)


# --------------------------------------------------------------------------------------------
# Positions and ray fans (IV-A-2)
# --------------------------------------------------------------------------------------------
def candidate_positions(grid_map: GridMap, grid_resolution: float, min_clearance: float) -> NDArray[np.float64]:
    """Centres ``(P, 2)`` [m] of a ``grid_resolution`` lattice over the map that fall in free cells
    at least ``min_clearance`` from any occupied or unknown cell (row by row of the lattice)."""
    x0, x1, y0, y1 = grid_map.extent
    xs = np.arange(x0 + grid_resolution / 2.0, x1, grid_resolution)
    ys = np.arange(y0 + grid_resolution / 2.0, y1, grid_resolution)
    columns = np.floor((xs - grid_map.origin[0]) / grid_map.resolution).astype(np.int64)
    rows = np.floor((ys - grid_map.origin[1]) / grid_map.resolution).astype(np.int64)
    keep_x, keep_y = (columns >= 0) & (columns < grid_map.width), (rows >= 0) & (rows < grid_map.height)
    xs, columns, ys, rows = xs[keep_x], columns[keep_x], ys[keep_y], rows[keep_y]
    free = grid_map.free_mask
    # Not cached: a large map's field is 4 bytes a cell, needed only here.
    clearance = grid_map.distance_field(unknown_is_obstacle=True, cache=False) if min_clearance > 0.0 else None
    chunks = [np.zeros((0, 2))]
    step = max(1, _LATTICE_POINTS_AT_ONCE // max(len(xs), 1))
    for start in range(0, len(rows), step):
        block = rows[start : start + step, None], columns[None, :]
        keep = free[block]
        if clearance is not None:
            keep &= clearance[block] >= min_clearance - 1e-6
        r, c = np.nonzero(keep)
        chunks.append(np.stack([xs[c], ys[start + r]], axis=-1))
    return np.concatenate(chunks)


def lattice_positions(grid_map: GridMap, settings: IndexSettings) -> tuple[NDArray[np.float64], float]:
    """:func:`candidate_positions` at ``grid_resolution``, the lattice widened while more than
    ``max_positions`` remain (positions shrink with the square of the step); returns them and the step [m]."""
    step = settings.grid_resolution
    positions = candidate_positions(grid_map, step, settings.min_clearance)
    limit = settings.max_positions
    while limit > 0 and len(positions) > limit:
        step *= max(math.sqrt(len(positions) / limit), 1.02)
        positions = candidate_positions(grid_map, step, settings.min_clearance)
    if step != settings.grid_resolution:
        _LOG.info("IR lattice widened from %.3f m to %.3f m: %d positions (max_positions %d)",
                  settings.grid_resolution, step, len(positions), limit)
    return positions, step


def cast_fans(
    grid_map: GridMap,
    positions: NDArray[np.float64],
    fan: FanModel,
    *,
    unknown_blocks: bool = False,
    progress: bool = True,
    chunk: int = 8192,
) -> NDArray[np.uint8]:
    """Quantised 360-degree fans ``(P, M)`` at ``positions`` by the shared ray caster (threads over poses)."""
    caster = RayCaster(grid_map, max_range=fan.max_range, unknown_blocks=unknown_blocks, skip_free_space=True)
    angles = fan.angles()
    fans = np.empty((len(positions), fan.rays), dtype=np.uint8)
    poses = np.zeros((min(chunk, max(len(positions), 1)), 3))
    bar = ReportingBar(total=len(positions), desc="IR ray fans", unit="pos", disable=progress_disabled(progress), leave=False)
    for start in range(0, len(positions), chunk):
        stop = min(start + chunk, len(positions))
        poses_chunk = poses[: stop - start]
        poses_chunk[:, :2] = positions[start:stop]
        fans[start:stop] = fan.quantise(caster.cast(poses_chunk, angles, parallel=True))
        bar.update(stop - start)
    bar.close()
    return fans


# --------------------------------------------------------------------------------------------
# Patterns (IV-B-1)
# --------------------------------------------------------------------------------------------
#: Patterns per block of the hit index: ids within a block are stored as 16-bit offsets.
BLOCK_BITS = 16


@dataclass(frozen=True)
class HitIndex:
    """The first level, hit -> pattern, as an inverted index of 16-bit pattern offsets.

    Pattern ids are cut into blocks of ``2**16``; each hit's row is stored block by block as
    the ids' offsets within their block (2 bytes a link instead of 4). Row ``t`` spans
    ``patterns[indptr[t * blocks] : indptr[(t + 1) * blocks]]``; its part in block ``b`` starts
    at ``indptr[t * blocks + b]``.

    Attributes:
        indptr: ``(T * blocks + 1,)`` start of each (hit, block) part in ``patterns``.
        patterns: ``(L,)`` pattern offsets within their block, ascending within each part.
        pattern_count: number of patterns ``U``.
        blocks: number of pattern blocks, ``ceil(U / 2**16)`` (at least 1).
    """

    indptr: NDArray[np.int64]
    patterns: NDArray[np.uint16]
    pattern_count: int
    blocks: int = 1

    @property
    def term_count(self) -> int:
        return int((len(self.indptr) - 1) // max(self.blocks, 1))

    @property
    def nnz(self) -> int:
        return int(len(self.patterns))

    @property
    def nbytes(self) -> int:
        return int(self.indptr.nbytes + self.patterns.nbytes)

    def row(self, term: int) -> NDArray[np.int64]:
        """The patterns holding hit ``term`` (ascending ids)."""
        parts = [
            self.patterns[self.indptr[term * self.blocks + b] : self.indptr[term * self.blocks + b + 1]].astype(np.int64)
            + (b << BLOCK_BITS)
            for b in range(self.blocks)
        ]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    def as_csr(self) -> sp.csr_matrix:
        """The same index as a ``(T, U)`` scipy CSR matrix of ones."""
        rows = [self.row(t) for t in range(self.term_count)]
        indptr = np.zeros(self.term_count + 1, dtype=np.int64)
        np.cumsum([len(r) for r in rows], out=indptr[1:])
        indices = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        return sp.csr_matrix(
            (np.ones(len(indices), dtype=np.float32), indices, indptr), shape=(self.term_count, self.pattern_count)
        )


def pattern_blocks(pattern_count: int) -> int:
    """Blocks of ``2**16`` pattern ids the hit index needs (at least 1)."""
    return max(1, -(-pattern_count // (1 << BLOCK_BITS)))


@numba.njit(cache=True, nogil=True)
def _invert(term_offsets, terms, term_count, blocks):
    """Pattern-major hit lists -> (hit, block)-major 16-bit pattern offsets (a counting sort; ascending)."""
    counts = np.zeros(term_count * blocks + 1, dtype=np.int64)
    for u in range(term_offsets.shape[0] - 1):
        block = u >> 16
        for e in range(term_offsets[u], term_offsets[u + 1]):
            counts[np.int64(terms[e]) * blocks + block + 1] += 1
    indptr = np.cumsum(counts)
    fill = indptr[:-1].copy()
    out = np.empty(terms.shape[0], dtype=np.uint16)
    for u in range(term_offsets.shape[0] - 1):
        block = u >> 16
        for e in range(term_offsets[u], term_offsets[u + 1]):
            key = np.int64(terms[e]) * blocks + block
            out[fill[key]] = u & 0xFFFF
            fill[key] += 1
    return indptr, out


@dataclass
class IRIndex:
    """Precomputed fans and the two-level index of one map.

    Attributes:
        positions: ``(P, 2)`` candidate positions [m].
        fans: ``(P, M)`` quantised 360-degree fans (byte codes, see :class:`FanModel`).
        fan: the fan model.
        settings: what the index was built with.
        hit_patterns: level 1, first-level hit -> patterns holding it.
        pattern_positions: ``(U, P)`` CSR of frequencies (occurrences of pattern ``u`` at position ``p``).
        pattern_frequency: ``(U,)`` occurrences of each pattern over the whole map.
        build_seconds: wall time of the precomputation (0 when loaded from the cache).
        cache_path: the cache file used, if any.
        memory_mapped: the large arrays are mapped from ``cache_path`` rather than held in memory.
        lattice_step: spacing of ``positions`` [m]: ``settings.grid_resolution`` unless
            ``max_positions`` widened it (0 read as ``grid_resolution``).
    """

    positions: NDArray[np.float64]
    fans: NDArray[np.uint8]
    fan: FanModel
    settings: IndexSettings
    hit_patterns: HitIndex
    pattern_positions: sp.csr_matrix
    pattern_frequency: NDArray[np.int64]
    build_seconds: float = 0.0
    cache_path: Path | None = None
    memory_mapped: bool = False
    lattice_step: float = 0.0

    @property
    def grid_step(self) -> float:
        """Spacing of the candidate positions [m] (:attr:`lattice_step`)."""
        return self.lattice_step if self.lattice_step > 0.0 else self.settings.grid_resolution

    # -- derived sizes ------------------------------------------------------------------
    @property
    def pattern_divisor(self) -> int:
        """Fan codes per first-level range bin."""
        return max(1, int(round(self.settings.pattern_range_bin / self.fan.range_resolution)))

    @property
    def pattern_cap_code(self) -> int:
        return self.fan.code_of(self.pattern_range)

    @property
    def pattern_range(self) -> float:
        """Readings beyond this [m] end a pattern: ``pattern_max_range``, or the fan's range for 0."""
        limit = self.settings.pattern_max_range
        return min(limit, self.fan.max_range) if limit > 0.0 else self.fan.max_range

    @property
    def jump_codes(self) -> int:
        if self.settings.split_at_jump <= 0.0:
            return 0
        return max(1, int(round(self.settings.split_at_jump / self.fan.range_resolution)))

    @property
    def term_bins(self) -> int:
        return MAX_HIT_CODE // self.pattern_divisor + 1

    @property
    def term_count(self) -> int:
        return 2 * self.settings.pattern_terms_per_end * self.term_bins

    def nbytes(self) -> int:
        """Memory held by the arrays [bytes]."""
        total = self.positions.nbytes + self.fans.nbytes + self.pattern_frequency.nbytes
        total += self.hit_patterns.nbytes
        matrix = self.pattern_positions
        total += matrix.data.nbytes + matrix.indices.nbytes + matrix.indptr.nbytes
        return int(total)

    # -- building -----------------------------------------------------------------------
    @classmethod
    def build(
        cls,
        grid_map: GridMap,
        fan: FanModel,
        settings: IndexSettings,
        *,
        progress: bool = True,
    ) -> IRIndex:
        """Cast the fans at every candidate position, cut the patterns and build the two-level index."""
        start_time = time.perf_counter()
        positions, step = lattice_positions(grid_map, settings)
        if len(positions) == 0:
            raise ValueError(
                f"the map has no free position at {settings.grid_resolution} m with clearance "
                f"{settings.min_clearance} m; lower min_clearance"
            )
        fans = cast_fans(grid_map, positions, fan, unknown_blocks=settings.unknown_blocks, progress=progress)
        index = cls.from_fans(positions, fans, fan, settings, progress=progress)
        index.lattice_step = step
        index.build_seconds = time.perf_counter() - start_time
        return index

    @classmethod
    def from_fans(cls, positions: NDArray[np.float64], fans: NDArray[np.uint8], fan: FanModel,
                  settings: IndexSettings, *, progress: bool = False) -> IRIndex:
        """The two-level index of quantised fans ``(P, M)`` cast at ``positions`` ``(P, 2)`` [m]."""
        index = cls(
            positions=positions,
            fans=fans,
            fan=fan,
            settings=settings,
            hit_patterns=HitIndex(np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.uint16), 0),
            pattern_positions=sp.csr_matrix((0, 0), dtype=np.float32),
            pattern_frequency=np.zeros(0, dtype=np.int64),
        )
        index._build_patterns(progress=progress)
        return index

    def _build_patterns(self, *, progress: bool) -> None:
        settings = self.settings
        fans = self.fans
        cap, jump, divisor = self.pattern_cap_code, self.jump_codes, self.pattern_divisor
        steps = ReportingBar(total=4, desc="IR index", disable=progress_disabled(progress), leave=False)
        # Rows the patterns are cut from: each whole circular fan, or each position's two views (row p * 2 + v).
        views = view_rays(self.fan) if settings.pattern_views == "two_240" else None
        if views is None:
            counts = count_fan_runs(fans, cap, jump, settings.min_pattern_beams)
        else:
            counts = count_view_runs(fans, views, cap, jump, settings.min_pattern_beams)
        offsets = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        total = int(offsets[-1])
        # Compact per-occurrence arrays (a campus-size map has millions of occurrences).
        run_start = np.empty(total, dtype=np.int32)
        run_length = np.empty(total, dtype=np.int32)
        run_hash = np.empty(total, dtype=np.uint64)
        if views is None:
            run_anchors = None
            fill_fan_runs(fans, cap, jump, settings.min_pattern_beams, divisor, offsets[:-1], run_start, run_length,
                          run_hash)
        else:
            run_anchors = np.empty(total, dtype=np.int8)
            fill_view_runs(fans, views, cap, jump, settings.min_pattern_beams, divisor, offsets[:-1], run_start,
                           run_length, run_anchors, run_hash)
        del offsets
        run_row = np.repeat(np.arange(len(counts), dtype=np.int32), counts)  # the fan, or the view, of each run
        run_position = run_row if views is None else run_row // len(views)
        del counts
        steps.update()

        # A pattern seen before is the same node at the pattern level; its frequency grows.
        unique_hash, first, inverse, frequency = np.unique(
            run_hash, return_index=True, return_inverse=True, return_counts=True
        )
        del unique_hash, run_hash
        pattern_count = len(first)
        steps.update()

        # Level 2: pattern -> position, frequencies summed over repeated occurrences.
        index_type = np.int32 if max(total, pattern_count, len(fans)) < np.iinfo(np.int32).max else np.int64
        matrix = sp.csr_matrix(
            (np.ones(total, dtype=np.float32), (inverse.astype(index_type), run_position)),
            shape=(pattern_count, len(fans)),
        )
        del inverse
        matrix.sum_duplicates()
        self.pattern_positions = matrix
        self.pattern_frequency = frequency.astype(np.int32 if total < np.iinfo(np.int32).max else np.int64)
        del frequency
        steps.update()

        # Level 1: hit -> pattern, from one representative occurrence of each pattern.
        per_end = settings.pattern_terms_per_end
        lengths, starts, rows = run_length[first], run_start[first], run_row[first]
        anchors = None if run_anchors is None else run_anchors[first]
        del run_length, run_start, run_position, run_row, run_anchors, first
        ends = 2 if anchors is None else (anchors & 1) + (anchors >> 1 & 1)  # delimited ends of each pattern
        term_offsets = np.zeros(pattern_count + 1, dtype=np.int64)
        np.cumsum(ends * np.minimum(lengths, per_end), out=term_offsets[1:])
        term_type = np.uint16 if self.term_count <= np.iinfo(np.uint16).max else np.int32
        terms = np.empty(int(term_offsets[-1]), dtype=term_type)
        if views is None:
            fill_terms_all_valid(fans, rows, starts, lengths, per_end, divisor, self.term_bins, term_offsets[:-1],
                                 terms)
        else:
            assert anchors is not None
            fill_view_terms(fans, views, rows, starts, lengths, anchors, per_end, divisor, self.term_bins,
                            term_offsets[:-1], terms)
        del lengths, starts, rows, anchors
        # Built pattern by pattern, inverted once into the hit -> pattern index.
        blocks = pattern_blocks(pattern_count)
        indptr, patterns = _invert(term_offsets, terms, self.term_count, blocks)
        del terms, term_offsets
        self.hit_patterns = HitIndex(indptr, patterns, pattern_count, blocks)
        steps.update()
        steps.close()

    # -- cache --------------------------------------------------------------------------
    @staticmethod
    def cache_key(grid_map: GridMap, fan: FanModel, settings: IndexSettings) -> str:
        """Map fingerprint + hash of every setting that changes the index, the code that builds it, and the map's exact
        resolution (the fingerprint reads it at float32 precision, but 0.05 and 0.05000000074505806 cast differently)."""
        description = json.dumps({**_cache_meta(fan, settings), "resolution": grid_map.resolution}, sort_keys=True)
        digest = hashlib.sha256(description.encode()).hexdigest()[:16]
        return f"{grid_map.fingerprint()}_{digest}"

    def save(self, path: Path) -> None:
        """Write the index to ``path`` (``.npz``), atomically."""
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + f".tmp{os.getpid()}")
        with open(tmp, "wb") as fh:
            np.savez(
                fh,
                meta=np.frombuffer(
                    json.dumps(_cache_meta(self.fan, self.settings)).encode(),
                    dtype=np.uint8,
                ),
                positions=self.positions,
                fans=self.fans,
                hit_indptr=self.hit_patterns.indptr,
                hit_patterns=self.hit_patterns.patterns,
                pattern_count=np.array(self.hit_patterns.pattern_count, dtype=np.int64),
                pp_indptr=self.pattern_positions.indptr,
                pp_indices=self.pattern_positions.indices,
                pp_data=self.pattern_positions.data,
                pp_shape=np.array(self.pattern_positions.shape, dtype=np.int64),
                pattern_frequency=self.pattern_frequency,
                lattice_step=np.array(self.grid_step, dtype=np.float64),
            )
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: Path, fan: FanModel, settings: IndexSettings, *, memory_map: bool = False) -> IRIndex:
        """Read an index written by :meth:`save`.

        With ``memory_map`` its large arrays are mapped from the file, not read: only the parts
        the queries touch become resident (and the kernel may drop them again).

        Raises:
            CacheError: the file is missing, unreadable, or was built with other settings.
        """
        try:
            data = _read_npz(path, memory_map=memory_map)
            meta = json.loads(bytes(data["meta"]).decode())
            if meta != _cache_meta(fan, settings):
                raise CacheError(f"IR cache {str(path)!r} was built with other settings: {meta!r}")
            pattern_count = int(data["pattern_count"])
            hit_patterns = HitIndex(data["hit_indptr"], data["hit_patterns"], pattern_count, pattern_blocks(pattern_count))
            pattern_positions = sp.csr_matrix(
                (data["pp_data"], data["pp_indices"], data["pp_indptr"]), shape=tuple(data["pp_shape"]), copy=False
            )
            index = cls(
                data["positions"], data["fans"], fan, settings, hit_patterns, pattern_positions,
                data["pattern_frequency"], 0.0, path, memory_map, float(data["lattice_step"]),
            )
        except CacheError:
            raise
        except Exception as exc:  # noqa: BLE001 - any decoding failure means a corrupt file
            raise CacheError(f"IR cache {str(path)!r} is unreadable: {type(exc).__name__}: {exc}") from exc
        index._check()
        return index

    def _check(self) -> None:
        P, M = self.fans.shape
        problems = []
        if self.positions.shape != (P, 2) or M != self.fan.rays:
            problems.append(f"positions {self.positions.shape} / fans {self.fans.shape} / rays {self.fan.rays}")
        hits = self.hit_patterns
        if (
            len(hits.indptr) != self.term_count * hits.blocks + 1
            or hits.indptr[-1] != hits.nnz
            or hits.indptr.dtype != np.int64
            or hits.patterns.dtype != np.uint16
        ):
            problems.append(f"hit rows {hits.term_count} != {self.term_count} or bad row pointers")
        elif hits.nnz and hits.pattern_count % (1 << BLOCK_BITS):
            # Only the last block is partly used: its offsets must stay below its size.
            last = hits.indptr[hits.blocks - 1 : -1 : hits.blocks]
            ends = hits.indptr[hits.blocks :: hits.blocks]
            size = hits.pattern_count % (1 << BLOCK_BITS)
            if any(_largest(hits.patterns[a:b]) >= size for a, b in zip(last, ends, strict=True) if b > a):
                problems.append("hit index names a pattern that does not exist")
        if self.pattern_positions.shape != (hits.pattern_count, P):
            problems.append(f"pattern_positions {self.pattern_positions.shape}")
        if len(self.pattern_frequency) != self.pattern_positions.shape[0]:
            problems.append("pattern_frequency length")
        if problems:
            raise CacheError(f"IR cache {str(self.cache_path)!r} is inconsistent: {'; '.join(problems)}")

    @classmethod
    def load_or_build(
        cls,
        grid_map: GridMap,
        fan: FanModel,
        settings: IndexSettings,
        *,
        cache_dir: Path | None = None,
        use_cache: bool = True,
        progress: bool = True,
        cache_budget_mb: float = 0.0,
        memory_budget_mb: float = math.inf,
    ) -> IRIndex:
        """The cached index of this map and these settings, built (and cached) when missing or corrupt.

        After writing a new index, the least recently used ones in the ``ir/`` cache directory are
        deleted until it holds at most ``cache_budget_mb`` [MB] (0: ``$RLS_CACHE_BUDGET_MB`` or 2048;
        see :mod:`~.cache`). A loaded index counts as used. An index whose cache file is larger than
        ``memory_budget_mb`` [MB] is memory-mapped from it (:meth:`load`), also right after it is built.

        Raises:
            ValueError: on a bad budget (checked before building).
        """
        path = None
        budget_bytes = memory_budget_mb * _BYTES_PER_MB
        if use_cache:
            budget = cache_budget_bytes(cache_budget_mb)
            directory = (cache_dir or default_cache_dir()) / "ir"
            path = directory / f"{cls.cache_key(grid_map, fan, settings)}.npz"
            if path.is_file():
                memory_map = path.stat().st_size > budget_bytes
                cached = load_cached(path, lambda file: cls.load(file, fan, settings, memory_map=memory_map),
                                     what="IR", warn=_LOG.warning)
                if cached is not None:
                    return cached
        index = cls.build(grid_map, fan, settings, progress=progress)
        if path is not None:
            try:
                index.save(path)
                index.cache_path = path
            except OSError as exc:
                _LOG.warning("could not write the IR cache %s: %s", path, exc)
            else:
                prune_cache(path.parent, budget, keep=path, log=lambda text: _LOG.info("IR %s", text))
                if path.stat().st_size > budget_bytes:
                    # The arrays just built are let go: the file serves them from now on.
                    try:
                        mapped = cls.load(path, fan, settings, memory_map=True)
                    except CacheError as exc:
                        _LOG.warning("%s; keeping the index in memory", exc)
                    else:
                        mapped.build_seconds = index.build_seconds
                        index = mapped
        return index

    def describe(self) -> dict[str, Any]:
        """Sizes for reports."""
        return {
            "positions": int(self.fans.shape[0]),
            "rays": int(self.fans.shape[1]),
            "patterns": int(self.hit_patterns.pattern_count),
            "pattern_occurrences": int(self.pattern_frequency.sum()),
            "hit_links": int(self.hit_patterns.nnz),
            "megabytes": round(self.nbytes() / 1e6, 1),
            "memory_mapped": self.memory_mapped,
            "lattice_step_m": round(self.grid_step, 4),
            "build_seconds": round(self.build_seconds, 2),
        }


_BYTES_PER_MB = 1024 * 1024


def _largest(values: NDArray[np.integer], chunk: int = 1 << 22) -> int:
    """Largest value, read chunk by chunk (a memory-mapped array is not made resident at once)."""
    return max((int(values[i : i + chunk].max()) for i in range(0, len(values), chunk)), default=-1)


def _read_npz(path: Path, *, memory_map: bool) -> dict[str, NDArray[Any]]:
    """The arrays of an ``.npz``; with ``memory_map``, those of at least 1 MB stored uncompressed mapped from the file."""
    arrays: dict[str, NDArray[Any]] = {}
    with np.load(path, allow_pickle=False) as data:
        if not memory_map:
            return {name: data[name] for name in data.files}
        with zipfile.ZipFile(path) as archive:
            sizes = {info.filename.removesuffix(".npy"): info.file_size for info in archive.infolist()}
        for name in data.files:
            mapped = npz_member_memmap(path, name) if sizes.get(name, 0) >= _MAP_AT_LEAST else None
            arrays[name] = mapped if mapped is not None else data[name]
    return arrays
