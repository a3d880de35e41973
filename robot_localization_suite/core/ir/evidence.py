"""What a scan's end points say about a pose on a partial map: IR's evidence with unknown space neutral.

An end point in an unknown cell or off the map is *neutral*: the map cannot say whether something
is there, so it scores what an end point scores by chance on this map (its *chance level*), never
as a miss. An end point in known free space far from every mapped obstacle is a miss whose cost is
bounded by a robust mixture (``outlier_share``), so that unmapped objects cannot outweigh the beams
the map explains. Used by step 2 (:mod:`.query`), the ranking of refined candidates
(:mod:`.global_fix`) and the tracker's end-point score (:mod:`.localizer`). Notes: docs/ir.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..grid_map import GridMap

__all__ = ["OCCUPIED", "UNKNOWN", "NEAR", "MapEvidence", "cell_flags"]

#: Bits of :func:`cell_flags` (one byte a cell): an obstacle, an unknown cell, a cell near an obstacle.
OCCUPIED, UNKNOWN, NEAR = 1, 2, 4


def cell_flags(grid_map: GridMap, near: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """``(H, W)`` :data:`OCCUPIED`, :data:`UNKNOWN` and :data:`NEAR` (from ``near``) bits per cell."""
    flags = np.where(grid_map.occupied_mask, np.uint8(OCCUPIED), np.uint8(0))
    unknown = grid_map.data < 0
    unknown |= grid_map.data > grid_map.free_threshold
    unknown &= grid_map.data < grid_map.occupied_threshold
    flags[unknown] |= UNKNOWN
    del unknown
    flags[near] |= NEAR
    return flags


@numba.njit(cache=True, nogil=True)
def _cell_of(flags, x, y, ox, oy, res):
    """Cell (row, column) of a world point, or (-1, -1) off the map."""
    ix = int(math.floor((x - ox) / res))
    iy = int(math.floor((y - oy) / res))
    if ix < 0 or iy < 0 or iy >= flags.shape[0] or ix >= flags.shape[1]:
        return -1, -1
    return iy, ix


@numba.njit(cache=True, nogil=True)
def _likelihood_ratios(flags, distance, ox, oy, res, poses, bx, by, inv_two_sigma2, outlier, chance, neutral, through,
                       out):
    """Mean log likelihood ratio per pose of the end points ``(bx, by)`` (laser frame) against chance;
    a beam marked in ``through`` (``(K, B)``, or ``(0, 0)``: none) scores the mixture's floor."""
    beams = bx.shape[0]
    reference = outlier + (1.0 - outlier) * chance
    floor = math.log(outlier / reference)
    marked = through.shape[0] > 0
    for k in range(poses.shape[0]):
        c, s = math.cos(poses[k, 2]), math.sin(poses[k, 2])
        total = 0.0
        for b in range(beams):
            if marked and through[k, b]:
                total += floor  # it passed through a mapped obstacle: the map does not explain it
                continue
            px = poses[k, 0] + c * bx[b] - s * by[b]
            py = poses[k, 1] + s * bx[b] + c * by[b]
            iy, ix = _cell_of(flags, px, py, ox, oy, res)
            if iy < 0:
                weight = 0.0
                known = False
            else:
                d = distance[iy, ix]
                weight = math.exp(-d * d * inv_two_sigma2)
                known = (flags[iy, ix] & 2) == 0
            ratio = math.log((outlier + (1.0 - outlier) * weight) / reference)
            if neutral and not known and ratio < 0.0:
                ratio = 0.0  # unknown space or off the map: never evidence against the pose
            total += ratio
        out[k] = total / max(beams, 1)


@numba.njit(cache=True, nogil=True)
def _hit_fractions(flags, ox, oy, res, poses, bx, by, chance, neutral, out):
    """Per pose: fraction of end points on cells near an obstacle; unknown / off-map ones count ``chance`` if neutral."""
    beams = bx.shape[0]
    for k in range(poses.shape[0]):
        c, s = math.cos(poses[k, 2]), math.sin(poses[k, 2])
        total = 0.0
        for b in range(beams):
            px = poses[k, 0] + c * bx[b] - s * by[b]
            py = poses[k, 1] + s * bx[b] + c * by[b]
            iy, ix = _cell_of(flags, px, py, ox, oy, res)
            if iy >= 0 and (flags[iy, ix] & 4) != 0:
                total += 1.0
            elif neutral and (iy < 0 or (flags[iy, ix] & 2) != 0):
                total += chance
        out[k] = total / max(beams, 1)


@numba.njit(cache=True, nogil=True)
def _chance_sums(flags, distance, inv_two_sigma2):
    """Over known cells: count, summed end-point weight, count of cells near an obstacle."""
    count = 0
    weight = 0.0
    hits = 0
    for iy in range(flags.shape[0]):
        for ix in range(flags.shape[1]):
            if (flags[iy, ix] & 2) == 0:
                d = distance[iy, ix]
                count += 1
                weight += math.exp(-d * d * inv_two_sigma2)
                if (flags[iy, ix] & 4) != 0:
                    hits += 1
    return count, weight, hits


@dataclass(frozen=True)
class MapEvidence:
    """The map as IR's scores read it: cell flags, distances to obstacles, chance levels.

    Attributes:
        flags: ``(H, W)`` :func:`cell_flags`; :data:`NEAR`: within ``tolerance`` of an obstacle (the tracker's hits).
        distance: ``(H, W)`` distance [m] from each cell centre to the nearest occupied one.
        origin: ``(x, y)`` of the lower left map corner [m].
        resolution: cell size [m].
        sigma: width of the end-point weight ``exp(-d^2 / 2 sigma^2)`` [m].
        chance_weight: mean end-point weight over the known cells: what an end point dropped
            anywhere on the mapped area scores by chance.
        chance_hit: share of known cells within ``tolerance`` of an occupied cell.
    """

    flags: NDArray[np.uint8]
    distance: NDArray[np.float32]
    origin: tuple[float, float]
    resolution: float
    sigma: float
    chance_weight: float
    chance_hit: float

    @classmethod
    def from_map(cls, grid_map: GridMap, *, sigma: float, tolerance: float) -> MapEvidence:
        """The evidence of ``grid_map`` for end-point weights of width ``sigma`` [m] and hits within ``tolerance`` [m]."""
        distance = np.ascontiguousarray(grid_map.distance_field(), dtype=np.float32)
        near = distance <= tolerance + 1e-6 if tolerance > 0.0 else grid_map.occupied_mask
        flags = cell_flags(grid_map, near)
        del near
        count, weight, hits = _chance_sums(flags, distance, 1.0 / (2.0 * sigma * sigma))
        return cls(
            flags=flags,
            distance=distance,
            origin=(float(grid_map.origin[0]), float(grid_map.origin[1])),
            resolution=float(grid_map.resolution),
            sigma=float(sigma),
            chance_weight=float(weight / count) if count else 0.0,
            chance_hit=float(hits / count) if count else 0.0,
        )

    def known(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Whether world points ``(..., 2)`` fall in known (free or occupied) cells on the map."""
        pts = np.asarray(points, dtype=np.float64)
        cells = np.floor((pts - np.asarray(self.origin)) / self.resolution).astype(np.int64)
        height, width = self.flags.shape
        inside = (cells[..., 0] >= 0) & (cells[..., 0] < width) & (cells[..., 1] >= 0) & (cells[..., 1] < height)
        out = np.zeros(inside.shape, dtype=bool)
        out[inside] = (self.flags[cells[..., 1][inside], cells[..., 0][inside]] & UNKNOWN) == 0
        return out

    def likelihood_ratios(
        self,
        poses: ArrayLike,
        angles: ArrayLike,
        ranges: ArrayLike,
        *,
        outlier_share: float,
        neutral_unknown: bool = True,
        through: NDArray[np.bool_] | None = None,
    ) -> NDArray[np.float64]:
        """Mean log likelihood ratio per pose of its end points, against chance on this map.

        Each end point ``i`` at distance ``d_i`` from the nearest obstacle has the likelihood
        ``e + (1 - e) exp(-d_i^2 / 2 sigma^2)`` (``e`` = ``outlier_share``: the share of beams the
        map does not explain, which bounds what one such beam costs); chance is the same with the
        weight at :attr:`chance_weight`. With ``neutral_unknown`` an end point in an unknown cell
        or off the map counts at least as chance (ratio 0). A beam marked in ``through`` reached past
        a mapped obstacle, wherever it ends: it scores ``e`` alone, as a beam the map does not explain.

        Args:
            poses: ``(K, 3)`` laser poses [m, m, rad].
            angles, ranges: ``(B,)`` the scan's hits in the laser frame [rad, m].
            through: ``(K, B)`` beams that passed through a mapped obstacle at each pose, or None.

        Returns:
            ``(K,)`` mean log ratios [nats per beam]; 0 for a scan without hits.
        """
        poses = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        angles = np.asarray(angles, dtype=np.float64)
        ranges = np.asarray(ranges, dtype=np.float64)
        out = np.zeros(len(poses))
        if through is not None and np.shape(through) != (len(poses), ranges.size):
            raise ValueError(f"through must be (poses, beams) = {(len(poses), ranges.size)}, got {np.shape(through)}")
        if len(poses) == 0 or ranges.size == 0:
            return out
        _likelihood_ratios(
            self.flags, self.distance, self.origin[0], self.origin[1], self.resolution, poses,
            np.ascontiguousarray(ranges * np.cos(angles)), np.ascontiguousarray(ranges * np.sin(angles)),
            1.0 / (2.0 * self.sigma * self.sigma), float(outlier_share), self.chance_weight, bool(neutral_unknown),
            np.zeros((0, 0), dtype=np.bool_) if through is None else np.ascontiguousarray(through, dtype=np.bool_), out,
        )
        return out

    def hit_fractions(
        self, poses: ArrayLike, angles: ArrayLike, ranges: ArrayLike, *, neutral_unknown: bool = True
    ) -> NDArray[np.float64]:
        """Per pose, the fraction of end points within the tolerance of an occupied cell (section IV-C-2).

        With ``neutral_unknown`` an end point in an unknown cell or off the map counts
        :attr:`chance_hit` (neither hit nor miss); without it, a miss (the paper's vote).
        """
        poses = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        angles = np.asarray(angles, dtype=np.float64)
        ranges = np.asarray(ranges, dtype=np.float64)
        out = np.zeros(len(poses))
        if len(poses) == 0 or ranges.size == 0:
            return out
        _hit_fractions(
            self.flags, self.origin[0], self.origin[1], self.resolution, poses,
            np.ascontiguousarray(ranges * np.cos(angles)), np.ascontiguousarray(ranges * np.sin(angles)),
            self.chance_hit, bool(neutral_unknown), out,
        )
        return out
