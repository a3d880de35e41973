"""PIL off-line learning (Lambert et al. 2020, section 2.2), its tile grid and its on-disk cache.

The map is covered by a grid of square tiles of side ``r``; a tile is valid
when its centre falls in a free cell (tiles exist only over free space). A
simulated robot at the centre of every valid tile, heading 0, measures the
range along ``angle_count`` evenly spaced directions with the shared
:class:`~robot_localization_suite.core.raycast.ClassifiedRayCaster` (finer than
the ``N_s`` sensors, over the full circle). Each learned ray is one byte: the
intensity of equation (2), ``I = 1 - D_s / R``, on 254 levels, or
:data:`CODE_UNKNOWN` for a ray the map cannot predict (it meets unknown space
or leaves the map first). The transform ``M`` of equation (1) puts tile
centres on integers.

Cache: ``$RLS_CACHE_DIR`` (or ``~/.cache/robot_localization_suite``)
``/pil/pil_<map fingerprint>_<parameter hash>.npz``, written atomically,
rebuilt when unreadable, kept within the budget of :mod:`..cache`; learned
profiles above a size are memory-mapped from it instead of read.

Notes (the choices the paper leaves open, memory and time on large maps): docs/pil.md.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import edt, raycast
from .. import grid_map as grid_map_module
from ..cache import (
    cache_budget_bytes,
    default_cache_dir,
    load_cached,
    npz_member_memmap,
    prune_cache,
    source_digest,
)
from ..errors import CacheError, MapError
from ..grid_map import GridMap
from ..progress import ReportingBar, progress_disabled
from ..raycast import RAY_UNKNOWN, ClassifiedRayCaster

__all__ = [
    "TileGrid",
    "PilLearning",
    "learn_pseudo_images",
    "default_cache_dir",
    "LEARNING_VERSION",
    "CODE_LEVELS",
    "CODE_UNKNOWN",
    "encode_ranges",
    "decode_intensities",
]

# Bump when the learned content changes meaning, so that old cache files are not reused.
LEARNING_VERSION = 3
#: A learned ray's byte: ``round(D / R * CODE_LEVELS)`` for a range ``D <= R`` (``I = 1 - code / CODE_LEVELS``) ...
CODE_LEVELS = 254
#: ... or this for a ray the map cannot predict.
CODE_UNKNOWN = 255
_MAX_RANGE_M = 65.0
# Tiles cast per progress-bar step: about 2 MB of ranges at 456 directions.
_TILES_PER_CHUNK = 1024

_logger = logging.getLogger(__name__)


def encode_ranges(ranges: NDArray[np.floating], max_range: float) -> NDArray[np.uint8]:
    """Bytes of ranges [m] (``inf`` or beyond ``R`` reads ``R``, as a no-return); NaN is unknown."""
    scaled = np.minimum(np.asarray(ranges, dtype=np.float32), np.float32(max_range)) * np.float32(CODE_LEVELS / max_range)
    codes = np.rint(scaled)
    codes[np.isnan(codes)] = CODE_UNKNOWN
    return codes.astype(np.uint8)


def decode_intensities(codes: NDArray[np.uint8]) -> NDArray[np.float32]:
    """``I = 1 - code / CODE_LEVELS`` of learned bytes, NaN where unknown."""
    intensities = np.float32(1.0) - codes.astype(np.float32) * np.float32(1.0 / CODE_LEVELS)
    intensities[codes == CODE_UNKNOWN] = np.nan
    return intensities


@dataclass(frozen=True)
class TileGrid:
    """The ``L_max x C_max`` grid of tiles over a map and its transform ``M`` (equation 1).

    Attributes:
        origin: world ``(x0, y0)`` of the corner of tile (0, 0) [m] (the map origin).
        tile_size: ``r`` [m].
        lines: ``L_max`` (tiles along y).
        columns: ``C_max`` (tiles along x).
    """

    origin: tuple[float, float]
    tile_size: float
    lines: int
    columns: int

    @classmethod
    def covering(cls, grid_map: GridMap, tile_size: float) -> TileGrid:
        x_min, x_max, y_min, y_max = grid_map.extent
        columns = max(1, int(np.ceil((x_max - x_min) / tile_size - 1e-9)))
        lines = max(1, int(np.ceil((y_max - y_min) / tile_size - 1e-9)))
        return cls((x_min, y_min), float(tile_size), lines, columns)

    @property
    def matrix(self) -> NDArray[np.float64]:
        """``M`` (3 x 3): ``[L, C, 1]^T = M [x, y, 1]^T`` (equation 1), tile centres on integers."""
        r = self.tile_size
        x0, y0 = self.origin
        return np.array([[0.0, 1.0 / r, -y0 / r - 0.5], [1.0 / r, 0.0, -x0 / r - 0.5], [0.0, 0.0, 1.0]])

    @property
    def inverse_matrix(self) -> NDArray[np.float64]:
        """``M^-1``: image ``(L, C)`` back to world ``(x, y)`` (equation 5)."""
        return np.linalg.inv(self.matrix).astype(np.float64, copy=False)  # float64 already: no copy

    def world_to_image(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Continuous ``(L, C)`` ``(..., 2)`` of world points ``(..., 2)``."""
        xy = np.asarray(xy, dtype=np.float64)
        homogeneous = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        return (homogeneous @ self.matrix.T)[..., :2]

    def world_to_tile(self, xy: ArrayLike) -> NDArray[np.int64]:
        """Integer ``(L, C)`` ``(..., 2)`` of the tiles holding world points ``(..., 2)`` (may be off the grid)."""
        return np.floor(self.world_to_image(xy) + 0.5).astype(np.int64)

    def tile_to_world(self, lc: ArrayLike) -> NDArray[np.float64]:
        """World ``(x, y)`` ``(..., 2)`` of image coordinates ``(L, C)`` ``(..., 2)`` (tile centres for integers)."""
        lc = np.asarray(lc, dtype=np.float64)
        homogeneous = np.concatenate([lc, np.ones(lc.shape[:-1] + (1,))], axis=-1)
        return (homogeneous @ self.inverse_matrix.T)[..., :2]

    def all_centres(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
        """``(L, C, xy)`` of every tile, line-major."""
        lines, columns = np.meshgrid(np.arange(self.lines), np.arange(self.columns), indexing="ij")
        lines, columns = lines.reshape(-1), columns.reshape(-1)
        return lines, columns, self.tile_to_world(np.stack([lines, columns], axis=-1))


@dataclass(eq=False)
class PilLearning:
    """The learned pseudo-images of one map.

    Attributes:
        grid: the tile grid and ``M``.
        tile_lines, tile_columns: ``(T,)`` image coordinates of the valid tiles.
        tile_centres: ``(T, 2)`` world centres of the valid tiles [m].
        codes: ``(T, J)`` one byte per learned ray along world angle ``j * 2 pi / J`` from each tile
            centre: ``round(D_s / R * CODE_LEVELS)``, or :data:`CODE_UNKNOWN`. May be a read-only
            memory map of the cache file.
        max_range: ``R`` [m].
        key: the cache key (map fingerprint + parameter hash).
        seconds: how long learning (or loading) took [s].
        from_cache: whether this was loaded from disk.
        memory_mapped: whether ``codes`` is a memory map of the cache file.
    """

    grid: TileGrid
    tile_lines: NDArray[np.int32]
    tile_columns: NDArray[np.int32]
    tile_centres: NDArray[np.float64]
    codes: NDArray[np.uint8]
    max_range: float
    key: str
    seconds: float = 0.0
    from_cache: bool = False
    memory_mapped: bool = False
    _intensities: NDArray[np.float32] | None = field(default=None, repr=False)

    @property
    def tile_count(self) -> int:
        return int(self.tile_lines.size)

    @property
    def angle_count(self) -> int:
        return int(self.codes.shape[1])

    @property
    def angle_step(self) -> float:
        """Spacing of the learned directions [rad]."""
        return 2.0 * np.pi / self.angle_count

    @property
    def nbytes(self) -> int:
        """Bytes this learning holds (a memory-mapped ``codes`` counts: its pages may all become resident)."""
        arrays = (self.tile_lines, self.tile_columns, self.tile_centres, self.codes)
        return int(sum(a.nbytes for a in arrays))

    @property
    def known(self) -> NDArray[np.bool_]:
        """``(T, J)``: the learned rays the map can predict (not :data:`CODE_UNKNOWN`)."""
        return np.asarray(self.codes != CODE_UNKNOWN)

    @property
    def intensities(self) -> NDArray[np.float32]:
        """``I = 1 - D_s / R`` ``(T, J)`` (equation 2), NaN on unknown rays.

        Four bytes a ray, derived once on first use: for inspection and small maps; the
        matching reads :attr:`codes`.
        """
        if self._intensities is None:
            self._intensities = decode_intensities(np.asarray(self.codes))
        return self._intensities

    def pseudo_image(self, values: NDArray[np.floating]) -> NDArray[np.float64]:
        """Scatter per-tile ``values`` ``(T,)`` into an ``L_max x C_max`` image, NaN on invalid tiles.

        ``pseudo_image(learning.intensities[:, k])`` is the paper's pseudo-image of direction k (figure 1).
        """
        image = np.full((self.grid.lines, self.grid.columns), np.nan)
        image[self.tile_lines, self.tile_columns] = values
        return image

    def tile_index_image(self) -> NDArray[np.int32]:
        """``(L_max, C_max)`` index into the valid tiles, -1 on invalid tiles."""
        image = np.full((self.grid.lines, self.grid.columns), -1, dtype=np.int32)
        image[self.tile_lines, self.tile_columns] = np.arange(self.tile_count, dtype=np.int32)
        return image


def _learning_key(
    grid_map: GridMap, tile_size: float, angle_count: int, max_range: float, unknown_blocks: bool, mark_unknown: bool
) -> str:
    params = {
        "version": LEARNING_VERSION,
        "code": source_digest(raycast, edt, grid_map_module, sys.modules[__name__]),
        "resolution": grid_map.resolution,  # exact: the fingerprint reads it at float32 precision
        "tile_size": round(float(tile_size), 9),
        "angle_count": int(angle_count),
        "max_range": round(float(max_range), 9),
        "unknown_blocks": bool(unknown_blocks),
        "mark_unknown": bool(mark_unknown),
        "occupied_threshold": int(grid_map.occupied_threshold),
        "free_threshold": int(grid_map.free_threshold),
    }
    params_hash = hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()[:16]
    return f"{grid_map.fingerprint()}_{params_hash}"


def _file_checksum(path: Path, start: int, size: int) -> str:
    """sha256 of ``size`` bytes of a file from ``start``, read in blocks (page cache, not this process's memory)."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        stream.seek(start)
        left = size
        while left > 0:
            block = stream.read(min(left, 1 << 22))
            if not block:
                raise ValueError("file ends early")
            digest.update(block)
            left -= len(block)
    return digest.hexdigest()


def _load_cache(path: Path, key: str, grid: TileGrid, angle_count: int, mmap_bytes: int) -> PilLearning:
    """Read a cache file (memory-mapping ``codes`` above ``mmap_bytes``); raise :class:`CacheError` naming what is wrong."""
    try:
        with np.load(path, allow_pickle=False) as archive:
            stored_key = str(archive["key"])
            lines = np.asarray(archive["tile_lines"], dtype=np.int32)
            columns = np.asarray(archive["tile_columns"], dtype=np.int32)
            max_range = float(archive["max_range"])
            checksum = str(archive["checksum"])
            codes_shape = tuple(int(n) for n in archive["codes_shape"])
            if stored_key != key:
                raise CacheError(f"PIL cache {str(path)!r} holds key {stored_key!r}, expected {key!r}")
            nbytes = codes_shape[0] * codes_shape[1] if len(codes_shape) == 2 else 0
            mapped_codes = npz_member_memmap(path, "codes") if nbytes > mmap_bytes else None
            mapped = mapped_codes is not None
            codes: NDArray[np.uint8] = np.asarray(mapped_codes if mapped else archive["codes"])
    except CacheError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise CacheError(f"PIL cache {str(path)!r} is unreadable: {type(exc).__name__}: {exc}") from exc
    if codes.dtype != np.uint8 or codes.ndim != 2 or codes.shape != (lines.size, angle_count):
        raise CacheError(
            f"PIL cache {str(path)!r} holds codes of shape {codes.shape!r} / {codes.dtype}, "
            f"expected ({lines.size}, {angle_count}) uint8"
        )
    if lines.size and (lines.min() < 0 or lines.max() >= grid.lines or columns.min() < 0 or columns.max() >= grid.columns):
        raise CacheError(f"PIL cache {str(path)!r} holds tiles outside the {grid.lines} x {grid.columns} grid")
    try:
        if isinstance(mapped_codes, np.memmap):
            found = _checksum_parts(_file_checksum(path, mapped_codes.offset, mapped_codes.nbytes), lines, columns)
        else:
            found = _checksum(codes, lines, columns)
    except (OSError, ValueError) as exc:
        raise CacheError(f"PIL cache {str(path)!r} is unreadable: {type(exc).__name__}: {exc}") from exc
    if found != checksum:
        raise CacheError(f"PIL cache {str(path)!r} fails its checksum")
    centres = grid.tile_to_world(np.stack([lines, columns], axis=-1))
    if isinstance(mapped_codes, np.memmap):
        codes = mapped_codes  # keep the memory map, not an in-memory view of it
    return PilLearning(grid, lines, columns, centres, codes, max_range, key, from_cache=True, memory_mapped=mapped)


def _checksum_parts(codes_digest: str, lines: NDArray[np.int32], columns: NDArray[np.int32]) -> str:
    digest = hashlib.sha256(codes_digest.encode())
    for array in (lines, columns):
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:32]


def _checksum(codes: NDArray[np.uint8], lines: NDArray[np.int32], columns: NDArray[np.int32]) -> str:
    """The codes' sha256 (in blocks, no copy), then the tiles'."""
    digest = hashlib.sha256()
    flat = np.asarray(codes).reshape(-1)
    for first in range(0, flat.size, 1 << 22):
        digest.update(flat[first : first + (1 << 22)].tobytes())
    return _checksum_parts(digest.hexdigest(), lines, columns)


def _save_cache(path: Path, learning: PilLearning, checksum: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp_name = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            np.savez(
                stream,
                key=np.array(learning.key),
                tile_lines=learning.tile_lines,
                tile_columns=learning.tile_columns,
                codes_shape=np.array(learning.codes.shape, dtype=np.int64),
                codes=learning.codes,
                max_range=np.array(learning.max_range),
                checksum=np.array(checksum),
            )
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise


def learn_pseudo_images(
    grid_map: GridMap,
    *,
    tile_size: float,
    angle_count: int,
    max_range: float,
    unknown_blocks: bool = False,
    mark_unknown: bool = True,
    cache_dir: str | os.PathLike[str] | None = None,
    use_cache: bool = True,
    mmap_bytes: int = 256 << 20,
    show_progress: bool = True,
    log: Callable[[str, str], None] | None = None,
    caster: ClassifiedRayCaster | None = None,
) -> PilLearning:
    """Learn (or load from the cache) the pseudo-images of ``grid_map`` (section 2.2).

    Args:
        grid_map: the map.
        tile_size: ``r`` [m].
        angle_count: learned directions over the full circle (``N_s``-derived, upsampled).
        max_range: ``R`` [m], at most 65 m.
        unknown_blocks: without ``mark_unknown``: unknown cells stop the learning rays as walls do.
        mark_unknown: a ray that leaves the map, or crosses an unknown cell and then hits
            nothing, before ``R`` is :data:`CODE_UNKNOWN` (otherwise it reads the range it
            finds, as the paper's simulated robot in a fully known environment). A ray that
            crosses unknown cells and then hits a wall reads that wall: holes in the free
            space of a map built from scans are mostly unobserved free space.
        cache_dir: cache directory; ``None``: :func:`default_cache_dir`.
        use_cache: read and write the on-disk cache.
        mmap_bytes: learned codes larger than this are memory-mapped from the cache file
            (after learning too, once written) instead of held in memory.
        show_progress: tqdm progress bar while casting (off with ``$TQDM_DISABLE``).
        log: ``log(level, text)``; default: this module's logger.
        caster: a caster of this map and range to use (its unknown cells must stop rays
            exactly when ``unknown_blocks and not mark_unknown``); default: one made here.

    Raises:
        MapError: when the map has no valid tile.
        ValueError: on a bad parameter.
    """
    if not (np.isfinite(tile_size) and tile_size > 0.0):
        raise ValueError(f"tile_size must be positive, got {tile_size!r}")
    if angle_count < 4:
        raise ValueError(f"angle_count must be at least 4, got {angle_count!r}")
    if not (np.isfinite(max_range) and 0.0 < max_range <= _MAX_RANGE_M):
        raise ValueError(f"max_range must be in (0, {_MAX_RANGE_M}] m, got {max_range!r}")
    emit = log or (lambda level, text: _logger.log(logging.WARNING if level == "warn" else logging.INFO, text))
    start = time.perf_counter()
    grid = TileGrid.covering(grid_map, tile_size)
    key = _learning_key(grid_map, tile_size, angle_count, max_range, unknown_blocks, mark_unknown)
    path = Path(cache_dir) if cache_dir else default_cache_dir()
    path = path / "pil" / f"pil_{key}.npz"

    if use_cache:
        cached = load_cached(path, lambda file: _load_cache(file, key, grid, angle_count, mmap_bytes), what="PIL",
                             warn=lambda text: emit("warn", text), then="relearning and rewriting it")
        if cached is not None:
            cached.seconds = time.perf_counter() - start
            return cached

    tile_lines, tile_columns, centres = _valid_tiles(grid, grid_map)
    if tile_lines.size == 0:
        raise MapError(f"no PIL tile of {tile_size} m has its centre in free space on this map")
    stops = unknown_blocks and not mark_unknown
    if caster is None or caster.grid_map is not grid_map or caster.max_range != max_range or caster.unknown_stops != stops:
        caster = ClassifiedRayCaster(grid_map, max_range=max_range, unknown_stops=stops)
    angles = np.arange(angle_count) * (2.0 * np.pi / angle_count)
    codes = np.empty((tile_lines.size, angle_count), dtype=np.uint8)
    poses = np.zeros((_TILES_PER_CHUNK, 3))
    with ReportingBar(total=int(tile_lines.size), desc="PIL learning", unit="tile", disable=progress_disabled(show_progress),
              leave=False) as bar:
        for first in range(0, tile_lines.size, _TILES_PER_CHUNK):
            last = min(first + _TILES_PER_CHUNK, tile_lines.size)
            poses[: last - first, :2] = centres[first:last]
            ranges, outcome = caster.cast(poses[: last - first], angles)
            if mark_unknown:
                ranges[outcome == RAY_UNKNOWN] = np.nan  # else R, or where an unknown cell stopped it
            codes[first:last] = encode_ranges(ranges, max_range)
            bar.update(last - first)
    learning = PilLearning(grid, tile_lines, tile_columns, centres, codes, float(max_range), key)
    if use_cache:
        try:
            _save_cache(path, learning, _checksum(codes, tile_lines, tile_columns))
            prune_cache(path.parent, cache_budget_bytes(), keep=path, log=lambda text: emit("info", text))
            if codes.nbytes > mmap_bytes:  # the learned bytes now live in the cache file: map them instead
                mapped = npz_member_memmap(path, "codes")
                if mapped is not None:
                    learning.codes = mapped
                    learning.memory_mapped = True
                    del codes
        except OSError as exc:
            emit("warn", f"could not write the PIL cache {str(path)!r}: {exc}")
    learning.seconds = time.perf_counter() - start
    unknown = 100.0 * _unknown_share(learning.codes)
    emit("info", f"PIL learned {learning.tile_count} tiles x {angle_count} directions in {learning.seconds:.2f} s "
         f"({unknown:.1f} % of the rays unknown)")
    return learning


def _valid_tiles(grid: TileGrid, grid_map: GridMap) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.float64]]:
    """Lines, columns and centres of the tiles whose centre is in a free cell, line-major, without a full-grid array."""
    lines_out: list[NDArray[np.int32]] = []
    columns_out: list[NDArray[np.int32]] = []
    columns = np.arange(grid.columns)
    free = grid_map.free_mask
    for line in range(grid.lines):
        xy = grid.tile_to_world(np.column_stack([np.full(grid.columns, line), columns]))
        cells = grid_map.world_to_cell(xy)
        inside = grid_map.in_bounds(cells)
        valid = np.zeros(grid.columns, dtype=bool)
        valid[inside] = free[cells[inside, 1], cells[inside, 0]]
        if valid.any():
            found = np.flatnonzero(valid).astype(np.int32)
            lines_out.append(np.full(found.size, line, dtype=np.int32))
            columns_out.append(found)
    if not lines_out:
        return np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros((0, 2))
    tile_lines, tile_columns = np.concatenate(lines_out), np.concatenate(columns_out)
    return tile_lines, tile_columns, grid.tile_to_world(np.stack([tile_lines, tile_columns], axis=-1))


def _unknown_share(codes: NDArray[np.uint8]) -> float:
    total = unknown = 0
    for first in range(0, codes.shape[0], 1 << 14):
        block = np.asarray(codes[first : first + (1 << 14)])
        unknown += int(np.count_nonzero(block == CODE_UNKNOWN))
        total += block.size
    return unknown / max(total, 1)
