"""The one ray caster: many poses x many beams through an occupancy grid.

Grid traversal is Amanatides & Woo's DDA ("A fast voxel traversal algorithm
for ray tracing", Eurographics 1987), compiled with numba. The returned range
is the distance from the ray origin to where the ray enters the first blocking
cell, which is exact for the cell boundaries of the map.

"No hit" is explicit: a ray that reaches ``max_range`` or leaves the map
without meeting a blocking cell returns ``inf``, never a magic range. A ray
starting inside a blocking cell returns 0.

Parallelism: a numba ``prange`` over poses for large batches; small batches run
on one thread because a parallel launch costs milliseconds here.

Open space (optional, ``skip_free_space``): a ray may jump ahead by the chessboard
distance to the nearest blocking cell less one, since every cell it would cross
there is free; ranges equal the plain traversal's except for rays through exact
cell corners (a tie either side may take). It pays off on large, open maps
(outdoors most rays run to ``max_range``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .grid_map import GridMap

__all__ = ["RayCaster", "cast_rays", "free_space_skip"]

# Below this many rays a single thread is faster than a parallel launch.
_PARALLEL_MIN_RAYS = 20_000


@numba.njit(cache=True, nogil=True, fastmath=False)
def _cast_one(
    blocking: np.ndarray,
    x0: float,
    y0: float,
    angle: float,
    max_cells: float,
) -> float:
    """Distance in cells to the first blocking cell along a ray, or inf."""
    height, width = blocking.shape
    ix = int(math.floor(x0))
    iy = int(math.floor(y0))
    if ix < 0 or iy < 0 or ix >= width or iy >= height:
        return math.inf
    if blocking[iy, ix]:
        return 0.0
    dx = math.cos(angle)
    dy = math.sin(angle)
    if dx > 0.0:
        step_x = 1
        t_max_x = (ix + 1.0 - x0) / dx
        t_delta_x = 1.0 / dx
    elif dx < 0.0:
        step_x = -1
        t_max_x = (x0 - ix) / -dx
        t_delta_x = -1.0 / dx
    else:
        step_x = 0
        t_max_x = math.inf
        t_delta_x = math.inf
    if dy > 0.0:
        step_y = 1
        t_max_y = (iy + 1.0 - y0) / dy
        t_delta_y = 1.0 / dy
    elif dy < 0.0:
        step_y = -1
        t_max_y = (y0 - iy) / -dy
        t_delta_y = -1.0 / dy
    else:
        step_y = 0
        t_max_y = math.inf
        t_delta_y = math.inf
    while True:
        if t_max_x < t_max_y:
            t = t_max_x
            ix += step_x
            t_max_x += t_delta_x
        else:
            t = t_max_y
            iy += step_y
            t_max_y += t_delta_y
        if t > max_cells:
            return math.inf
        if ix < 0 or iy < 0 or ix >= width or iy >= height:
            return math.inf
        if blocking[iy, ix]:
            return t


@numba.njit(cache=True, nogil=True)
def _cast_one_skip(skip, x0, y0, angle, max_cells):
    """As :func:`_cast_one`, jumping through open space: ``skip`` is the chessboard distance [cells]
    from each cell to the nearest blocking one (:func:`free_space_skip`; 0: the cell blocks)."""
    height, width = skip.shape
    dx = math.cos(angle)
    dy = math.sin(angle)
    t = 0.0
    while True:
        x = x0 + t * dx
        y = y0 + t * dy
        ix = int(math.floor(x))
        iy = int(math.floor(y))
        if ix < 0 or iy < 0 or ix >= width or iy >= height:
            return math.inf
        k = skip[iy, ix]
        if k == 0:
            return t
        if k >= 3:
            # Any point of this cell moved by k - 1 cells stays within chessboard distance k - 1 of it: all free.
            t += k - 1.0
            if t > max_cells:
                return math.inf
            continue
        # Plain traversal from (x, y) until a blocking cell, or a cell from which a jump pays off.
        if dx > 0.0:
            step_x = 1
            t_max_x = t + (ix + 1.0 - x) / dx
            t_delta_x = 1.0 / dx
        elif dx < 0.0:
            step_x = -1
            t_max_x = t + (x - ix) / -dx
            t_delta_x = -1.0 / dx
        else:
            step_x = 0
            t_max_x = math.inf
            t_delta_x = math.inf
        if dy > 0.0:
            step_y = 1
            t_max_y = t + (iy + 1.0 - y) / dy
            t_delta_y = 1.0 / dy
        elif dy < 0.0:
            step_y = -1
            t_max_y = t + (y - iy) / -dy
            t_delta_y = -1.0 / dy
        else:
            step_y = 0
            t_max_y = math.inf
            t_delta_y = math.inf
        while True:
            if t_max_x < t_max_y:
                t = t_max_x
                ix += step_x
                t_max_x += t_delta_x
            else:
                t = t_max_y
                iy += step_y
                t_max_y += t_delta_y
            if t > max_cells:
                return math.inf
            if ix < 0 or iy < 0 or ix >= width or iy >= height:
                return math.inf
            k = skip[iy, ix]
            if k == 0:
                return t
            if k >= 3:
                # Jump from where the ray entered this cell (on its boundary), as above.
                t += k - 1.0
                if t > max_cells:
                    return math.inf
                break


@numba.njit(cache=True, nogil=True)
def free_space_skip(blocking):
    """Chessboard distance [cells] from each cell to the nearest blocking one, capped at 255 (``uint8``)."""
    height, width = blocking.shape
    out = np.empty((height, width), dtype=np.uint8)
    for iy in range(height):
        for ix in range(width):
            if blocking[iy, ix]:
                out[iy, ix] = 0
                continue
            best = 255
            if iy > 0:
                best = min(best, out[iy - 1, ix] + 1)
                if ix > 0:
                    best = min(best, out[iy - 1, ix - 1] + 1)
                if ix + 1 < width:
                    best = min(best, out[iy - 1, ix + 1] + 1)
            if ix > 0:
                best = min(best, out[iy, ix - 1] + 1)
            out[iy, ix] = best
    for iy in range(height - 1, -1, -1):
        for ix in range(width - 1, -1, -1):
            best = int(out[iy, ix])
            if best == 0:
                continue
            if iy + 1 < height:
                best = min(best, out[iy + 1, ix] + 1)
                if ix > 0:
                    best = min(best, out[iy + 1, ix - 1] + 1)
                if ix + 1 < width:
                    best = min(best, out[iy + 1, ix + 1] + 1)
            if ix + 1 < width:
                best = min(best, out[iy, ix + 1] + 1)
            out[iy, ix] = best
    return out


@numba.njit(cache=True, nogil=True)
def _cast_serial(blocking, origin_x, origin_y, resolution, poses, angles, max_range, out):
    max_cells = max_range / resolution
    for p in range(poses.shape[0]):
        x0 = (poses[p, 0] - origin_x) / resolution
        y0 = (poses[p, 1] - origin_y) / resolution
        for b in range(angles.shape[0]):
            out[p, b] = _cast_one(blocking, x0, y0, poses[p, 2] + angles[b], max_cells) * resolution


@numba.njit(cache=True, nogil=True, parallel=True)
def _cast_parallel(blocking, origin_x, origin_y, resolution, poses, angles, max_range, out):
    max_cells = max_range / resolution
    for p in numba.prange(poses.shape[0]):
        x0 = (poses[p, 0] - origin_x) / resolution
        y0 = (poses[p, 1] - origin_y) / resolution
        for b in range(angles.shape[0]):
            out[p, b] = _cast_one(blocking, x0, y0, poses[p, 2] + angles[b], max_cells) * resolution


@numba.njit(cache=True, nogil=True)
def _cast_serial_skip(skip, origin_x, origin_y, resolution, poses, angles, max_range, out):
    max_cells = max_range / resolution
    for p in range(poses.shape[0]):
        x0 = (poses[p, 0] - origin_x) / resolution
        y0 = (poses[p, 1] - origin_y) / resolution
        for b in range(angles.shape[0]):
            out[p, b] = _cast_one_skip(skip, x0, y0, poses[p, 2] + angles[b], max_cells) * resolution


@numba.njit(cache=True, nogil=True, parallel=True)
def _cast_parallel_skip(skip, origin_x, origin_y, resolution, poses, angles, max_range, out):
    max_cells = max_range / resolution
    for p in numba.prange(poses.shape[0]):
        x0 = (poses[p, 0] - origin_x) / resolution
        y0 = (poses[p, 1] - origin_y) / resolution
        for b in range(angles.shape[0]):
            out[p, b] = _cast_one_skip(skip, x0, y0, poses[p, 2] + angles[b], max_cells) * resolution


def cast_rays(
    blocking: NDArray[np.bool_] | NDArray[np.uint8],
    resolution: float,
    origin: tuple[float, float],
    poses: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    *,
    parallel: bool | None = None,
    skip: NDArray[np.uint8] | None = None,
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
        skip: :func:`free_space_skip` of ``blocking``, to jump through open space (the same ranges but
            for rays through exact cell corners, which may pass either side).

    Returns:
        ``(P, B)`` ranges [m] (``(B,)`` for a single pose), ``inf`` where nothing is hit.
    """
    poses_arr = np.asarray(poses, dtype=np.float64)
    single = poses_arr.ndim == 1
    poses_arr = np.ascontiguousarray(poses_arr.reshape(-1, 3))
    angles_arr = np.ascontiguousarray(np.asarray(angles, dtype=np.float64).reshape(-1))
    if max_range <= 0.0 or not np.isfinite(max_range):
        raise ValueError(f"max_range must be positive and finite, got {max_range!r}")
    grid = np.ascontiguousarray(blocking, dtype=np.uint8)
    out = np.empty((poses_arr.shape[0], angles_arr.shape[0]), dtype=np.float32)
    if parallel is None:
        parallel = out.size >= _PARALLEL_MIN_RAYS
    args = (float(origin[0]), float(origin[1]), float(resolution), poses_arr, angles_arr, float(max_range), out)
    if skip is None:
        (_cast_parallel if parallel else _cast_serial)(grid, *args)
    else:
        if skip.shape != grid.shape or skip.dtype != np.uint8:
            raise ValueError(f"skip must be a uint8 array of shape {grid.shape}, got {skip.dtype} {skip.shape}")
        (_cast_parallel_skip if parallel else _cast_serial_skip)(np.ascontiguousarray(skip), *args)
    return out[0] if single else out


class RayCaster:
    """Ray casting against one :class:`GridMap`.

    Args:
        grid_map: the map.
        max_range: longest range reported [m].
        unknown_blocks: whether unknown cells stop rays (a conservative choice for
            maps built by SLAM, whose unknown cells are often unseen walls).
        skip_free_space: jump through open space (one more byte a cell; the same ranges but for
            rays through exact cell corners; faster where rays are long).
    """

    def __init__(
        self, grid_map: GridMap, *, max_range: float, unknown_blocks: bool = False, skip_free_space: bool = False
    ) -> None:
        self.grid_map = grid_map
        self.max_range = float(max_range)
        mask = grid_map.occupied_mask
        if unknown_blocks:
            mask = mask | grid_map.unknown_mask
        self._blocking = np.ascontiguousarray(mask, dtype=np.uint8)
        self._skip = free_space_skip(self._blocking) if skip_free_space else None

    def cast(self, poses: ArrayLike, angles: ArrayLike, *, parallel: bool | None = None) -> NDArray[np.float32]:
        """Ranges ``(P, B)`` [m] from ``poses`` ``(P, 3)`` along ``angles`` ``(B,)``; ``inf`` = no hit."""
        return cast_rays(
            self._blocking,
            self.grid_map.resolution,
            self.grid_map.origin,
            poses,
            angles,
            self.max_range,
            parallel=parallel,
            skip=self._skip,
        )
