"""Queries of the IR initialiser: the live scan's hits, step 1 (positions), step 2 (poses), refinement.

Aycard & Brouard, sections IV-B-3 and IV-B-4; the choices are written in
docs/ir.md. Everything here is vectorised (scipy.sparse products for step 1,
one compiled ``(positions x headings x beams)`` pass for step 2, batched
Gauss-Newton for the refinement).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from ..scan import Scan
from ..se2 import wrap_angle
from .evidence import MapEvidence
from .index import FanModel, IRIndex
from .patterns import NO_RETURN, extract_runs, pattern_terms
from .settings import MAX_HIT_CODE

__all__ = [
    "LiveScan",
    "resample_scan",
    "live_pattern_terms",
    "step1_positions",
    "step2_poses",
    "suppress_duplicates",
]


@dataclass(frozen=True)
class LiveScan:
    """A live scan resampled onto the fan's angular grid.

    Attributes:
        codes: ``(J,)`` byte codes (see :class:`~.ir_index.FanModel`).
        valid: ``(J,)`` False for invalid readings (NaN, negative, below range_min).
        offsets: ``(J,)`` beam angles in fan rays relative to the laser heading.
        angles: ``(J,)`` angles [rad] of the beams the readings come from, relative to the laser heading.
        ranges: ``(J,)`` ranges [m] (inf no-return, NaN invalid).
        circular: the scan covers 360 degrees.
    """

    codes: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    offsets: NDArray[np.float64]
    angles: NDArray[np.float64]
    ranges: NDArray[np.float64]
    circular: bool

    @property
    def hit_mask(self) -> NDArray[np.bool_]:
        return self.valid & (self.codes != NO_RETURN)


def resample_scan(scan: Scan, fan: FanModel) -> LiveScan:
    """The live scan on the fan's grid: beams ``ray_step`` apart from the first beam, nearest reading each.

    Readings beyond the fan's ``max_range`` become no-returns, as in the fans. The patterns take each
    reading at its grid place (``offsets``); its end point is at the beam's own angle (``angles``), which
    differs by up to half a beam when the scanner's step is not a whole fraction of the fan's.
    """
    angles = np.asarray(scan.angles, dtype=np.float64)
    ranges = scan.clean_ranges()
    if angles.size > 1 and angles[-1] < angles[0]:
        angles, ranges = angles[::-1], ranges[::-1]
    step = fan.ray_step
    if angles.size > 1:
        increment = (angles[-1] - angles[0]) / (angles.size - 1)
        span = min(angles[-1] - angles[0] + increment, 2.0 * math.pi)
        count = max(1, int(math.floor(span / step + 1e-6)))
        target = angles[0] + step * np.arange(count)
        nearest = np.clip(np.rint((target - angles[0]) / increment), 0, angles.size - 1).astype(np.int64)
    else:
        span = 0.0
        target = angles.copy()
        nearest = np.zeros(angles.size, dtype=np.int64)
    picked = ranges[nearest]
    valid = ~np.isnan(picked)
    codes = fan.quantise(np.where(valid, picked, np.inf))
    far = valid & ~np.isfinite(picked)
    picked = np.where(far | (valid & (codes == NO_RETURN)), np.inf, picked)
    return LiveScan(
        codes=codes,
        valid=valid,
        offsets=target / step,
        angles=angles[nearest],  # where each picked reading was taken: end points and refinement use these
        ranges=picked,
        circular=span >= 2.0 * math.pi - step / 2.0,
    )


def live_pattern_terms(live: LiveScan, index: IRIndex) -> tuple[list[NDArray[np.int64]], NDArray[np.int64]]:
    """First-level hits of each anchored pattern of the live scan, and the anchors of every pattern found.

    Returns:
        terms: one array of term ids per anchored pattern (invalid readings left out).
        anchors: ``(R,)`` anchor bits of all R patterns (0 = unanchored, unusable).
    """
    starts, lengths, anchors = extract_runs(
        live.codes,
        live.valid,
        cap_code=index.pattern_cap_code,
        jump_codes=index.jump_codes,
        min_len=index.settings.min_pattern_beams,
        circular=live.circular,
    )
    usable = anchors > 0
    terms = pattern_terms(
        live.codes,
        live.valid,
        starts[usable],
        lengths[usable],
        anchors[usable],
        per_end=index.settings.pattern_terms_per_end,
        divisor=index.pattern_divisor,
        circular=live.circular,
    )
    return [t[t >= 0] for t in terms], anchors


def _query_terms(term: NDArray[np.int64], bins: int, soft_weight: float) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """A live pattern's hits, and with ``soft_weight`` their neighbouring range bins."""
    terms, weights = [term], [np.ones(len(term), dtype=np.float32)]
    if soft_weight > 0.0:
        for delta in (-1, 1):
            neighbour = term % bins + delta
            ok = (neighbour >= 0) & (neighbour < bins)
            terms.append(term[ok] + delta)
            weights.append(np.full(int(ok.sum()), soft_weight, dtype=np.float32))
    return np.concatenate(terms), np.concatenate(weights)


@numba.njit(cache=True, nogil=True)
def _count_common_hits(indptr, offsets, blocks, terms, weights, scores, touched):
    """Add each query hit's weight to every pattern holding it (the hit -> pattern index); returns #touched."""
    count = 0
    for q in range(terms.shape[0]):
        t = terms[q]
        w = weights[q]
        for b in range(blocks):
            base = b << 16
            for e in range(indptr[t * blocks + b], indptr[t * blocks + b + 1]):
                u = base + np.int64(offsets[e])
                if scores[u] == 0.0:
                    touched[count] = u
                    count += 1
                scores[u] += w
    return count


@numba.njit(cache=True, nogil=True)
def _take_best(scores, touched, count, limit, ceiling):
    """The ``limit`` best touched patterns (ties in touch order) by a histogram of scores; resets scores."""
    bins = 1024
    scale = (bins - 1) / max(ceiling, 1e-9)
    histogram = np.zeros(bins, dtype=np.int64)
    for i in range(count):
        histogram[int(scores[touched[i]] * scale)] += 1
    threshold = bins - 1
    total = 0
    while threshold > 0 and total + histogram[threshold] < limit:
        total += histogram[threshold]
        threshold -= 1
    # Everything above the threshold bin, and the first ones in it until ``limit``.
    room = limit - total
    n = min(limit, count)
    ids = np.empty(n, dtype=np.int64)
    values = np.empty(n, dtype=np.float64)
    k = 0
    for i in range(count):
        u = touched[i]
        b = int(scores[u] * scale)
        if b > threshold or (b == threshold and room > 0):
            if b == threshold:
                room -= 1
            if k < n:
                ids[k] = u
                values[k] = scores[u]
                k += 1
        scores[u] = 0.0
    return ids[:k], values[:k]


def step1_positions(
    index: IRIndex,
    terms: list[NDArray[np.int64]],
    *,
    patterns_per_live_pattern: int,
    positions: int,
    soft_weight: float,
    weight_by_length: bool,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Section IV-B-3: the best positions (x, y) for the live patterns.

    For each live pattern, stored patterns are scored by common hits (one
    sparse product over the hit -> pattern index), the ``patterns_per_live_pattern``
    best kept and normalised by the best score; each position then sums the
    normalised scores of the patterns it holds (times their frequency there).
    With ``weight_by_length`` a live pattern's votes are also scaled by its
    number of hits relative to the longest live pattern (a 3-beam pattern
    then weighs less than a wall; the paper weighs them alike).

    Returns:
        position ids ``(K,)`` best first and their scores ``(K,)``.
    """
    terms = [t for t in terms if len(t)]
    if not terms:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    hits = index.hit_patterns
    pattern_count = hits.pattern_count
    scores = np.zeros(pattern_count, dtype=np.float32)
    touched = np.empty(pattern_count, dtype=np.int64)
    longest = max(len(t) for t in terms)
    cols, vals = [], []
    for term in terms:
        query, weights = _query_terms(term, index.term_bins, soft_weight)
        count = _count_common_hits(hits.indptr, hits.patterns, hits.blocks, query, weights, scores, touched)
        if count == 0:
            continue
        ids, data = _take_best(scores, touched, count, patterns_per_live_pattern, float(weights.sum()))
        weight = len(term) / longest if weight_by_length else 1.0
        cols.append(ids)
        vals.append(data / data.max() * weight)
    if not cols:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    pattern_scores = np.bincount(
        np.concatenate(cols), weights=np.concatenate(vals), minlength=pattern_count
    )
    chosen = np.flatnonzero(pattern_scores)
    position_scores = index.pattern_positions[chosen].T @ pattern_scores[chosen]
    position_scores = np.asarray(position_scores).ravel()
    candidates = np.flatnonzero(position_scores)
    if len(candidates) > positions:
        candidates = candidates[np.argpartition(-position_scores[candidates], positions - 1)[:positions]]
    order = np.argsort(-position_scores[candidates], kind="stable")
    return candidates[order], position_scores[candidates[order]]


def _bin_table(divisor: int) -> NDArray[np.int16]:
    table = (np.arange(256) // divisor).astype(np.int16)
    table[NO_RETURN] = 10_000  # never within a tolerance of a hit's bin
    return table


@numba.njit(cache=True, nogil=True)
def _step2_held(fans, ids, rays, observed, table, tolerance, no_return_terms, no_return_bin, held, frequency):
    """Pass 1: whether each pose (position x heading) holds each live hit (``held``), and how many poses do."""
    headings, beams = rays.shape
    for n in range(ids.shape[0]):
        fan = fans[ids[n]]
        for h in range(headings):
            row = held[n * headings + h]
            for j in range(beams):
                expected = table[fan[rays[h, j]]]
                d = expected - observed[j]
                hit = -tolerance <= d <= tolerance or (
                    no_return_terms and expected == no_return_bin and observed[j] == no_return_bin
                )
                row[j] = hit
                if hit:
                    frequency[j] += 1.0


@numba.njit(cache=True, nogil=True)
def _step2_scores(held, weights, scores):
    """Pass 2: each pose's summed weights of the hits it holds."""
    for k in range(held.shape[0]):
        row = held[k]
        total = 0.0
        for j in range(held.shape[1]):
            if row[j]:
                total += weights[j]
        scores[k] = total


@numba.njit(cache=True, nogil=True)
def _step2_neutral(held, neutral_values, xy, end_x, end_y, flags, poses, scores):
    """Pass 3, for the poses listed: a live hit a pose does not hold but whose end point falls, at that
    pose, in an unknown cell or off the map (``flags``: :func:`~.evidence.cell_flags`) adds its
    neutral value. ``xy`` and the end points are in cells from the map origin."""
    height, width = flags.shape[0], flags.shape[1]
    headings, beams = end_x.shape
    for k in poses:
        n, h = k // headings, k % headings
        row = held[k]
        x, y = xy[n, 0], xy[n, 1]
        total = 0.0
        for j in range(beams):
            if not row[j] and neutral_values[j] > 0.0:
                ix = int(math.floor(x + end_x[h, j]))
                iy = int(math.floor(y + end_y[h, j]))
                if ix < 0 or iy < 0 or ix >= width or iy >= height or (flags[iy, ix] & 2) != 0:
                    total += neutral_values[j]
        scores[k] += total


def step2_poses(
    index: IRIndex,
    live: LiveScan,
    position_ids: NDArray[np.int64],
    *,
    heading_count: int,
    range_bin: float,
    tolerance_bins: int,
    use_idf: bool,
    no_return_terms: bool,
    idf_log: bool = False,
    evidence: MapEvidence | None = None,
    exact: int = 1_000_000_000,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Section IV-B-4: every (x, y, theta) of the positions, ranked by the summed idf of their hits.

    The on-the-fly index links each live hit ``(beam, range bin)`` to the poses
    whose expected scan (the fan rotated to theta) holds it; a hit's weight is
    the number of indexed poses divided by the number holding it (the paper's
    idf; its logarithm, the usual idf of information retrieval, with
    ``idf_log``), or 1 without idf (plain counting).

    With ``evidence`` (unknown space neutral, :mod:`.evidence`), a live hit a pose does not
    hold but whose end point falls, at that pose, in an unknown cell or off the map scores
    its chance value instead of nothing: its weight times the share of poses holding it
    (1 for the paper's idf): the map cannot tell, so it favours no pose. Only the best ``exact``
    poses are sure to carry it: a pose that cannot reach them even with every hit neutral is
    ranked by the hits it holds alone (the end-point lookups are most of step 2's time).

    Returns:
        poses ``(N * H, 3)`` (x, y, theta of the laser) and scores, best first.
    """
    usable = live.valid & (no_return_terms | (live.codes != NO_RETURN))
    if len(position_ids) == 0 or not usable.any():
        return np.zeros((0, 3)), np.zeros(0)
    fan = index.fan
    offsets = live.offsets[usable]
    headings = np.arange(heading_count) * (2.0 * math.pi / heading_count)
    rays = np.ascontiguousarray(np.rint(headings[:, None] / fan.ray_step + offsets[None, :]).astype(np.int64) % fan.rays)
    divisor = max(1, int(round(range_bin / fan.range_resolution)))
    table = _bin_table(divisor)
    observed = table[live.codes[usable]]
    no_return = int(table[NO_RETURN])
    ids = np.ascontiguousarray(position_ids, dtype=np.int64)
    pose_count = len(ids) * heading_count
    held = np.empty((pose_count, len(observed)), dtype=np.bool_)
    frequency = np.zeros(len(observed))
    _step2_held(index.fans, ids, rays, observed, table, tolerance_bins, no_return_terms, no_return, held, frequency)
    share = frequency / pose_count
    weights = pose_count / np.maximum(frequency, 1.0) if use_idf else np.ones(len(observed))
    if use_idf and idf_log:
        weights = np.log(weights)
    scores = np.empty(pose_count)
    _step2_scores(held, np.ascontiguousarray(weights, dtype=np.float64), scores)
    ranges = live.ranges[usable]
    if evidence is not None:
        # A hit's chance value: its weight times the share of poses holding it; none for no-returns.
        neutral_values = np.ascontiguousarray(np.where(np.isfinite(ranges), weights * share, 0.0))
        # Only poses that could still reach the best ``exact`` are looked up: the neutral part adds at most
        # the sum of the neutral values to a pose's score.
        exact = min(max(int(exact), 1), pose_count)
        floor = np.partition(scores, pose_count - exact)[pose_count - exact]
        reach = np.flatnonzero(scores + neutral_values.sum() >= floor)
        beam_angles = headings[:, None] + live.angles[usable][None, :]
        cells = np.where(np.isfinite(ranges), ranges, 0.0)[None, :] / evidence.resolution
        xy = (index.positions[ids] - np.asarray(evidence.origin)) / evidence.resolution
        _step2_neutral(
            held, neutral_values, np.ascontiguousarray(xy, dtype=np.float64),
            np.ascontiguousarray(cells * np.cos(beam_angles)), np.ascontiguousarray(cells * np.sin(beam_angles)),
            evidence.flags, reach, scores,
        )
    grid: NDArray[np.float64] = np.empty((len(ids), heading_count, 3))
    grid[..., :2] = index.positions[ids][:, None, :]
    grid[..., 2] = np.asarray(wrap_angle(headings))[None, :]
    poses = grid.reshape(-1, 3)
    order = np.argsort(-scores, kind="stable")
    return poses[order], scores[order]


@numba.njit(cache=True, nogil=True)
def _suppress(poses, distance2, angle, limit):
    kept = np.empty(poses.shape[0], dtype=np.int64)
    count = 0
    for i in range(poses.shape[0]):
        ok = True
        for k in range(count):
            j = kept[k]
            dx = poses[i, 0] - poses[j, 0]
            dy = poses[i, 1] - poses[j, 1]
            if dx * dx + dy * dy <= distance2:
                da = abs((poses[i, 2] - poses[j, 2] + math.pi) % (2.0 * math.pi) - math.pi)
                if da <= angle:
                    ok = False
                    break
        if ok:
            kept[count] = i
            count += 1
            if count >= limit:
                break
    return kept[:count]


def suppress_duplicates(
    poses: NDArray[np.float64], *, distance: float, angle: float, limit: int
) -> NDArray[np.int64]:
    """Greedy non-maximum suppression of poses ranked best first: indices of the kept ones (at most ``limit``).

    ``distance`` 0 keeps every pose whatever ``angle`` is (the paper's list, docs/ir.md); otherwise a pose within
    ``distance`` and ``angle`` of a kept one is dropped."""
    if len(poses) == 0:
        return np.zeros(0, dtype=np.int64)
    if distance <= 0.0:
        return np.arange(min(limit, len(poses)))
    return _suppress(np.ascontiguousarray(poses, dtype=np.float64), distance * distance, angle, limit)


# Re-exported for the localizer's diagnostics.
MAX_CODE = MAX_HIT_CODE
