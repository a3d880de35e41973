"""PIL on-line matching (Lambert et al. 2020, sections 2.4-2.5) and what this package adds to it.

Pieces, in the order a query uses them:

* :class:`SensorLayout`: the ``N_s`` sensors over the field of view and the finer
  learned directions around the full circle.
* :class:`BeamMapping`: live beams -> ``N_s`` sensors, ``"nearest"`` (default)
  or ``"sector_min"``; a sensor with no valid beam is invalid (zero weight).
* :func:`rank_tiles`: equation (4) and a ranking of every tile from the level
  functions (one compiled pass over the tiles and heading sheets);
  :class:`LevelIndex` gives the same best-ranked and passing tiles visiting only
  the blocks of tiles whose level-function bounds can hold them.
* :func:`cost_table`: the cost of every learned byte for every live sensor: a
  truncated squared difference, lower for a reading shorter than learned (an
  unmapped obstacle in front), a constant for a ray the map cannot predict.
* :func:`correlate_tiles`: theta of many candidate tiles at once, coarse to fine:
  every heading at the sensor step with a subset of the sensors (abandoning a
  heading once it cannot enter the best ones), then the best hypotheses at the
  learned step with every sensor.

Notes (the reading of the paper's correlation, measured figures): docs/pil.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from ..errors import ScanError
from ..scan import Scan
from ..se2 import wrap_angle
from .settings import BEAM_MAPPINGS

__all__ = [
    "SensorLayout",
    "BeamMapping",
    "LiveProfile",
    "rank_tiles",
    "LevelIndex",
    "RankedTiles",
    "select_ranked",
    "encode_features",
    "decode_features",
    "term_tables",
    "FEATURE_LEVELS",
    "FEATURE_MISSING",
    "cost_table",
    "profile_costs",
    "correlate_tiles",
    "Hypotheses",
    "BEAM_MAPPINGS",
    "check_live_profile",
    "sheet_sectors",
]

_TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class SensorLayout:
    """``N_s`` sensors over a field of view, and the learned directions over the full circle.

    Attributes:
        field_of_view: angular span the sensors cover [rad], at most 2 pi.
        sensor_count: ``N_s``.
        upsampling: learned directions per sensor step of ``N_s`` sensors around the full
            circle: the learned angular step is about ``2 pi / (N_s * upsampling)`` whatever the
            field of view (:attr:`directions_per_sensor` is what a sensor step spans).
    """

    field_of_view: float
    sensor_count: int
    upsampling: int

    def __post_init__(self) -> None:
        if not (np.isfinite(self.field_of_view) and 0.0 < self.field_of_view <= _TWO_PI + 1e-9):
            raise ValueError(f"field_of_view must be in (0, 2 pi] rad, got {self.field_of_view!r}")
        if self.sensor_count < 4:
            raise ValueError(f"sensor_count must be at least 4, got {self.sensor_count!r}")
        if self.upsampling < 1:
            raise ValueError(f"upsampling must be at least 1, got {self.upsampling!r}")

    @property
    def full_circle(self) -> bool:
        return self.field_of_view >= _TWO_PI - 1e-6

    @property
    def circle_sensors(self) -> int:
        """Sensors that would fill the full circle at this spacing."""
        if self.full_circle:
            return self.sensor_count
        return max(self.sensor_count, int(round(_TWO_PI * self.sensor_count / self.field_of_view)))

    @property
    def sensor_spacing(self) -> float:
        """``Delta``: angle between neighbouring sensors [rad]."""
        return _TWO_PI / self.circle_sensors

    @property
    def directions_per_sensor(self) -> int:
        """Learned directions per sensor step: ``upsampling`` for 360 degrees, fewer for denser sensors."""
        return max(1, int(round(self.upsampling * self.sensor_count / self.circle_sensors)))

    @property
    def angle_count(self) -> int:
        """Learned directions over the full circle."""
        return self.circle_sensors * self.directions_per_sensor

    def sensor_angles(self, scan: Scan) -> NDArray[np.float64]:
        """Sensor angles ``(N_s,)`` in the laser frame [rad] for this scan's beams.

        360 degrees: ``angle_min + k Delta``. Limited FOV: centred on the scan's
        middle angle, ``centre + (k - (N_s - 1) / 2) Delta``.
        """
        k = np.arange(self.sensor_count, dtype=np.float64)
        if self.full_circle:
            return scan.angles[0] + k * self.sensor_spacing
        centre = 0.5 * (scan.angles[0] + scan.angles[-1])
        return centre + (k - 0.5 * (self.sensor_count - 1)) * self.sensor_spacing


@dataclass(frozen=True)
class LiveProfile:
    """The live scan as ``N_s`` sensors (equation 3).

    Attributes:
        intensities: ``(N_s,)`` ``I = 1 - min(D, R) / R``; 0 where invalid.
        valid: ``(N_s,)`` sensors that received a valid beam.
        sensor_angles: ``(N_s,)`` laser-frame angles of the sensors [rad].
    """

    intensities: NDArray[np.float64]
    valid: NDArray[np.bool_]
    sensor_angles: NDArray[np.float64]

    @property
    def weights(self) -> NDArray[np.float64]:
        return self.valid.astype(np.float64)


class BeamMapping:
    """Assignment of a scan geometry's beams to the ``N_s`` sensors (docs/pil.md, "On-line matching").

    Built once per scan geometry (angle_min, increment, beam count) and reused.
    """

    def __init__(self, layout: SensorLayout, scan: Scan, mode: str) -> None:
        if mode not in BEAM_MAPPINGS:
            raise ValueError(f"beam mapping must be one of {BEAM_MAPPINGS}, got {mode!r}")
        self.mode = mode
        self.geometry = (float(scan.angles[0]), float(scan.angles[-1]), scan.beam_count)
        self.sensor_angles = layout.sensor_angles(scan)
        half = 0.5 * layout.sensor_spacing + 1e-9
        offsets = np.abs(wrap_angle(scan.angles[None, :] - self.sensor_angles[:, None]))
        distance = np.where(offsets <= half, offsets, np.inf)
        width = max(1, int(np.isfinite(distance).sum(axis=1).max()))
        order = np.argsort(distance, axis=1, kind="stable")[:, :width]
        self.beams = np.where(np.isfinite(np.take_along_axis(distance, order, axis=1)), order, -1)

    def matches(self, scan: Scan) -> bool:
        return self.geometry == (float(scan.angles[0]), float(scan.angles[-1]), scan.beam_count)

    def profile(self, scan: Scan, max_range: float) -> LiveProfile:
        """Sensor intensities of ``scan``; no-returns and hits beyond ``R`` read ``R``."""
        clean = np.minimum(scan.clean_ranges(), max_range)  # NaN stays NaN (invalid), inf -> R
        padded = np.append(clean, np.nan)  # index -1 -> NaN
        candidates = padded[self.beams]  # (N_s, width), nearest beam first
        usable = ~np.isnan(candidates)
        valid = usable.any(axis=1)
        if self.mode == "nearest":
            first = np.argmax(usable, axis=1)
            ranges = candidates[np.arange(len(first)), first]
        else:
            ranges = np.where(usable, candidates, np.inf).min(axis=1)
        intensities = np.where(valid, 1.0 - np.where(valid, ranges, max_range) / max_range, 0.0)
        return LiveProfile(intensities, valid, self.sensor_angles)


def sheet_sectors(layout: SensorLayout, first_sensor_angle: float, headings: int) -> NDArray[np.int64]:
    """Learned-direction indices ``(S, n)`` each heading sheet sees.

    360 degrees: one sheet, every direction. Limited FOV: ``S = K`` sheets;
    sheet j covers the ``N_s * directions_per_sensor`` directions from half a sensor step
    before ``h_j + phi_0`` (``phi_0`` the first sensor's angle).
    """
    n = layout.angle_count
    if layout.full_circle:
        return np.arange(n, dtype=np.int64)[None, :]
    step = _TWO_PI / n
    span = layout.sensor_count * layout.directions_per_sensor
    sheets = []
    for j in range(headings):
        start = int(round((_TWO_PI * j / headings + first_sensor_angle) / step)) - layout.directions_per_sensor // 2
        sheets.append((start + np.arange(span)) % n)
    return np.asarray(sheets, dtype=np.int64)


#: A level function's byte: ``round(I_n * FEATURE_LEVELS)`` (every function here lies in [0, 1]) ...
FEATURE_LEVELS = 254
#: ... or this where a sheet has too few known rays for it.
FEATURE_MISSING = 255


def encode_features(values: NDArray[np.floating]) -> NDArray[np.uint8]:
    """Bytes of level-function values in [0, 1] (NaN: :data:`FEATURE_MISSING`); steps of 1/254 <= sigma_n / 5."""
    scaled = np.rint(np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0) * FEATURE_LEVELS)
    return np.where(np.isnan(scaled), FEATURE_MISSING, scaled).astype(np.uint8)


def decode_features(codes: NDArray[np.uint8]) -> NDArray[np.float64]:
    values = codes.astype(np.float64) / FEATURE_LEVELS
    values[codes == FEATURE_MISSING] = np.nan
    return values


def term_tables(
    live: NDArray[np.float64], alphas: NDArray[np.float64], sigmas: NDArray[np.float64], term_cap: float
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """``(F, 256)`` ranking term ``min((alpha_n |I_n - E_n| / sigma_n)^2, cap)`` and equation (4)'s
    ``alpha_n |I_n - E_n| < sigma_n`` for every feature byte (a missing one: the cap, not passing)."""
    values = np.arange(256, dtype=np.float64) / FEATURE_LEVELS
    scaled = np.abs(values[None, :] - np.asarray(live, dtype=np.float64)[:, None]) * (
        np.asarray(alphas) / np.asarray(sigmas)
    )[:, None]
    cap = float(term_cap) if np.isfinite(term_cap) else 3.4e38
    terms = np.minimum(scaled * scaled, cap).astype(np.float32)
    inside = scaled < 1.0
    terms[:, FEATURE_MISSING] = np.float32(cap)
    inside[:, FEATURE_MISSING] = False
    return terms, inside


def rank_tiles(
    features: NDArray[np.uint8],
    live: NDArray[np.float64],
    alphas: NDArray[np.float64],
    sigmas: NDArray[np.float64],
    term_cap: float = np.inf,
) -> tuple[NDArray[np.bool_], NDArray[np.float32]]:
    """Equation (4) and a ranking from the same terms, for every tile.

    Args:
        features: ``(T, S, F)`` learned ``I_n`` per tile and sheet, bytes of :func:`encode_features`.
        live: ``(F,)`` live ``E_n``.
        alphas, sigmas: ``(F,)``.
        term_cap: each function's term of the ranking is capped at this, so that one
            function thrown off by an unlearned obstacle (a person next to the robot
            moves the near-range quantile a lot) cannot push the true tile out.

    Returns:
        ``passes`` ``(T,)``: ``AND_n alpha_n |I_n - E_n| < sigma_n`` on at least one sheet (the
        binary image of equation 4), and ``rank`` ``(T,)``: ``min over sheets of
        sum_n min((alpha_n |I_n - E_n| / sigma_n)^2, term_cap)`` (smaller is more alike; a missing
        feature counts as the cap).
    """
    tiles = features.shape[0]
    if features.shape[2] == 0:
        return np.ones(tiles, dtype=bool), np.zeros(tiles, dtype=np.float32)
    passes = np.empty(tiles, dtype=np.bool_)
    rank = np.empty(tiles, dtype=np.float32)
    terms, inside = term_tables(live, alphas, sigmas, term_cap)
    _rank_kernel(features, terms, inside, passes, rank)
    return passes, rank


@numba.njit(cache=True, nogil=True)
def _tile_rank(features, t, terms, inside):
    sheets, functions = features.shape[1], features.shape[2]
    best = np.inf
    passed = False
    for s in range(sheets):
        total = 0.0
        all_inside = True
        for f in range(functions):
            code = features[t, s, f]
            total += terms[f, code]
            all_inside = all_inside and inside[f, code]
        best = min(best, total)
        passed = passed or all_inside
    return best, passed


@numba.njit(cache=True, nogil=True)
def _rank_kernel(features, terms, inside, passes, rank):
    for t in range(features.shape[0]):
        rank[t], passes[t] = _tile_rank(features, t, terms, inside)


@dataclass(frozen=True)
class RankedTiles:
    """The tiles a :class:`LevelIndex` query scored, a superset of the ``count`` first in the order
    "passing equation (4) first, then by rank" (the order :func:`select_ranked` takes them in).

    Attributes:
        tiles: ``(E,)`` tile indices.
        rank: ``(E,)`` their rank (as :func:`rank_tiles`).
        passes: ``(E,)`` whether they pass equation (4).
        complete: every tile was scored (then ``passes`` holds every passing tile).
    """

    tiles: NDArray[np.int64]
    rank: NDArray[np.float32]
    passes: NDArray[np.bool_]
    complete: bool


def select_ranked(rank: NDArray[np.floating], passes: NDArray[np.bool_], count: int) -> NDArray[np.int64]:
    """Indices of the first ``count`` entries in the order passing first, then by rank (best first)."""
    chosen = []
    left = int(count)
    for group in (np.flatnonzero(passes), np.flatnonzero(~passes)):
        if left <= 0:
            break
        if left < group.size:
            group = group[np.argpartition(rank[group], left - 1)[:left]]
        chosen.append(group[np.argsort(rank[group], kind="stable")])
        left -= group.size
    return np.concatenate(chosen).astype(np.int64) if chosen else np.zeros(0, dtype=np.int64)


class LevelIndex:
    """The level functions of all tiles, grouped in square blocks of tiles with their bounds.

    A query scores the blocks' lower bounds first (the distance from the live value to each
    function's interval over the block, and whether a tile of the block can pass equation
    (4)), then the tiles of the blocks in increasing bound until the ``count`` first tiles in
    the order "passing first, then by rank" are known for sure: those of :func:`rank_tiles`
    over every tile, visiting a few blocks of a large map instead of all its tiles.

    Args:
        features: ``(T, S, F)`` learned level functions, bytes of :func:`encode_features`.
        lines, columns: ``(T,)`` tile coordinates.
        block: side of a block [tiles].
    """

    def __init__(self, features: NDArray[np.uint8], lines: NDArray[np.int32], columns: NDArray[np.int32],
                 block: int = 4) -> None:
        self.features = features
        keys = (lines.astype(np.int64) // block) * (int(columns.max(initial=0)) // block + 1) + columns // block
        self.order = np.argsort(keys, kind="stable").astype(np.int64)
        starts = np.flatnonzero(np.r_[True, np.diff(keys[self.order]) != 0])
        self.starts = np.append(starts, keys.size).astype(np.int64)
        blocks = starts.size
        self.low = np.empty((blocks, features.shape[1], features.shape[2]), dtype=np.uint8)
        self.high = np.empty_like(self.low)
        if blocks:
            _block_bounds(features, self.order, self.starts, self.low, self.high)

    @property
    def nbytes(self) -> int:
        return int(self.order.nbytes + self.starts.nbytes + self.low.nbytes + self.high.nbytes)

    def query(self, live: NDArray[np.float64], alphas: NDArray[np.float64], sigmas: NDArray[np.float64],
              term_cap: float, count: int) -> RankedTiles:
        """Scored tiles holding the ``count`` first in the order passing first, then by rank."""
        tiles = self.features.shape[0]
        if self.features.shape[2] == 0 or count >= tiles:
            passes, rank = rank_tiles(self.features, live, alphas, sigmas, term_cap)
            return RankedTiles(np.arange(tiles, dtype=np.int64), rank, passes, True)
        terms, inside = term_tables(live, alphas, sigmas, term_cap)
        bound = np.empty(self.starts.size - 1)
        may_pass = np.empty(self.starts.size - 1, dtype=np.bool_)
        live_bytes = np.clip(np.asarray(live, dtype=np.float64), 0.0, 1.0) * FEATURE_LEVELS
        _bound_kernel(self.low, self.high, live_bytes, terms, inside, bound, may_pass)
        visit = np.argsort(bound, kind="stable").astype(np.int64)
        out_tiles = np.empty(tiles, dtype=np.int64)
        out_rank = np.empty(tiles, dtype=np.float32)
        out_pass = np.empty(tiles, dtype=np.bool_)
        scored = _visit_kernel(self.features, self.order, self.starts, visit, bound, may_pass, terms, inside,
                               max(1, int(count)), out_tiles, out_rank, out_pass)
        return RankedTiles(out_tiles[:scored].copy(), out_rank[:scored].copy(), out_pass[:scored].copy(),
                           scored == tiles)


@numba.njit(cache=True, nogil=True)
def _block_bounds(features, order, starts, low, high):
    """Smallest and largest byte of each function over each block; a missing one is left out (its term is
    the cap, at least any bound); a block missing it everywhere gets the missing byte as both."""
    sheets, functions = features.shape[1], features.shape[2]
    for b in range(starts.shape[0] - 1):
        for s in range(sheets):
            for f in range(functions):
                lo = 255
                hi = -1
                for i in range(starts[b], starts[b + 1]):
                    v = features[order[i], s, f]
                    if v != FEATURE_MISSING:
                        lo = min(lo, v)
                        hi = max(hi, v)
                if hi < 0:
                    lo = hi = FEATURE_MISSING
                low[b, s, f] = lo
                high[b, s, f] = hi


@numba.njit(cache=True, nogil=True)
def _bound_kernel(low, high, live_bytes, terms, inside, bound, may_pass):
    """Per block, the smallest rank and whether equation (4) can hold: each term is smallest at the byte of
    the block's interval nearest the live value ``live_bytes`` (the terms grow with the distance)."""
    blocks, sheets, functions = low.shape
    for b in range(blocks):
        best = np.inf
        passing = False
        for s in range(sheets):
            total = 0.0
            all_inside = True
            for f in range(functions):
                lo = low[b, s, f]
                if lo == FEATURE_MISSING:
                    code = FEATURE_MISSING
                else:
                    code = int(round(min(max(live_bytes[f], lo), high[b, s, f])))
                total += terms[f, code]
                all_inside = all_inside and inside[f, code]
            best = min(best, total)
            passing = passing or all_inside
        bound[b] = best
        may_pass[b] = passing


@numba.njit(cache=True, nogil=True)
def _visit_kernel(features, order, starts, visit, bound, may_pass, terms, inside, count, out_tiles, out_rank,
                  out_pass):
    """Score the tiles of the blocks that may hold one of the ``count`` first (passing first, then by rank)."""
    passing = np.empty(count)  # the `count` best ranks among passing tiles so far (max-heap)
    others = np.empty(count)  # ... among the others
    no_payload = np.empty(count, dtype=np.int64)  # the heaps keep ranks only
    n_passing = 0
    n_others = 0
    scored = 0
    for v in range(visit.shape[0]):
        b = visit[v]
        # A passing tile of this block is needed while fewer than `count` passed or it could rank better;
        # another tile only while fewer than `count` passed at all, and it could rank among the best others.
        need_passing = may_pass[b] and (n_passing < count or bound[b] < passing[0])
        need_other = n_passing < count and (n_others < count or bound[b] < others[0])
        if not (need_passing or need_other):
            continue
        for i in range(starts[b], starts[b + 1]):
            t = order[i]
            best, passed = _tile_rank(features, t, terms, inside)
            out_tiles[scored] = t
            out_rank[scored] = best
            out_pass[scored] = passed
            scored += 1
            if passed:
                n_passing = _heap_push(passing, no_payload, no_payload, n_passing, best, 0, 0)
            else:
                n_others = _heap_push(others, no_payload, no_payload, n_others, best, 0, 0)
    return scored


def cost_table(
    live: LiveProfile, truncation: float, *, unknown_cost: float, short_cost: float = 1.0, correlation: bool = False
) -> NDArray[np.float32]:
    """``(N_s, 256)``: the cost of each learned byte (``learning.CODE_LEVELS`` levels, 255 unknown) for each sensor.

    With ``d = I_live - I_learned`` (positive: the reading is shorter than the learned
    range), the cost is ``min(d^2 / tau^2, 1)``, and at most ``short_cost`` for ``d > 0``:
    something the map does not hold in front of the robot hides the rest of the ray, which
    says little against the place. A learned ray the map cannot predict costs
    ``unknown_cost`` whatever the reading. Invalid sensors cost 0 (they are left out of the
    normalisation by :func:`profile_costs` and :func:`correlate_tiles`).

    ``correlation`` (section 2.5): the cost is ``1 - D_live D_learned / R^2`` instead, with the
    distances ``D = R (1 - I)``: the lowest summed cost is the highest correlation of the two
    distance profiles at that shift (``truncation`` and ``short_cost`` are not used).
    """
    learned = 1.0 - np.arange(255, dtype=np.float64) / 254.0
    table = np.empty((live.intensities.size, 256), dtype=np.float32)
    if correlation:
        table[:, :255] = 1.0 - (1.0 - live.intensities[:, None]) * (1.0 - learned[None, :])
    else:
        d = live.intensities[:, None] - learned[None, :]
        squared = d * d / (truncation * truncation)
        table[:, :255] = np.minimum(squared, np.where(d > 0.0, short_cost, 1.0))
    table[:, 255] = unknown_cost
    table[~live.valid] = 0.0
    return table


def profile_costs(codes: NDArray[np.uint8], table: NDArray[np.float32], valid: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Normalised costs ``(P,)`` of aligned learned bytes ``(P, N_s)`` against the live sensors (0 best, 1 worst)."""
    sensors = np.arange(table.shape[0])
    costs = table[sensors[None, :], codes].astype(np.float64).sum(axis=1)
    return costs / max(int(valid.sum()), 1)


@dataclass(frozen=True)
class Hypotheses:
    """Candidate poses from the correlation (section 2.5), best first.

    Attributes:
        tiles: ``(H,)`` tile of each hypothesis.
        shifts: ``(H,)`` learned-direction shift (fractional after parabolic interpolation).
        costs: ``(H,)`` normalised cost at that shift (0 best, 1 worst).
        coarse_count: (tile, heading) pairs the coarse pass scored to the end.
    """

    tiles: NDArray[np.int64]
    shifts: NDArray[np.float64]
    costs: NDArray[np.float64]
    coarse_count: int = 0


def correlate_tiles(
    codes: NDArray[np.uint8],
    tiles: NDArray[np.int64],
    table: NDArray[np.float32],
    valid: NDArray[np.bool_],
    upsampling: int,
    *,
    keep: int,
    per_tile: int = 2,
    coarse_sensors: int = 19,
    neighbours: tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.int32]] | None = None,
) -> Hypotheses:
    """Theta of every candidate tile by comparing the live profile with its learned one at every shift.

    Live sensor k at heading theta looks along world direction ``theta + phi_k``; with
    learned direction index ``s + k * upsampling`` this is shift ``s`` and
    ``theta = s * step - phi_0``. Coarse: the shifts at the sensor step (``s`` a multiple of
    ``upsampling``) with ``coarse_sensors`` valid sensors evenly spread; each tile's best
    ``per_tile`` local minima compete for ``keep`` places, and a shift is abandoned as soon
    as its partial cost exceeds the worst kept one (costs only grow). Fine: the kept
    hypotheses at every learned shift within one sensor step, with every valid sensor, a
    parabola through the best one's neighbours for the sub-step.

    Args:
        codes: ``(T, J)`` learned bytes.
        tiles: ``(P,)`` candidate tiles, most promising first (the bound tightens sooner).
        table: ``(N_s, 256)`` from :func:`cost_table`.
        valid: ``(N_s,)`` live sensors with a reading.
        upsampling: learned directions per sensor step.
        keep: hypotheses kept after the coarse pass.
        per_tile: local minima of one tile kept at most.
        coarse_sensors: sensors compared by the coarse pass (all valid ones if fewer).
        neighbours: ``(index_image, tile_lines, tile_columns)``: the coarse pass scored
            representatives of blocks of tiles; the fine pass then tries each
            hypothesis' tile and its 8 neighbours (``index_image``: ``(L, C)`` tile index, -1
            where no tile) and keeps the best.
    """
    sensors = np.flatnonzero(valid).astype(np.int64)
    if tiles.size == 0 or sensors.size == 0 or keep <= 0:
        return Hypotheses(np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
    n = codes.shape[1]
    pick = np.unique(np.round(np.linspace(0, sensors.size - 1, min(max(1, coarse_sensors), sensors.size))))
    coarse = np.ascontiguousarray(sensors[pick.astype(np.int64)])
    chunks = 1
    heap_cost = np.full((chunks, keep), np.inf)
    heap_tile = np.full((chunks, keep), -1, dtype=np.int64)
    heap_shift = np.zeros((chunks, keep), dtype=np.int64)
    scored = np.zeros(chunks, dtype=np.int64)
    _coarse_kernel(codes, np.ascontiguousarray(tiles, dtype=np.int64), table, coarse, int(upsampling),
                   max(1, int(per_tile)), heap_cost, heap_tile, heap_shift, scored)
    flat = np.flatnonzero(heap_tile.reshape(-1) >= 0)
    order = flat[np.argsort(heap_cost.reshape(-1)[flat], kind="stable")][:keep]
    kept_tiles = heap_tile.reshape(-1)[order]
    kept_shifts = heap_shift.reshape(-1)[order]
    fine_cost = np.empty(kept_tiles.size)
    fine_shift = np.empty(kept_tiles.size)
    index_image: NDArray[np.int32] = np.full((1, 1), -1, dtype=np.int32)
    lines: NDArray[np.int32] = np.zeros(0, dtype=np.int32)
    columns = lines
    reach = 0
    if neighbours is not None:
        index_image, lines, columns = neighbours
        reach = 1
    _fine_kernel(codes, kept_tiles, kept_shifts, table, np.ascontiguousarray(sensors), int(upsampling), n,
                 index_image, lines, columns, reach, fine_cost, fine_shift)
    fine_cost /= sensors.size
    # Two coarse minima of one tile may settle within a sensor step of each other: keep the better.
    order = np.argsort(fine_cost, kind="stable")
    keep_mask = np.ones(order.size, dtype=bool)
    seen: dict[int, list[float]] = {}
    for i, h in enumerate(order):
        tile, shift = int(kept_tiles[h]), float(fine_shift[h])
        for other in seen.get(tile, ()):
            gap = abs(shift - other) % n
            if min(gap, n - gap) < upsampling:
                keep_mask[i] = False
                break
        else:
            seen.setdefault(tile, []).append(shift)
    order = order[keep_mask]
    return Hypotheses(kept_tiles[order], fine_shift[order], fine_cost[order], int(scored.sum()))


@numba.njit(cache=True, nogil=True)
def _heap_push(costs, tiles, shifts, size, cost, tile, shift):
    """Push into a max-heap of fixed capacity (``size`` filled); returns the new size.

    ``tiles`` and ``shifts`` move with ``costs`` (one scratch array may serve both when only costs matter)."""
    capacity = costs.shape[0]
    if size < capacity:
        i = size
        size += 1
    elif cost < costs[0]:
        # Replace the root (the worst kept) and sift it down.
        i = 0
        while True:
            child = 2 * i + 1
            if child >= capacity:
                break
            if child + 1 < capacity and costs[child + 1] > costs[child]:
                child += 1
            if costs[child] <= cost:
                break
            costs[i] = costs[child]
            tiles[i] = tiles[child]
            shifts[i] = shifts[child]
            i = child
        costs[i] = cost
        tiles[i] = tile
        shifts[i] = shift
        return size
    else:
        return size
    # Sift up from the new leaf.
    while i > 0:
        parent = (i - 1) // 2
        if costs[parent] >= cost:
            break
        costs[i] = costs[parent]
        tiles[i] = tiles[parent]
        shifts[i] = shifts[parent]
        i = parent
    costs[i] = cost
    tiles[i] = tile
    shifts[i] = shift
    return size


@numba.njit(cache=True, nogil=True)
def _coarse_kernel(codes, tiles, table, sensors, up, per_tile, heap_cost, heap_tile, heap_shift, scored):
    n = codes.shape[1]
    coarse = n // up
    chunks, keep = heap_cost.shape
    count = tiles.shape[0]
    m = sensors.shape[0]
    for chunk in range(chunks):
        costs = np.empty(coarse)
        size = 0
        bound = np.inf
        done = 0
        # Interleaved tiles: every chunk sees the most promising ones first.
        for p in range(chunk, count, chunks):
            t = tiles[p]
            for c in range(coarse):
                s = c * up
                acc = 0.0
                for q in range(m):
                    k = sensors[q]
                    j = s + k * up
                    while j >= n:
                        j -= n
                    acc += table[k, codes[t, j]]
                    if acc > bound:
                        acc = np.inf
                        break
                costs[c] = acc
            for _ in range(per_tile):
                best = np.inf
                best_c = -1
                for c in range(coarse):
                    v = costs[c]
                    if v >= best:
                        continue
                    before = costs[c - 1] if c > 0 else costs[coarse - 1]
                    after = costs[c + 1] if c + 1 < coarse else costs[0]
                    if v <= before and v < after:
                        best = v
                        best_c = c
                if best_c < 0:
                    break
                done += 1
                size = _heap_push(heap_cost[chunk], heap_tile[chunk], heap_shift[chunk], size, best, t, best_c * up)
                if size == keep:
                    bound = heap_cost[chunk, 0]
                costs[best_c] = np.inf  # the next local minimum of this tile
        scored[chunk] = done


@numba.njit(cache=True, nogil=True)
def _shift_cost(codes, t, s, table, sensors, up, n, bound):
    """Sum of the sensors' costs of tile ``t`` at shift ``s``; ``inf`` once it exceeds ``bound``."""
    while s < 0:
        s += n
    acc = 0.0
    for q in range(sensors.shape[0]):
        k = sensors[q]
        j = s + k * up
        while j >= n:
            j -= n
        acc += table[k, codes[t, j]]
        if acc > bound:
            return np.inf
    return acc


@numba.njit(cache=True, nogil=True)
def _fine_kernel(codes, tiles, shifts, table, sensors, up, n, index_image, lines, columns, reach, out_cost, out_shift):
    """Every learned shift within a sensor step of each hypothesis, on its tile and (``reach`` 1) its neighbours.

    ``tiles`` is overwritten with the best tile of each hypothesis.
    """
    width = 2 * up - 1
    costs = np.empty(width)
    for h in range(tiles.shape[0]):
        centre = tiles[h]
        best_cost = np.inf
        best_tile = centre
        best_shift = 0.0
        for dl in range(-reach, reach + 1):
            for dc in range(-reach, reach + 1):
                if reach == 0:
                    t = centre
                else:
                    line = lines[centre] + dl
                    column = columns[centre] + dc
                    if line < 0 or column < 0 or line >= index_image.shape[0] or column >= index_image.shape[1]:
                        continue
                    t = index_image[line, column]
                    if t < 0:
                        continue
                best = -1
                for w in range(width):
                    costs[w] = _shift_cost(codes, t, shifts[h] - (up - 1) + w, table, sensors, up, n, best_cost)
                    if best < 0 or costs[w] < costs[best]:
                        best = w
                if not costs[best] < best_cost:
                    continue
                offset = 0.0
                if 0 < best < width - 1:
                    for w in (best - 1, best + 1):  # abandoned against the previous best: score them fully
                        if not np.isfinite(costs[w]):
                            costs[w] = _shift_cost(codes, t, shifts[h] - (up - 1) + w, table, sensors, up, n, np.inf)
                    curvature = costs[best - 1] - 2.0 * costs[best] + costs[best + 1]
                    if curvature > 1e-12:
                        offset = 0.5 * (costs[best - 1] - costs[best + 1]) / curvature
                        offset = min(0.5, max(-0.5, offset))
                best_cost = costs[best]
                best_tile = t
                best_shift = shifts[h] - (up - 1) + best + offset
        out_cost[h] = best_cost
        out_shift[h] = best_shift
        tiles[h] = best_tile


def check_live_profile(profile: LiveProfile, min_valid_fraction: float) -> None:
    """Raise :class:`ScanError` when too few sensors received a valid beam."""
    valid = int(profile.valid.sum())
    needed = max(3, int(math.ceil(min_valid_fraction * profile.valid.size)))
    if valid < needed:
        raise ScanError(f"only {valid} of {profile.valid.size} PIL sensors received a valid beam (need {needed})")
