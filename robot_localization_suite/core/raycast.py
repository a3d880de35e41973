"""The one ray caster: many poses x many beams through an occupancy grid.

Grid traversal is Amanatides & Woo's DDA ("A fast voxel traversal algorithm
for ray tracing", Eurographics 1987), compiled with numba. The returned range
is the distance from the ray origin to where the ray enters the first blocking
cell, which is exact for the cell boundaries of the map.

"No hit" is explicit: a ray that reaches ``max_range`` or leaves the map
without meeting a blocking cell returns ``inf``, never a magic range. A ray
starting inside a blocking cell returns 0.

Open space (:func:`clearance_codes`, optional for :class:`RayCaster`, always on
for :class:`ClassifiedRayCaster`): a ray jumps ahead by the clearance from its cell
to the nearest cell that could end it, less a margin, and restarts the DDA there,
which never skips a cell the plain traversal would stop in. It pays off on large,
open maps (outdoors most rays run to ``max_range``). One kernel serves both front
ends; :class:`RayCaster` ignores how a ray ended.

Parallelism: a numba ``prange`` over blocks of poses for large batches; small
batches run on one thread because a parallel launch costs milliseconds here.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .grid_map import GridMap

__all__ = [
    "RayCaster",
    "cast_rays",
    "ClassifiedRayCaster",
    "clearance_codes",
    "RAY_HIT",
    "RAY_FREE",
    "RAY_UNKNOWN",
]

# Below this many rays a single thread is faster than a parallel launch.
_PARALLEL_MIN_RAYS = 20_000

#: How a ray ended (:class:`ClassifiedRayCaster`).
RAY_HIT = 0  #: entered an occupied cell within range (its range is finite)
RAY_FREE = 1  #: crossed known free cells only, up to the range limit (a no-return the map vouches for)
RAY_UNKNOWN = 2  #: met an unknown cell or left the map first (the map does not know what it would read)

# One byte per cell: 0 occupied, 1 unknown, 2 + c free, c the distance [cells, floored, at most 253]
# from the cell's centre to the nearest non-free cell centre or the map border (c = 0 without the
# open-space jump); and, for the jump only, a second byte: the distance [cells, floored, at most 255]
# to the nearest occupied cell centre or the border.
_CODE_OCCUPIED, _CODE_UNKNOWN, _CODE_FREE = 0, 1, 2
# Any point of a free cell whose centre is c cells from the nearest non-free cell centre is at least
# c - sqrt(2) cells from any point of a non-free cell: a jump along the ray that enters no such cell.
_SKIP_MARGIN_CELLS = math.sqrt(2.0) + 0.05
_SKIP_MIN_CELLS = 2.0
# Poses cast together, every direction for all of them in turn: neighbouring rays share cache lines.
_POSES_PER_BLOCK = 16


# Inlined with ``jumps`` a constant: the plain traversal then costs what it did without the jump.
@numba.njit(cache=True, nogil=True, inline="always")
def _cast_one(codes, to_occupied, x0, y0, angle, max_cells, unknown_stops, jumps):
    """``(distance [cells], outcome)`` of one ray: Amanatides & Woo's DDA, with ``jumps`` through open space.

    ``codes``/``to_occupied``: :func:`clearance_codes` (``to_occupied`` is read only with
    ``jumps``). Until the ray has met an unknown cell it jumps by the clearance to non-free
    cells (it must see every unknown cell); after, only a hit can change its outcome, and it
    jumps by the clearance to occupied cells.
    """
    height, width = codes.shape
    ix = int(math.floor(x0))
    iy = int(math.floor(y0))
    if ix < 0 or iy < 0 or ix >= width or iy >= height:
        return math.inf, RAY_UNKNOWN
    code = codes[iy, ix]
    if code == _CODE_OCCUPIED:
        return 0.0, RAY_HIT
    touched_unknown = False
    if code == _CODE_UNKNOWN:
        if unknown_stops:
            return 0.0, RAY_UNKNOWN
        touched_unknown = True
    dx = math.cos(angle)
    dy = math.sin(angle)
    t = 0.0
    px, py = x0, y0
    while True:
        # DDA state from the point (px, py), at distance t along the ray, inside cell (ix, iy).
        if dx > 0.0:
            step_x = 1
            t_max_x = t + (ix + 1.0 - px) / dx
            t_delta_x = 1.0 / dx
        elif dx < 0.0:
            step_x = -1
            t_max_x = t + (px - ix) / -dx
            t_delta_x = -1.0 / dx
        else:
            step_x = 0
            t_max_x = math.inf
            t_delta_x = math.inf
        if dy > 0.0:
            step_y = 1
            t_max_y = t + (iy + 1.0 - py) / dy
            t_delta_y = 1.0 / dy
        elif dy < 0.0:
            step_y = -1
            t_max_y = t + (py - iy) / -dy
            t_delta_y = -1.0 / dy
        else:
            step_y = 0
            t_max_y = math.inf
            t_delta_y = math.inf
        while True:
            if jumps:
                if touched_unknown:
                    jump = to_occupied[iy, ix] - _SKIP_MARGIN_CELLS
                elif code >= _CODE_FREE:
                    jump = (code - _CODE_FREE) - _SKIP_MARGIN_CELLS
                else:
                    jump = 0.0
                if jump >= _SKIP_MIN_CELLS:
                    # No cell that could end the ray (nor the map border) within `jump` of any point of
                    # this cell: move on along the ray and restart the DDA from there.
                    t += jump
                    if t > max_cells:
                        return math.inf, (RAY_UNKNOWN if touched_unknown else RAY_FREE)
                    px = x0 + t * dx
                    py = y0 + t * dy
                    ix = int(math.floor(px))
                    iy = int(math.floor(py))
                    code = codes[iy, ix]
                    break
            if t_max_x < t_max_y:
                t = t_max_x
                ix += step_x
                t_max_x += t_delta_x
            else:
                t = t_max_y
                iy += step_y
                t_max_y += t_delta_y
            if t > max_cells:
                return math.inf, (RAY_UNKNOWN if touched_unknown else RAY_FREE)
            if ix < 0 or iy < 0 or ix >= width or iy >= height:
                return math.inf, RAY_UNKNOWN
            code = codes[iy, ix]
            if code == _CODE_OCCUPIED:
                return t, RAY_HIT
            if code == _CODE_UNKNOWN:
                if unknown_stops:
                    return t, RAY_UNKNOWN
                touched_unknown = True


@numba.njit(cache=True, nogil=True)
def _cast_block(codes, to_occupied, origin_x, origin_y, resolution, poses, angles, max_cells, unknown_stops, jumps,
                first, last, out, outcome):
    # Two loops, so that each inlines _cast_one with constant flags. Without jumps the codes hold no
    # unknown cell (:class:`RayCaster` folds ``unknown_blocks`` into them), so ``unknown_stops`` is moot.
    if jumps:
        for b in range(angles.shape[0]):
            for p in range(first, last):
                x0 = (poses[p, 0] - origin_x) / resolution
                y0 = (poses[p, 1] - origin_y) / resolution
                t, kind = _cast_one(codes, to_occupied, x0, y0, poses[p, 2] + angles[b], max_cells, unknown_stops, True)
                out[p, b] = t * resolution
                outcome[p, b] = kind
    else:
        for p in range(first, last):
            x0 = (poses[p, 0] - origin_x) / resolution
            y0 = (poses[p, 1] - origin_y) / resolution
            for b in range(angles.shape[0]):
                t, kind = _cast_one(codes, to_occupied, x0, y0, poses[p, 2] + angles[b], max_cells, False, False)
                out[p, b] = t * resolution
                outcome[p, b] = kind


@numba.njit(cache=True, nogil=True, parallel=True)
def _cast_parallel(codes, to_occupied, origin_x, origin_y, resolution, poses, angles, max_range, unknown_stops, jumps,
                   out, outcome):
    max_cells = max_range / resolution
    blocks = (poses.shape[0] + _POSES_PER_BLOCK - 1) // _POSES_PER_BLOCK
    for k in numba.prange(blocks):
        first = k * _POSES_PER_BLOCK
        last = min(first + _POSES_PER_BLOCK, poses.shape[0])
        _cast_block(codes, to_occupied, origin_x, origin_y, resolution, poses, angles, max_cells, unknown_stops, jumps,
                    first, last, out, outcome)


@numba.njit(cache=True, nogil=True)
def _cast_serial(codes, to_occupied, origin_x, origin_y, resolution, poses, angles, max_range, unknown_stops, jumps,
                 out, outcome):
    max_cells = max_range / resolution
    for first in range(0, poses.shape[0], _POSES_PER_BLOCK):
        last = min(first + _POSES_PER_BLOCK, poses.shape[0])
        _cast_block(codes, to_occupied, origin_x, origin_y, resolution, poses, angles, max_cells, unknown_stops, jumps,
                    first, last, out, outcome)


_NO_TABLE = np.zeros((1, 1), dtype=np.uint8)


def _cast(
    codes: NDArray[np.uint8],
    to_occupied: NDArray[np.uint8] | None,
    resolution: float,
    origin: tuple[float, float],
    poses: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    unknown_stops: bool,
    parallel: bool | None,
) -> tuple[NDArray[np.float32], NDArray[np.uint8], bool]:
    """Ranges ``(P, B)``, outcomes ``(P, B)`` and whether a single pose was given; jumps iff ``to_occupied``."""
    if max_range <= 0.0 or not np.isfinite(max_range):
        raise ValueError(f"max_range must be positive and finite, got {max_range!r}")
    poses_arr = np.asarray(poses, dtype=np.float64)
    single = poses_arr.ndim == 1
    poses_arr = np.ascontiguousarray(poses_arr.reshape(-1, 3))
    angles_arr = np.ascontiguousarray(np.asarray(angles, dtype=np.float64).reshape(-1))
    out = np.empty((poses_arr.shape[0], angles_arr.shape[0]), dtype=np.float32)
    outcome = np.empty(out.shape, dtype=np.uint8)
    if parallel is None:
        parallel = out.size >= _PARALLEL_MIN_RAYS
    kernel = _cast_parallel if parallel else _cast_serial
    jumps = to_occupied is not None
    kernel(codes, to_occupied if to_occupied is not None else _NO_TABLE, float(origin[0]), float(origin[1]),
           float(resolution), poses_arr, angles_arr, float(max_range), bool(unknown_stops), jumps, out, outcome)
    return out, outcome, single


def _plain_codes(blocking: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """:func:`clearance_codes`' first byte without clearances: 0 where ``blocking``, free elsewhere."""
    return np.where(blocking, np.uint8(_CODE_OCCUPIED), np.uint8(_CODE_FREE))


def cast_rays(
    blocking: NDArray[np.bool_] | NDArray[np.uint8],
    resolution: float,
    origin: tuple[float, float],
    poses: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    *,
    parallel: bool | None = None,
) -> NDArray[np.float32]:
    """Cast ``len(angles)`` rays from each pose.

    Args:
        blocking: ``(height, width)`` mask of cells that stop a ray (row 0 at the origin), bool or 0/1 uint8.
        resolution: cell size [m].
        origin: world ``(x, y)`` of the corner of cell (0, 0) [m].
        poses: ``(P, 3)`` or ``(3,)`` ray origins and headings [m, m, rad].
        angles: ``(B,)`` beam angles relative to each pose's heading [rad].
        max_range: longest range reported [m]; farther hits are ``inf``.
        parallel: force or forbid threads; by default threads for large batches.

    Returns:
        ``(P, B)`` ranges [m] (``(B,)`` for a single pose), ``inf`` where nothing is hit.
    """
    codes = _plain_codes(np.asarray(blocking).astype(bool, copy=False))
    out, _, single = _cast(codes, None, resolution, origin, poses, angles, max_range, False, parallel)
    return out[0] if single else out


class RayCaster:
    """Ray casting against one :class:`GridMap`.

    Args:
        grid_map: the map.
        max_range: longest range reported [m].
        unknown_blocks: whether unknown cells stop rays (a conservative choice for
            maps built by SLAM, whose unknown cells are often unseen walls).
        skip_free_space: jump through open space (:func:`clearance_codes`: one more byte a
            cell and two distance transforms when made; the same ranges but for rays
            through exact cell corners; faster where rays are long).
    """

    def __init__(
        self, grid_map: GridMap, *, max_range: float, unknown_blocks: bool = False, skip_free_space: bool = False
    ) -> None:
        self.grid_map = grid_map
        self.max_range = float(max_range)
        self.unknown_blocks = bool(unknown_blocks)
        self._to_occupied: NDArray[np.uint8] | None
        if skip_free_space:
            self._codes, self._to_occupied = clearance_codes(grid_map)
        else:
            mask = grid_map.occupied_mask
            if unknown_blocks:
                mask = mask | grid_map.unknown_mask
            self._codes, self._to_occupied = _plain_codes(mask), None

    def cast(self, poses: ArrayLike, angles: ArrayLike, *, parallel: bool | None = None) -> NDArray[np.float32]:
        """Ranges ``(P, B)`` [m] from ``poses`` ``(P, 3)`` along ``angles`` ``(B,)``; ``inf`` = no hit."""
        out, _, single = _cast(self._codes, self._to_occupied, self.grid_map.resolution, self.grid_map.origin, poses,
                               angles, self.max_range, self.unknown_blocks, parallel)
        return out[0] if single else out


# -- rays that say how they ended -------------------------------------------------------------------
def _clearance(mask: NDArray[np.bool_], ceiling: float) -> NDArray[np.float32]:
    """Distance [cells] from each cell centre to the nearest centre outside ``mask`` or the map border, at most ``ceiling``."""
    from .edt import distance_to_marked

    outside = np.ones((mask.shape[0] + 2, mask.shape[1] + 2), dtype=bool)
    outside[1:-1, 1:-1] = ~mask  # the border ring stands for the space off the map
    field_cells = distance_to_marked(outside)[1:-1, 1:-1]
    np.minimum(field_cells, ceiling, out=field_cells)
    return field_cells


def clearance_codes(grid_map: GridMap) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """The two bytes per cell of :class:`ClassifiedRayCaster`.

    First: 0 occupied, 1 unknown, ``2 + c`` free, ``c`` the distance [cells, floored, at
    most 253] from the cell's centre to the nearest non-free cell centre. Second: the
    distance [cells, floored, at most 255] to the nearest occupied cell centre. The map
    border counts as both (the fields are computed with a ring of such cells around the
    map), so no jump leaves the map.
    """
    free = grid_map.free_mask
    occupied = grid_map.occupied_mask
    codes = np.where(occupied, _CODE_OCCUPIED, _CODE_UNKNOWN).astype(np.uint8)
    codes[free] = _clearance(free, 253.0)[free].astype(np.uint8) + _CODE_FREE  # floored: never more than the distance
    to_occupied = _clearance(~occupied, 255.0).astype(np.uint8)
    return codes, to_occupied


class ClassifiedRayCaster:
    """Ray casting that says how each ray ended (:data:`RAY_HIT`, :data:`RAY_FREE`, :data:`RAY_UNKNOWN`).

    The DDA of :class:`RayCaster` (a hit's range is where the ray enters the occupied
    cell), sped up through open space by jumping ahead by the clearance to the nearest
    non-free cell, which never skips a cell the plain DDA would stop in. Leaving the map
    before the range limit counts as unknown. Two bytes per map cell
    (:func:`clearance_codes`).

    Args:
        grid_map: the map.
        max_range: longest range [m].
        unknown_stops: an unknown cell ends the ray as unknown (True), or the ray goes on
            through it and is unknown only if it then hits nothing within range (False).
    """

    def __init__(self, grid_map: GridMap, *, max_range: float, unknown_stops: bool = True) -> None:
        if max_range <= 0.0 or not np.isfinite(max_range):
            raise ValueError(f"max_range must be positive and finite, got {max_range!r}")
        self.grid_map = grid_map
        self.max_range = float(max_range)
        self.unknown_stops = bool(unknown_stops)
        self._codes, self._to_occupied = clearance_codes(grid_map)

    @property
    def nbytes(self) -> int:
        return int(self._codes.nbytes + self._to_occupied.nbytes)

    def cast(
        self, poses: ArrayLike, angles: ArrayLike, *, parallel: bool | None = None
    ) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
        """Ranges ``(P, B)`` [m] and outcomes ``(P, B)`` of rays from ``poses`` ``(P, 3)`` along ``angles`` ``(B,)``.

        A range is where the ray entered the occupied cell (:data:`RAY_HIT`) or, with
        ``unknown_stops``, the unknown cell that stopped it (:data:`RAY_UNKNOWN`); ``inf``
        otherwise (nothing within range, or the ray left the map).
        """
        out, outcome, single = _cast(self._codes, self._to_occupied, self.grid_map.resolution, self.grid_map.origin,
                                     poses, angles, self.max_range, self.unknown_stops, parallel)
        return (out[0], outcome[0]) if single else (out, outcome)
