"""PIL off-line learning (Lambert et al. 2020, section 2.2), its tile grid and its on-disk cache.

The map is covered by a grid of square tiles of side ``r``; a tile is valid
when its centre falls in a free cell. A simulated robot at the centre of every
valid tile, heading 0, measures the range along ``angle_count`` evenly spaced
directions with the shared :class:`~robot_localization_suite.core.raycast.RayCaster`
(finer than the ``N_s`` sensors, over the full circle); intensities are
equation (2), ``I = 1 - D_s / R``, derived from ranges stored as ``uint16``
millimetres. The transform ``M`` of equation (1) puts tile centres on integers.

Cache: ``$RLS_CACHE_DIR`` (or ``~/.cache/robot_localization_suite``)
``/pil/pil_<map fingerprint>_<parameter hash>.npz``, written atomically,
rebuilt when unreadable, kept within the budget of :mod:`..cache`.

Notes (the choices the paper leaves open): docs/pil.md.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from ..cache import cache_budget_bytes, default_cache_dir, load_cached, prune_cache
from ..errors import CacheError, MapError
from ..grid_map import GridMap
from ..progress import progress_disabled
from ..raycast import RayCaster

__all__ = ["TileGrid", "PilLearning", "learn_pseudo_images", "default_cache_dir", "LEARNING_VERSION"]

# Bump when the learned content changes meaning, so that old cache files are not reused.
LEARNING_VERSION = 1
_MM_PER_M = 1000.0
_MAX_STORABLE_RANGE_M = 65.0  # uint16 millimetres
_TILES_PER_CHUNK = 256

_logger = logging.getLogger(__name__)


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
        ranges_mm: ``(T, J)`` ``D_s`` [mm] along world angles ``j * 2 pi / J`` from each tile centre, capped at R.
        max_range: ``R`` [m].
        key: the cache key (map fingerprint + parameter hash).
        seconds: how long learning (or loading) took [s].
        from_cache: whether this was loaded from disk.
    """

    grid: TileGrid
    tile_lines: NDArray[np.int32]
    tile_columns: NDArray[np.int32]
    tile_centres: NDArray[np.float64]
    ranges_mm: NDArray[np.uint16]
    max_range: float
    key: str
    seconds: float = 0.0
    from_cache: bool = False
    _intensities: NDArray[np.float32] | None = field(default=None, repr=False)
    _spectra: tuple[NDArray[np.complex64], NDArray[np.complex64]] | None = field(default=None, repr=False)

    @property
    def tile_count(self) -> int:
        return int(self.tile_lines.size)

    @property
    def angle_count(self) -> int:
        return int(self.ranges_mm.shape[1])

    @property
    def angle_step(self) -> float:
        """Spacing of the learned directions [rad]."""
        return 2.0 * np.pi / self.angle_count

    @property
    def intensities(self) -> NDArray[np.float32]:
        """``I = 1 - D_s / R`` ``(T, J)`` (equation 2)."""
        if self._intensities is None:
            scale = np.float32(1.0 / (_MM_PER_M * self.max_range))
            self._intensities = np.float32(1.0) - self.ranges_mm.astype(np.float32) * scale
        return self._intensities

    @property
    def spectra(self) -> tuple[NDArray[np.complex64], NDArray[np.complex64]]:
        """``(rfft(I), rfft(I^2))`` ``(T, J // 2 + 1)`` of every tile's profile, for the theta correlation.

        Computed once per learning (derived data, not cached on disk): the on-line
        correlation then needs one inverse FFT per candidate instead of three FFTs.
        """
        if self._spectra is None:
            intensities = self.intensities
            spectrum = np.empty((self.tile_count, self.angle_count // 2 + 1), dtype=np.complex64)
            spectrum_sq = np.empty_like(spectrum)
            for first in range(0, self.tile_count, 4096):
                block = intensities[first : first + 4096].astype(np.float64)
                spectrum[first : first + 4096] = np.fft.rfft(block, axis=1)
                spectrum_sq[first : first + 4096] = np.fft.rfft(block * block, axis=1)
            self._spectra = (spectrum, spectrum_sq)
        return self._spectra

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


def _learning_key(grid_map: GridMap, tile_size: float, angle_count: int, max_range: float, unknown_blocks: bool) -> str:
    params = {
        "version": LEARNING_VERSION,
        "tile_size": round(float(tile_size), 9),
        "angle_count": int(angle_count),
        "max_range": round(float(max_range), 9),
        "unknown_blocks": bool(unknown_blocks),
        "occupied_threshold": int(grid_map.occupied_threshold),
        "free_threshold": int(grid_map.free_threshold),
    }
    params_hash = hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()[:16]
    return f"{grid_map.fingerprint()}_{params_hash}"


def _load_cache(path: Path, key: str, grid: TileGrid, angle_count: int) -> PilLearning:
    """Read a cache file; raise :class:`CacheError` naming what is wrong."""
    try:
        with np.load(path, allow_pickle=False) as archive:
            stored_key = str(archive["key"])
            lines = np.asarray(archive["tile_lines"], dtype=np.int32)
            columns = np.asarray(archive["tile_columns"], dtype=np.int32)
            ranges_mm = np.asarray(archive["ranges_mm"])
            max_range = float(archive["max_range"])
            checksum = str(archive["checksum"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise CacheError(f"PIL cache {str(path)!r} is unreadable: {type(exc).__name__}: {exc}") from exc
    if stored_key != key:
        raise CacheError(f"PIL cache {str(path)!r} holds key {stored_key!r}, expected {key!r}")
    if ranges_mm.dtype != np.uint16 or ranges_mm.ndim != 2 or ranges_mm.shape != (lines.size, angle_count):
        raise CacheError(
            f"PIL cache {str(path)!r} holds ranges of shape {ranges_mm.shape!r} / {ranges_mm.dtype}, "
            f"expected ({lines.size}, {angle_count}) uint16"
        )
    if lines.size and (lines.min() < 0 or lines.max() >= grid.lines or columns.min() < 0 or columns.max() >= grid.columns):
        raise CacheError(f"PIL cache {str(path)!r} holds tiles outside the {grid.lines} x {grid.columns} grid")
    if _checksum(ranges_mm, lines, columns) != checksum:
        raise CacheError(f"PIL cache {str(path)!r} fails its checksum")
    centres = grid.tile_to_world(np.stack([lines, columns], axis=-1))
    return PilLearning(grid, lines, columns, centres, ranges_mm, max_range, key, from_cache=True)


def _checksum(ranges_mm: NDArray[np.uint16], lines: NDArray[np.int32], columns: NDArray[np.int32]) -> str:
    digest = hashlib.sha256()
    for array in (ranges_mm, lines, columns):
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:32]


def _save_cache(path: Path, learning: PilLearning) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp_name = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            np.savez(
                stream,
                key=np.array(learning.key),
                tile_lines=learning.tile_lines,
                tile_columns=learning.tile_columns,
                ranges_mm=learning.ranges_mm,
                max_range=np.array(learning.max_range),
                checksum=np.array(_checksum(learning.ranges_mm, learning.tile_lines, learning.tile_columns)),
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
    cache_dir: str | os.PathLike[str] | None = None,
    use_cache: bool = True,
    show_progress: bool = True,
    log: Callable[[str, str], None] | None = None,
) -> PilLearning:
    """Learn (or load from the cache) the pseudo-images of ``grid_map`` (section 2.2).

    Args:
        grid_map: the map.
        tile_size: ``r`` [m].
        angle_count: learned directions over the full circle (``N_s``-derived, upsampled).
        max_range: ``R`` [m], at most 65 m (ranges are stored in uint16 millimetres).
        unknown_blocks: whether unknown cells stop the learning rays.
        cache_dir: cache directory; ``None``: :func:`default_cache_dir`.
        use_cache: read and write the on-disk cache.
        show_progress: tqdm progress bar while casting.
        log: ``log(level, text)``; default: this module's logger.

    Raises:
        MapError: when the map has no valid tile.
        ValueError: on a bad parameter.
    """
    if not (np.isfinite(tile_size) and tile_size > 0.0):
        raise ValueError(f"tile_size must be positive, got {tile_size!r}")
    if angle_count < 4:
        raise ValueError(f"angle_count must be at least 4, got {angle_count!r}")
    if not (np.isfinite(max_range) and 0.0 < max_range <= _MAX_STORABLE_RANGE_M):
        raise ValueError(f"max_range must be in (0, {_MAX_STORABLE_RANGE_M}] m, got {max_range!r}")
    emit = log or (lambda level, text: _logger.log(logging.WARNING if level == "warn" else logging.INFO, text))
    start = time.perf_counter()
    grid = TileGrid.covering(grid_map, tile_size)
    key = _learning_key(grid_map, tile_size, angle_count, max_range, unknown_blocks)
    path = Path(cache_dir) if cache_dir else default_cache_dir()
    path = path / "pil" / f"pil_{key}.npz"

    if use_cache:
        cached = load_cached(path, lambda file: _load_cache(file, key, grid, angle_count), what="PIL",
                             warn=lambda text: emit("warn", text), then="relearning and rewriting it")
        if cached is not None:
            cached.seconds = time.perf_counter() - start
            return cached

    lines, columns, centres = grid.all_centres()
    valid = grid_map.is_free(centres)
    if not valid.any():
        raise MapError(f"no PIL tile of {tile_size} m has its centre in free space on this map")
    tile_lines, tile_columns, centres = lines[valid].astype(np.int32), columns[valid].astype(np.int32), centres[valid]
    caster = RayCaster(grid_map, max_range=max_range, unknown_blocks=unknown_blocks)
    angles = np.arange(angle_count) * (2.0 * np.pi / angle_count)
    poses = np.column_stack([centres, np.zeros(len(centres))])
    ranges_mm = np.empty((len(centres), angle_count), dtype=np.uint16)
    with tqdm(total=len(centres), desc="PIL learning", unit="tile", disable=progress_disabled(show_progress),
              leave=False) as bar:
        for first in range(0, len(centres), _TILES_PER_CHUNK):
            chunk = slice(first, min(first + _TILES_PER_CHUNK, len(centres)))
            ranges = caster.cast(poses[chunk], angles)
            np.minimum(ranges, max_range, out=ranges)  # inf (no hit within R) reads R
            ranges_mm[chunk] = np.rint(ranges * _MM_PER_M).astype(np.uint16)
            bar.update(chunk.stop - chunk.start)
    learning = PilLearning(grid, tile_lines, tile_columns, centres, ranges_mm, float(max_range), key)
    if use_cache:
        try:
            _save_cache(path, learning)
            prune_cache(path.parent, cache_budget_bytes(), keep=path, log=lambda text: emit("info", text))
        except OSError as exc:
            emit("warn", f"could not write the PIL cache {str(path)!r}: {exc}")
    learning.seconds = time.perf_counter() - start
    emit("info", f"PIL learned {learning.tile_count} tiles x {angle_count} directions in {learning.seconds:.2f} s")
    return learning
