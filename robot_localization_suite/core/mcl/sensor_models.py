"""Laser sensor models for particle filters: the likelihood field and the beam model.

Both score many poses against one scan and return, per pose, the *sum over
beams of the log-likelihood* of the readings, so that callers choose how to
combine beams and compare scans through the per-beam mean.

Likelihood field (Thrun, Burgard & Fox, *Probabilistic Robotics*, table 6.3;
nav2_amcl ``LikelihoodFieldModel``): ``p = z_hit * exp(-d^2 / (2 sigma_hit^2))
+ z_rand / max_range`` for a reading ending ``d`` from the nearest obstacle
(``d`` capped at ``max_distance``; unnormalised, as nav2), ``log p``
precomputed per map cell. Only hits are scored.

Beam model (*Probabilistic Robotics* table 6.1; nav2 ``BeamModel``): the
expected range from the shared :class:`RayCaster`, nav2's unnormalised
mixture of hit, short, max and random components; no-returns are scored.

Formulas and notes: docs/mcl.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..grid_map import GridMap
from ..raycast import RayCaster

__all__ = ["LikelihoodFieldModel", "BeamModel", "PartialMapScores", "field_log_likelihood", "unjudged_beams"]


# Cells per block when a per-cell table is computed (float64 temporaries of about 8 MB each).
_TABLE_BLOCK_CELLS = 1 << 20


def _check_positive(name: str, value: float) -> None:
    if not np.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be positive and finite, got {value!r}")


def _check_weight(name: str, value: float) -> None:
    if not np.isfinite(value) or value < 0.0:
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")


@numba.njit(cache=True, nogil=True, inline="always")
def _end_cell(x, y, c, s, beam_x, beam_y, origin_x, origin_y, inverse_resolution):
    """A beam's end point from the laser pose (x, y, cos, sin), in grid coordinates [cells]."""
    return (x + c * beam_x - s * beam_y - origin_x) * inverse_resolution, \
        (y + s * beam_x + c * beam_y - origin_y) * inverse_resolution


@numba.njit(cache=True, nogil=True, fastmath=True)
def _field_sum_kernel(table, origin_x, origin_y, inverse_resolution, poses, beam_x, beam_y, beam_floor, off_map, out):
    height, width = table.shape
    for p in range(poses.shape[0]):
        x = poses[p, 0]
        y = poses[p, 1]
        c = math.cos(poses[p, 2])
        s = math.sin(poses[p, 2])
        total = 0.0
        for b in range(beam_x.shape[0]):
            ex, ey = _end_cell(x, y, c, s, beam_x[b], beam_y[b], origin_x, origin_y, inverse_resolution)
            ix = int(math.floor(ex))
            iy = int(math.floor(ey))
            value = table[iy, ix] if ix >= 0 and iy >= 0 and ix < width and iy < height else off_map
            total += max(value, beam_floor[b])
        out[p] = total


@numba.njit(cache=True, nogil=True, fastmath=True)
def _agreement_kernel(near, origin_x, origin_y, inverse_resolution, poses, weights, beam_x, beam_y, out):
    height, width = near.shape
    for b in range(beam_x.shape[0]):
        out[b] = 0.0
    for p in range(poses.shape[0]):
        x = poses[p, 0]
        y = poses[p, 1]
        c = math.cos(poses[p, 2])
        s = math.sin(poses[p, 2])
        for b in range(beam_x.shape[0]):
            ex, ey = _end_cell(x, y, c, s, beam_x[b], beam_y[b], origin_x, origin_y, inverse_resolution)
            ix = int(math.floor(ex))
            iy = int(math.floor(ey))
            if ix >= 0 and iy >= 0 and ix < width and iy < height and near[iy, ix]:
                out[b] += weights[p]


@numba.njit(cache=True, nogil=True)
def _ray_is_clear(occupied, clearance, inverse_resolution, x0, y0, x1, y1):
    """Whether the segment from (x0, y0) to (x1, y1) [cells] crosses no occupied cell before the end (it leaves
    the map clear). Sampled every half cell near obstacles; where ``clearance`` (the map's distance field [m]:
    from a cell centre to the nearest obstacle cell centre) is larger, the walk jumps by it less 1.5 cells,
    within which no occupied cell can lie (sphere tracing)."""
    height, width = occupied.shape
    length = math.hypot(x1 - x0, y1 - y0)
    if length <= 0.0:
        return True
    dx = (x1 - x0) / length
    dy = (y1 - y0) / length
    t = 0.0
    while t < length:
        ix = int(math.floor(x0 + t * dx))
        iy = int(math.floor(y0 + t * dy))
        if ix < 0 or iy < 0 or ix >= width or iy >= height:
            return True
        if occupied[iy, ix]:
            return False
        step = clearance[iy, ix] * inverse_resolution - 1.5
        t += step if step > 0.5 else 0.5
    return True


_KNOWN, _CREDITED, _THROUGH_WALL = 0, 1, 2


@numba.njit(cache=True, nogil=True, inline="always")
def _laser_at(poses, p, origin_x, origin_y, inverse_resolution):
    """Pose ``p``'s position [m], heading cosine and sine, and position in grid coordinates [cells]."""
    x = poses[p, 0]
    y = poses[p, 1]
    return x, y, math.cos(poses[p, 2]), math.sin(poses[p, 2]), (x - origin_x) * inverse_resolution, \
        (y - origin_y) * inverse_resolution


@numba.njit(cache=True, nogil=True, inline="always")
def _end_class(open_unknown, occupied, clearance, inverse_resolution, gx, gy, ex, ey):
    """What the map says of an end point (ex, ey) seen from (gx, gy) [cells]: ``_KNOWN`` on a known cell;
    ``_CREDITED`` in open unknown space or off the map, reached through no mapped obstacle (the map cannot
    judge it); ``_THROUGH_WALL`` there, but behind a mapped obstacle (no explanation)."""
    height, width = open_unknown.shape
    ix = int(math.floor(ex))
    iy = int(math.floor(ey))
    if ix >= 0 and iy >= 0 and ix < width and iy < height and not open_unknown[iy, ix]:
        return _KNOWN
    if _ray_is_clear(occupied, clearance, inverse_resolution, gx, gy, ex, ey):
        return _CREDITED
    return _THROUGH_WALL


@numba.njit(cache=True, nogil=True, fastmath=True)
def _partial_sum_kernel(table, credit, open_unknown, occupied, clearance, origin_x, origin_y, inverse_resolution,
                        poses, beam_x, beam_y, beam_floor, off_map, closed_off_map, out, unjudged_sum,
                        unjudged_count):
    """As _field_sum_kernel, but an end point in open unknown space (or off the map, ``off_map``) that the beam
    reaches through no mapped obstacle scores at least ``credit`` (else as the table says, or ``closed_off_map``).
    The credited beams (the map cannot judge them) are also summed and counted on their own, per pose."""
    height, width = table.shape
    for p in range(poses.shape[0]):
        x, y, c, s, gx, gy = _laser_at(poses, p, origin_x, origin_y, inverse_resolution)
        total = 0.0
        credited = 0.0
        credited_count = 0
        for b in range(beam_x.shape[0]):
            ex, ey = _end_cell(x, y, c, s, beam_x[b], beam_y[b], origin_x, origin_y, inverse_resolution)
            ix = int(math.floor(ex))
            iy = int(math.floor(ey))
            inside = ix >= 0 and iy >= 0 and ix < width and iy < height
            kind = _end_class(open_unknown, occupied, clearance, inverse_resolution, gx, gy, ex, ey)
            if kind == _KNOWN:
                total += max(table[iy, ix], beam_floor[b])
            elif kind == _CREDITED:
                value = max(max(table[iy, ix], credit) if inside else off_map, beam_floor[b])
                total += value
                credited += value
                credited_count += 1
            else:  # through a wall: the unknown space behind it is no explanation
                total += max(table[iy, ix] if inside else closed_off_map, beam_floor[b])
        out[p] = total
        unjudged_sum[p] = credited
        unjudged_count[p] = credited_count


@numba.njit(cache=True, nogil=True)
def _credited_kernel(open_unknown, occupied, clearance, origin_x, origin_y, inverse_resolution, poses, beam_x, beam_y,
                     out):
    for p in range(poses.shape[0]):
        x, y, c, s, gx, gy = _laser_at(poses, p, origin_x, origin_y, inverse_resolution)
        for b in range(beam_x.shape[0]):
            ex, ey = _end_cell(x, y, c, s, beam_x[b], beam_y[b], origin_x, origin_y, inverse_resolution)
            out[p, b] = _end_class(open_unknown, occupied, clearance, inverse_resolution, gx, gy, ex, ey) == _CREDITED


def unjudged_beams(grid_map: GridMap, poses: ArrayLike, angles: ArrayLike, ranges: ArrayLike) -> NDArray[np.bool_]:
    """``(P, B)`` per laser pose, whether the map cannot judge each reading's end point there: in open unknown space
    (``GridMap.open_unknown``) or off the map, reached through no mapped obstacle. These are the beams the
    likelihood field credits on a partial map (:meth:`LikelihoodFieldModel.partial_log_likelihood`)."""
    poses_arr = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
    beam_x, beam_y = _beam_offsets(angles, ranges)
    out = np.zeros((poses_arr.shape[0], beam_x.shape[0]), dtype=np.bool_)
    origin = grid_map.origin
    _credited_kernel(grid_map.open_unknown()[0], np.ascontiguousarray(grid_map.occupied_mask),
                     np.ascontiguousarray(grid_map.distance_field()), float(origin[0]), float(origin[1]),
                     1.0 / grid_map.resolution, poses_arr, beam_x, beam_y, out)
    return out


def _beam_offsets(angles: ArrayLike, ranges: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    angles_arr = np.asarray(angles, dtype=np.float64).reshape(-1)
    ranges_arr = np.asarray(ranges, dtype=np.float64).reshape(-1)
    return (np.ascontiguousarray(ranges_arr * np.cos(angles_arr)), np.ascontiguousarray(ranges_arr * np.sin(angles_arr)))


def field_log_likelihood(
    table: NDArray[np.float32],
    resolution: float,
    origin: tuple[float, float],
    poses: ArrayLike,
    angles: ArrayLike,
    ranges: ArrayLike,
    off_map: float,
    beam_floor: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Sum over beams of ``table`` at the beam endpoints (each at least its ``beam_floor``), for each pose.

    Args:
        table: ``(H, W)`` per-cell value (e.g. log-likelihood), row 0 at the origin.
        resolution: cell size [m]; origin: world ``(x, y)`` of cell (0, 0)'s corner [m].
        poses: ``(P, 3)`` sensor poses [m, m, rad].
        angles, ranges: ``(B,)`` beam angles [rad] and finite ranges [m] in the sensor frame.
        off_map: value of an endpoint outside the table.
        beam_floor: ``(B,)`` lowest value of each beam; None: no floor.

    Returns:
        ``(P,)`` sums.
    """
    poses_arr = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
    beam_x, beam_y = _beam_offsets(angles, ranges)
    floors = np.full(len(beam_x), -np.finfo(np.float64).max) if beam_floor is None \
        else np.ascontiguousarray(np.asarray(beam_floor, dtype=np.float64).reshape(-1))
    if floors.shape != beam_x.shape:
        raise ValueError(f"beam_floor must have one value per beam ({len(beam_x)}), got shape {floors.shape}")
    out = np.empty(poses_arr.shape[0], dtype=np.float64)
    _field_sum_kernel(
        np.ascontiguousarray(table, dtype=np.float32),
        float(origin[0]),
        float(origin[1]),
        1.0 / float(resolution),
        poses_arr,
        beam_x,
        beam_y,
        floors,
        float(off_map),
        out,
    )
    return out


@dataclass(frozen=True)
class PartialMapScores:
    """Per pose ``(P,)``: the summed beam log-likelihood with unknown space credited (``total``), and the sum
    and count of the credited beams, which the map cannot judge (``unjudged_sum``, ``unjudged_count``)."""

    total: NDArray[np.float64]
    unjudged_sum: NDArray[np.float64]
    unjudged_count: NDArray[np.int64]

    @property
    def judged_sum(self) -> NDArray[np.float64]:
        """Per pose, the summed log-likelihood of the beams the map judges."""
        return self.total - self.unjudged_sum


class LikelihoodFieldModel:
    """Likelihood-field laser model over one map (see the module docstring and docs/mcl.md).

    Args:
        grid_map: the map; obstacles are its occupied cells.
        z_hit: weight of the Gaussian around the nearest obstacle (nav2 ``z_hit``).
        z_rand: weight of the uniform random-reading component (nav2 ``z_rand``).
        sigma_hit: standard deviation of the hit Gaussian [m] (nav2 ``sigma_hit``).
        max_distance: cap on the endpoint-to-obstacle distance [m] (nav2 ``laser_likelihood_max_dist``).
        unknown_occupancy: probability that an unknown cell (or a point off the map) holds an obstacle,
            as the hit Gaussian sees it: with ``partial_map=True``, an end point in open unknown space
            (``GridMap.open_unknown``) that the beam reaches through no mapped obstacle scores at least
            ``unknown_occupancy`` of a mapped hit, one value for all of it (docs/mcl.md, "Partial maps");
            otherwise it scores by its distance to the nearest mapped obstacle, as nav2 does.
        unmapped_weight, unmapped_decay: an obstacle the map does not hold (a person, a box) in front of the
            laser: a reading at range ``r`` scores at least ``log(z_rand / max_range + unmapped_weight *
            unmapped_decay * exp(-unmapped_decay * r))``, the better of the two explanations (a max-mixture);
            weight 0: nav2's model [1, 1/m] (docs/mcl.md, "Unmapped obstacles").
    """

    def __init__(
        self,
        grid_map: GridMap,
        *,
        z_hit: float,
        z_rand: float,
        sigma_hit: float,
        max_distance: float,
        unknown_occupancy: float = 0.0,
        unmapped_weight: float = 0.0,
        unmapped_decay: float = 1.0,
    ) -> None:
        _check_weight("z_hit", z_hit)
        _check_weight("unmapped_weight", unmapped_weight)
        _check_positive("unmapped_decay", unmapped_decay)
        _check_weight("z_rand", z_rand)
        if z_hit + z_rand <= 0.0:
            raise ValueError(f"z_hit + z_rand must be positive, got {z_hit!r} + {z_rand!r}")
        _check_positive("sigma_hit", sigma_hit)
        _check_positive("max_distance", max_distance)
        if not 0.0 <= unknown_occupancy <= 1.0:
            raise ValueError(f"unknown_occupancy must be in [0, 1], got {unknown_occupancy!r}")
        self.grid_map = grid_map
        self.z_hit = float(z_hit)
        self.z_rand = float(z_rand)
        self.sigma_hit = float(sigma_hit)
        self.max_distance = float(max_distance)
        self.unknown_occupancy = float(unknown_occupancy)
        self.unmapped_weight = float(unmapped_weight)
        self.unmapped_decay = float(unmapped_decay)
        grid_map.distance_field()  # map setup: the field every table is made from
        far = math.exp(-(self.max_distance**2) / (2.0 * self.sigma_hit**2))
        self._off_map_hit_term = {False: self.z_hit * far}
        if self.unknown_occupancy > 0.0:
            _, open_off_map = grid_map.open_unknown()
            self._off_map_hit_term[True] = self.z_hit * (max(far, self.unknown_occupancy) if open_off_map else far)
        self._far_hit_term = self.z_hit * far
        self._occupied = np.ascontiguousarray(grid_map.occupied_mask)
        self._near: dict[float, NDArray[np.bool_]] = {}
        self._tables: dict[float, tuple[NDArray[np.float32], float]] = {}

    def floor_log_likelihood(self, max_range: float) -> float:
        """The lowest per-beam log-likelihood: a reading far from every obstacle."""
        return math.log(self._far_hit_term + self.z_rand / max_range)

    def beam_floors(self, ranges: ArrayLike, max_range: float) -> NDArray[np.float64]:
        """Per reading, its lowest log-likelihood: far from every mapped obstacle, explained at best by a random
        reading or by an unmapped obstacle at its range (``unmapped_weight``)."""
        ranges_arr = np.asarray(ranges, dtype=np.float64).reshape(-1)
        unmapped = self.unmapped_weight * self.unmapped_decay * np.exp(-self.unmapped_decay * ranges_arr)
        return np.log(self._far_hit_term + self.z_rand / max_range + unmapped)

    def table(self, max_range: float) -> tuple[NDArray[np.float32], float]:
        """Per-cell ``log p`` ``(H, W)`` and the off-map value for readings up to ``max_range`` [m]."""
        _check_positive("max_range", max_range)
        key = float(max_range)
        if key not in self._tables:
            # The table of one range only (the scanner's range_max is fixed): 4 bytes a cell.
            self._tables.clear()
            random_term = self.z_rand / key
            self._tables[key] = (self._log_table(random_term), math.log(self._off_map_hit_term[False] + random_term))
        return self._tables[key]

    def unknown_credit(self, max_range: float) -> tuple[float, float]:
        """With ``unknown_occupancy``: the least ``log p`` of an end point in open unknown space, as ``table``
        rounds it, and the value off the map, for readings up to ``max_range`` [m].

        One value for all of open unknown space, so no slope pulls end points into it. An end point there
        scores ``max(table, credit)``: what the table would hold with ``hit`` at least ``unknown_occupancy``,
        without a second map-sized table."""
        _check_positive("max_range", max_range)
        random_term = self.z_rand / float(max_range)
        credit = np.log(self.z_hit * np.array([self.unknown_occupancy]) + random_term).astype(np.float32)
        return float(credit[0]), math.log(self._off_map_hit_term[True] + random_term)

    def _log_table(self, random_term: float) -> NDArray[np.float32]:
        """``log(z_hit * hit + random_term)`` per cell, in blocks of rows: no float64 copy of a large map is held."""
        distance = self.grid_map.distance_field()
        table = np.empty(distance.shape, dtype=np.float32)
        rows = max(1, _TABLE_BLOCK_CELLS // max(1, distance.shape[1]))
        for start in range(0, distance.shape[0], rows):
            block = slice(start, start + rows)
            capped = np.minimum(distance[block], np.float32(self.max_distance)).astype(np.float64)
            hit = np.exp(-(capped**2) / (2.0 * self.sigma_hit**2))
            table[block] = np.log(self.z_hit * hit + random_term)
        return table

    def load_kernels(self) -> None:
        """Load the compiled scoring kernel now (map setup), on a one-cell table, not in the first update."""
        field_log_likelihood(np.zeros((1, 1), dtype=np.float32), self.grid_map.resolution, self.grid_map.origin,
                             np.zeros((1, 3)), np.zeros(1), np.ones(1), 0.0, np.zeros(1))

    def log_likelihood(
        self, poses: ArrayLike, angles: ArrayLike, ranges: ArrayLike, *, max_range: float, partial_map: bool = False
    ) -> NDArray[np.float64]:
        """Sum over beams of ``log p`` for each pose.

        Args:
            poses: ``(P, 3)`` laser poses in the map [m, m, rad].
            angles, ranges: ``(B,)`` hits only (finite ranges) [rad, m].
            max_range: the range that ``z_rand`` is spread over [m].
            partial_map: score end points in unknown space with ``unknown_occupancy``.

        Returns:
            ``(P,)`` summed per-beam log-likelihoods.
        """
        if not (partial_map and self.unknown_occupancy > 0.0):
            table, off_map = self.table(max_range)
            return field_log_likelihood(table, self.grid_map.resolution, self.grid_map.origin, poses, angles, ranges,
                                        off_map, self.beam_floors(ranges, max_range))
        return self.partial_log_likelihood(poses, angles, ranges, max_range=max_range).total

    def partial_log_likelihood(
        self, poses: ArrayLike, angles: ArrayLike, ranges: ArrayLike, *, max_range: float
    ) -> PartialMapScores:
        """``log_likelihood(..., partial_map=True)``, with the part of it the map cannot judge, per pose.

        The unjudged beams are those credited with ``unknown_occupancy``: end points in open unknown
        space or off the map that the beam reaches through no mapped obstacle (docs/mcl.md, "Partial maps").
        """
        if self.unknown_occupancy <= 0.0:
            raise ValueError("partial_log_likelihood needs unknown_occupancy > 0")
        table, closed_off_map = self.table(max_range)
        credit, off_map = self.unknown_credit(max_range)
        open_unknown, _ = self.grid_map.open_unknown()
        poses_arr = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        beam_x, beam_y = _beam_offsets(angles, ranges)
        out = np.empty(poses_arr.shape[0], dtype=np.float64)
        unjudged_sum = np.empty_like(out)
        unjudged_count = np.empty(poses_arr.shape[0], dtype=np.int64)
        origin = self.grid_map.origin
        _partial_sum_kernel(table, credit, open_unknown, self._occupied,
                            np.ascontiguousarray(self.grid_map.distance_field()), float(origin[0]), float(origin[1]),
                            1.0 / self.grid_map.resolution, poses_arr, beam_x, beam_y,
                            self.beam_floors(ranges, max_range), float(off_map),
                            float(closed_off_map), out, unjudged_sum, unjudged_count)
        return PartialMapScores(out, unjudged_sum, unjudged_count)

    def beam_agreement(
        self, poses: ArrayLike, weights: ArrayLike, angles: ArrayLike, ranges: ArrayLike, *, distance: float
    ) -> NDArray[np.float64]:
        """Per beam ``(B,)``: the weight of the poses whose end point lies within ``distance`` [m] of a mapped obstacle.

        nav2_amcl's beam skipping counts particles; here they are weighted.
        """
        key = float(distance)
        if key not in self._near:
            self._near.clear()
            self._near[key] = np.ascontiguousarray(self.grid_map.distance_field() <= key)
        poses_arr = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        weights_arr = np.ascontiguousarray(np.asarray(weights, dtype=np.float64).reshape(-1))
        beam_x, beam_y = _beam_offsets(angles, ranges)
        out = np.empty(beam_x.shape[0], dtype=np.float64)
        origin = self.grid_map.origin
        _agreement_kernel(self._near[key], float(origin[0]), float(origin[1]), 1.0 / self.grid_map.resolution,
                          poses_arr, weights_arr, beam_x, beam_y, out)
        return out


class BeamModel:
    """Beam (ray-casting) laser model over one map (see the module docstring and docs/mcl.md).

    Args:
        grid_map: the map.
        z_hit, z_short, z_max, z_rand: mixture weights (nav2 names).
        sigma_hit: standard deviation of the hit Gaussian [m].
        lambda_short: decay of the short-reading exponential [1/m].
        unknown_blocks: whether unknown cells stop the expected ray.
    """

    def __init__(
        self,
        grid_map: GridMap,
        *,
        z_hit: float,
        z_short: float,
        z_max: float,
        z_rand: float,
        sigma_hit: float,
        lambda_short: float,
        unknown_blocks: bool = False,
    ) -> None:
        for name, value in (("z_hit", z_hit), ("z_short", z_short), ("z_max", z_max), ("z_rand", z_rand)):
            _check_weight(name, value)
        if z_hit + z_short + z_max + z_rand <= 0.0:
            raise ValueError("beam model weights z_hit + z_short + z_max + z_rand must be positive")
        _check_positive("sigma_hit", sigma_hit)
        _check_positive("lambda_short", lambda_short)
        self.grid_map = grid_map
        self.z_hit, self.z_short, self.z_max, self.z_rand = float(z_hit), float(z_short), float(z_max), float(z_rand)
        self.sigma_hit = float(sigma_hit)
        self.lambda_short = float(lambda_short)
        self.unknown_blocks = bool(unknown_blocks)
        self._casters: dict[float, RayCaster] = {}

    def floor_log_likelihood(self, max_range: float) -> float:
        """A lower bound of the per-beam log-likelihood of a hit (only the random component)."""
        return math.log(max(self.z_rand / max_range, 1e-300))

    def _caster(self, max_range: float) -> RayCaster:
        key = float(max_range)
        if key not in self._casters:
            self._casters.clear()
            self._casters[key] = RayCaster(self.grid_map, max_range=key, unknown_blocks=self.unknown_blocks)
        return self._casters[key]

    def log_likelihood(
        self, poses: ArrayLike, angles: ArrayLike, ranges: ArrayLike, *, max_range: float
    ) -> NDArray[np.float64]:
        """Sum over beams of ``log p`` for each pose.

        Args:
            poses: ``(P, 3)`` laser poses [m, m, rad].
            angles: ``(B,)`` beam angles [rad].
            ranges: ``(B,)`` hits (finite, < max_range) or ``inf`` for no-returns [m].
            max_range: the sensor's maximum range [m].
        """
        _check_positive("max_range", max_range)
        ranges_arr = np.asarray(ranges, dtype=np.float64).reshape(-1)
        no_return = ~np.isfinite(ranges_arr) | (ranges_arr >= max_range)
        measured = np.where(no_return, max_range, ranges_arr)
        expected = self._caster(max_range).cast(np.asarray(poses, dtype=np.float64).reshape(-1, 3), angles)
        expected = np.where(np.isfinite(expected), expected, np.float32(max_range)).astype(np.float64)
        error = measured[None, :] - expected
        p = self.z_hit * np.exp(-(error**2) / (2.0 * self.sigma_hit**2))
        short = (measured[None, :] < expected) * (self.lambda_short * np.exp(-self.lambda_short * measured))[None, :]
        p += self.z_short * short
        p += np.where(no_return, self.z_max, self.z_rand / max_range)[None, :]
        return np.log(np.maximum(p, 1e-300)).sum(axis=1)
