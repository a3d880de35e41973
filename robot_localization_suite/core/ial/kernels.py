"""Compiled kernels of interval-analysis localization (the method: :mod:`.localizer`, docs/ial.md).

Boxes are float64 rows ``[x_lo, x_hi, y_lo, y_hi, theta_lo, theta_hi]`` [m, m, rad]
with unwrapped headings (see :mod:`.interval`). Obstacle queries run on a
summed-area table (Crow, "Summed-area tables for texture mapping",
SIGGRAPH 1984) of the obstacle mask, ``sat[r, c] = sum(obstacle[:r, :c])``, so
"is there an obstacle in this cell rectangle" costs four reads and "the hull
of the obstacles in this rectangle" four binary searches of such reads.
Cells outside the map are obstacles (a beam may end on anything the map
does not describe), handled analytically without padding the table.

Everything here is serial numba: the work is a depth-first paving whose
order must not depend on threads (the same input gives the same boxes), and
a numba parallel launch costs more than a tracking iteration on this machine.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from ..interval import OUTWARD, TWO_PI, scalar_cos, scalar_mul, scalar_sin

__all__ = ["summed_area_table", "obstacle_count", "obstacle_hull", "inmap_hull", "contract_box", "pave", "merge_boxes"]

# Padding of world -> cell conversions [cells]: a point on a cell border belongs to both cells.
_CELL_PAD = 1e-6
# Depth-first stack headroom beyond the input boxes: bisections nest at most this deep.
_STACK_HEADROOM = 256


def summed_area_table(obstacle: NDArray[np.bool_]) -> NDArray[np.int32]:
    """``(H + 1, W + 1)`` int32 table with ``sat[r, c] = obstacle[:r, :c].sum()``."""
    height, width = obstacle.shape
    sat = np.zeros((height + 1, width + 1), dtype=np.int32)
    np.cumsum(np.cumsum(obstacle.astype(np.int32), axis=0), axis=1, out=sat[1:, 1:])
    return sat


@numba.njit(cache=True, nogil=True, inline="always")
def _count(sat, r0, r1, c0, c1):
    """Obstacle cells in rows r0..r1, columns c0..c1 (inclusive, inside the map)."""
    return sat[r1 + 1, c1 + 1] - sat[r0, c1 + 1] - sat[r1 + 1, c0] + sat[r0, c0]


@numba.njit(cache=True, nogil=True)
def obstacle_count(sat, c0, c1, r0, r1):
    """Obstacle cells in a cell rectangle (inclusive); off-map cells count, so the result is >= 1 then."""
    height = sat.shape[0] - 1
    width = sat.shape[1] - 1
    cc0 = max(c0, 0)
    cc1 = min(c1, width - 1)
    rr0 = max(r0, 0)
    rr1 = min(r1, height - 1)
    off_map = (c1 - c0 + 1) * (r1 - r0 + 1)
    inside = 0
    if cc0 <= cc1 and rr0 <= rr1:
        off_map -= (cc1 - cc0 + 1) * (rr1 - rr0 + 1)
        inside = _count(sat, rr0, rr1, cc0, cc1)
    return inside + off_map


@numba.njit(cache=True, nogil=True, inline="always")
def _all_marked(sat, c0, c1, r0, r1):
    """Whether every cell of the rectangle is on the map and marked."""
    height = sat.shape[0] - 1
    width = sat.shape[1] - 1
    if c0 < 0 or r0 < 0 or c1 > width - 1 or r1 > height - 1:
        return False
    return _count(sat, r0, r1, c0, c1) == (c1 - c0 + 1) * (r1 - r0 + 1)


@numba.njit(cache=True, nogil=True)
def inmap_hull(sat, c0, c1, r0, r1):
    """Cell hull ``(found, c_min, c_max, r_min, r_max)`` of the marked cells of the map inside a rectangle.

    Cells off the map are not marked here. Four binary searches on the table.
    """
    height = sat.shape[0] - 1
    width = sat.shape[1] - 1
    cc0 = max(c0, 0)
    cc1 = min(c1, width - 1)
    rr0 = max(r0, 0)
    rr1 = min(r1, height - 1)
    if cc0 > cc1 or rr0 > rr1 or _count(sat, rr0, rr1, cc0, cc1) == 0:
        return False, 0, -1, 0, -1
    lo, hi = cc0, cc1
    while lo < hi:
        mid = (lo + hi) // 2
        if _count(sat, rr0, rr1, cc0, mid) > 0:
            hi = mid
        else:
            lo = mid + 1
    c_min = lo
    lo, hi = c_min, cc1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if _count(sat, rr0, rr1, mid, cc1) > 0:
            lo = mid
        else:
            hi = mid - 1
    c_max = lo
    lo, hi = rr0, rr1
    while lo < hi:
        mid = (lo + hi) // 2
        if _count(sat, rr0, mid, c_min, c_max) > 0:
            hi = mid
        else:
            lo = mid + 1
    r_min = lo
    lo, hi = r_min, rr1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if _count(sat, mid, rr1, c_min, c_max) > 0:
            lo = mid
        else:
            hi = mid - 1
    r_max = lo
    return True, c_min, c_max, r_min, r_max


@numba.njit(cache=True, nogil=True)
def obstacle_hull(sat, c0, c1, r0, r1):
    """Cell hull ``(found, c_min, c_max, r_min, r_max)`` of the obstacles (off-map cells included) in a rectangle."""
    height = sat.shape[0] - 1
    width = sat.shape[1] - 1
    off_cols_low = c0 < 0
    off_cols_high = c1 > width - 1
    off_rows_low = r0 < 0
    off_rows_high = r1 > height - 1
    off_cols = off_cols_low or off_cols_high
    off_rows = off_rows_low or off_rows_high
    big = 1 << 60
    c_min, c_max, r_min, r_max = big, -big, big, -big
    if off_cols or off_rows:
        # Off-map cells of the rectangle: whole rows bands and/or whole column bands.
        c_min = c0 if (off_cols_low or off_rows) else max(c0, width)
        c_max = c1 if (off_cols_high or off_rows) else min(c1, -1)
        r_min = r0 if (off_rows_low or off_cols) else max(r0, height)
        r_max = r1 if (off_rows_high or off_cols) else min(r1, -1)
    found, in_c_min, in_c_max, in_r_min, in_r_max = inmap_hull(sat, c0, c1, r0, r1)
    if found:
        c_min = min(c_min, in_c_min)
        c_max = max(c_max, in_c_max)
        r_min = min(r_min, in_r_min)
        r_max = max(r_max, in_r_max)
    return c_min <= c_max, c_min, c_max, r_min, r_max


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_range(lo, hi, origin, resolution):
    """Inclusive cell indices of every cell touching the closed world interval [lo, hi]."""
    return (
        int(math.floor((lo - origin) / resolution - _CELL_PAD)),
        int(math.floor((hi - origin) / resolution + _CELL_PAD)),
    )


@numba.njit(cache=True, nogil=True, inline="always")
def _insert_largest(buffer, count, capacity, value):
    """Keep ``buffer[:count]`` the largest values seen, in descending order; returns the new count."""
    if count < capacity:
        position = count
        count += 1
    elif value > buffer[capacity - 1]:
        position = capacity - 1
    else:
        return count
    while position > 0 and buffer[position - 1] < value:
        buffer[position] = buffer[position - 1]
        position -= 1
    buffer[position] = value
    return count


@numba.njit(cache=True, nogil=True)
def _arc_of_box(d1lo, d1hi, d2lo, d2hi):
    """Directions ``[a_lo, a_hi]`` of every vector in a box that excludes the origin (span < pi)."""
    centre = math.atan2(0.5 * (d2lo + d2hi), 0.5 * (d1lo + d1hi))
    rel_lo = math.inf
    rel_hi = -math.inf
    for k in range(4):
        vx = d1lo if (k & 1) == 0 else d1hi
        vy = d2lo if (k & 2) == 0 else d2hi
        rel = math.atan2(vy, vx) - centre
        if rel > math.pi:
            rel -= TWO_PI
        elif rel < -math.pi:
            rel += TWO_PI
        rel_lo = min(rel_lo, rel)
        rel_hi = max(rel_hi, rel)
    return centre + rel_lo - OUTWARD, centre + rel_hi + OUTWARD


@numba.njit(cache=True, nogil=True)
def _intersect_arc(tlo, thi, alo, ahi):
    """Hull of ``[tlo, thi]`` intersected with the arc ``[alo, ahi] + 2 pi k`` over all k; (ok, lo, hi)."""
    k_first = math.floor((tlo - ahi) / TWO_PI)
    k_last = math.ceil((thi - alo) / TWO_PI)
    out_lo = math.inf
    out_hi = -math.inf
    for k in range(int(k_first), int(k_last) + 1):
        lo = max(tlo, alo + k * TWO_PI - OUTWARD)
        hi = min(thi, ahi + k * TWO_PI + OUTWARD)
        if lo <= hi:
            out_lo = min(out_lo, lo)
            out_hi = max(out_hi, hi)
    return out_lo <= out_hi, out_lo, out_hi


@numba.njit(cache=True, nogil=True)
def contract_box(
    box,
    beam_angles,
    range_lo,
    range_hi,
    max_outliers,
    sat,
    free_sat,
    certain_sat,
    free_samples,
    origin_x,
    origin_y,
    resolution,
    margin,
    scratch,
    beam_ok,
    top,
):
    """Contract ``box`` (6,) in place by the beams; return the number of consistent beams, or -1 if empty.

    For each beam ``i`` (heading ``gamma_i`` in the laser frame, range in
    ``[range_lo_i, range_hi_i]``): forward, equation (6) of the paper in
    REP 103 axes, ``[w_i] = [x, y] + [r_i] (cos, sin)([theta] + gamma_i)``;
    the constraint "the beam ends on an obstacle" shrinks ``[w_i]`` to the hull
    of the obstacle cells within ``margin`` [m] of it (grown back by ``margin``);
    backward, ``[x] &= [w_1] - [r] cos``, ``[y] &= [w_2] - [r] sin``, the heading
    to the directions of ``[w] - [x, y]`` minus ``gamma_i``, and a range check
    ``|[w] - [x, y]|`` against ``[r_i]``. The relaxed intersection of the
    per-beam boxes keeps, dimension by dimension, the poses inside at least
    ``n - max_outliers`` of them (Jaulin's q-intersection, Kieffer et al. 2000).

    ``scratch`` (n, 12), ``beam_ok`` (n,) and ``top`` (6, max_outliers + 1) are work arrays.
    """
    n = beam_angles.shape[0]
    required = n - max_outliers
    failures = 0
    # The laser stands in a cell the map does not mark occupied (within the margin).
    c0, c1 = _cell_range(box[0] - margin, box[1] + margin, origin_x, resolution)
    r0, r1 = _cell_range(box[2] - margin, box[3] + margin, origin_y, resolution)
    found, hc0, hc1, hr0, hr1 = inmap_hull(free_sat, c0, c1, r0, r1)
    if not found:
        return -1
    box[0] = max(box[0], origin_x + hc0 * resolution - margin - OUTWARD)
    box[1] = min(box[1], origin_x + (hc1 + 1) * resolution + margin + OUTWARD)
    box[2] = max(box[2], origin_y + hr0 * resolution - margin - OUTWARD)
    box[3] = min(box[3], origin_y + (hr1 + 1) * resolution + margin + OUTWARD)
    x_lo, x_hi, y_lo, y_hi, t_lo, t_hi = box[0], box[1], box[2], box[3], box[4], box[5]
    # Phase 1: forward evaluation and the O(1) "any obstacle near [w_i]" test (cheap rejection).
    for i in range(n):
        c_lo, c_hi = scalar_cos(t_lo + beam_angles[i] - OUTWARD, t_hi + beam_angles[i] + OUTWARD)
        s_lo, s_hi = scalar_sin(t_lo + beam_angles[i] - OUTWARD, t_hi + beam_angles[i] + OUTWARD)
        px_lo, px_hi = scalar_mul(range_lo[i], range_hi[i], c_lo, c_hi)
        py_lo, py_hi = scalar_mul(range_lo[i], range_hi[i], s_lo, s_hi)
        w1_lo = x_lo + px_lo - OUTWARD
        w1_hi = x_hi + px_hi + OUTWARD
        w2_lo = y_lo + py_lo - OUTWARD
        w2_hi = y_hi + py_hi + OUTWARD
        scratch[i, 0] = w1_lo
        scratch[i, 1] = w1_hi
        scratch[i, 2] = w2_lo
        scratch[i, 3] = w2_hi
        scratch[i, 4] = px_lo
        scratch[i, 5] = px_hi
        scratch[i, 6] = py_lo
        scratch[i, 7] = py_hi
        scratch[i, 8] = c_lo
        scratch[i, 9] = c_hi
        scratch[i, 10] = s_lo
        scratch[i, 11] = s_hi
        c0, c1 = _cell_range(w1_lo - margin, w1_hi + margin, origin_x, resolution)
        r0, r1 = _cell_range(w2_lo - margin, w2_hi + margin, origin_y, resolution)
        if obstacle_count(sat, c0, c1, r0, r1) > 0:
            beam_ok[i] = True
        else:
            beam_ok[i] = False
            failures += 1
            if failures > max_outliers:
                return -1
    # Phase 2: contract [w_i] to the obstacle hull and carry it back to the pose (forward-backward).
    capacity = max_outliers + 1
    kept = 0
    for i in range(n):
        if not beam_ok[i]:
            continue
        w1_lo, w1_hi, w2_lo, w2_hi = scratch[i, 0], scratch[i, 1], scratch[i, 2], scratch[i, 3]
        c0, c1 = _cell_range(w1_lo - margin, w1_hi + margin, origin_x, resolution)
        r0, r1 = _cell_range(w2_lo - margin, w2_hi + margin, origin_y, resolution)
        found, hc0, hc1, hr0, hr1 = obstacle_hull(sat, c0, c1, r0, r1)
        consistent = found
        if consistent:
            w1_lo = max(w1_lo, origin_x + hc0 * resolution - margin - OUTWARD)
            w1_hi = min(w1_hi, origin_x + (hc1 + 1) * resolution + margin + OUTWARD)
            w2_lo = max(w2_lo, origin_y + hr0 * resolution - margin - OUTWARD)
            w2_hi = min(w2_hi, origin_y + (hr1 + 1) * resolution + margin + OUTWARD)
            consistent = w1_lo <= w1_hi and w2_lo <= w2_hi
        if consistent:
            bx_lo = max(x_lo, w1_lo - scratch[i, 5] - OUTWARD)
            bx_hi = min(x_hi, w1_hi - scratch[i, 4] + OUTWARD)
            by_lo = max(y_lo, w2_lo - scratch[i, 7] - OUTWARD)
            by_hi = min(y_hi, w2_hi - scratch[i, 6] + OUTWARD)
            consistent = bx_lo <= bx_hi and by_lo <= by_hi
        bt_lo, bt_hi = t_lo, t_hi
        if consistent:
            d1_lo = w1_lo - bx_hi - OUTWARD
            d1_hi = w1_hi - bx_lo + OUTWARD
            d2_lo = w2_lo - by_hi - OUTWARD
            d2_hi = w2_hi - by_lo + OUTWARD
            # Distance from the laser to the beam end must be a possible range.
            near_x = 0.0 if d1_lo <= 0.0 <= d1_hi else min(abs(d1_lo), abs(d1_hi))
            near_y = 0.0 if d2_lo <= 0.0 <= d2_hi else min(abs(d2_lo), abs(d2_hi))
            far_x = max(abs(d1_lo), abs(d1_hi))
            far_y = max(abs(d2_lo), abs(d2_hi))
            near = math.sqrt(near_x * near_x + near_y * near_y) - OUTWARD
            far = math.sqrt(far_x * far_x + far_y * far_y) + OUTWARD
            consistent = near <= range_hi[i] and far >= range_lo[i]
            if consistent and (near_x > 0.0 or near_y > 0.0):
                a_lo, a_hi = _arc_of_box(d1_lo, d1_hi, d2_lo, d2_hi)
                consistent, bt_lo, bt_hi = _intersect_arc(
                    t_lo, t_hi, a_lo - beam_angles[i] - OUTWARD, a_hi - beam_angles[i] + OUTWARD
                )
        if consistent and free_samples > 0:
            # The beam met no obstacle before its end: points short of the shortest possible
            # range must not lie in certain obstacles for every pose of the box.
            back = 0.5 * resolution
            for _ in range(free_samples):
                s_k = range_lo[i] - back
                if s_k <= 0.0:
                    break
                qx_lo, qx_hi = scalar_mul(s_k, s_k, scratch[i, 8], scratch[i, 9])
                qy_lo, qy_hi = scalar_mul(s_k, s_k, scratch[i, 10], scratch[i, 11])
                q0, q1 = _cell_range(bx_lo + qx_lo - OUTWARD, bx_hi + qx_hi + OUTWARD, origin_x, resolution)
                q2, q3 = _cell_range(by_lo + qy_lo - OUTWARD, by_hi + qy_hi + OUTWARD, origin_y, resolution)
                if _all_marked(certain_sat, q0, q1, q2, q3):
                    consistent = False
                    break
                back = 2.0 * back + 0.5 * resolution
        if not consistent:
            failures += 1
            if failures > max_outliers:
                return -1
            continue
        # Keep the (max_outliers + 1) largest lower bounds and smallest upper bounds per dimension.
        _insert_largest(top[0], kept, capacity, bx_lo)
        _insert_largest(top[1], kept, capacity, -bx_hi)
        _insert_largest(top[2], kept, capacity, by_lo)
        _insert_largest(top[3], kept, capacity, -by_hi)
        _insert_largest(top[4], kept, capacity, bt_lo)
        kept = _insert_largest(top[5], kept, capacity, -bt_hi)
    consistent_beams = n - failures
    # q-intersection: a pose inside >= required boxes has each coordinate above the required-th
    # smallest lower bound, i.e. the (consistent - required + 1)-th largest one.
    rank = consistent_beams - required
    new_x_lo = top[0, rank]
    new_x_hi = -top[1, rank]
    new_y_lo = top[2, rank]
    new_y_hi = -top[3, rank]
    new_t_lo = top[4, rank]
    new_t_hi = -top[5, rank]
    if new_x_lo > new_x_hi or new_y_lo > new_y_hi or new_t_lo > new_t_hi:
        return -1
    box[0] = max(x_lo, new_x_lo)
    box[1] = min(x_hi, new_x_hi)
    box[2] = max(y_lo, new_y_lo)
    box[3] = min(y_hi, new_y_hi)
    box[4] = max(t_lo, new_t_lo)
    box[5] = min(t_hi, new_t_hi)
    return consistent_beams


@numba.njit(cache=True, nogil=True)
def _contract_to_fixpoint(box, beam_angles, range_lo, range_hi, max_outliers, sat, free_sat, certain_sat,
                          free_samples, origin_x, origin_y, resolution, margin, scratch, beam_ok, top, passes,
                          min_gain):
    """Repeat :func:`contract_box` while a pass removes more than ``min_gain`` of some width."""
    consistent = -1
    for _ in range(passes):
        before0 = box[1] - box[0]
        before1 = box[3] - box[2]
        before2 = box[5] - box[4]
        consistent = contract_box(box, beam_angles, range_lo, range_hi, max_outliers, sat, free_sat, certain_sat,
                                  free_samples, origin_x, origin_y, resolution, margin, scratch, beam_ok, top)
        if consistent < 0:
            return -1
        gain = 0.0
        if before0 > 0.0:
            gain = max(gain, 1.0 - (box[1] - box[0]) / before0)
        if before1 > 0.0:
            gain = max(gain, 1.0 - (box[3] - box[2]) / before1)
        if before2 > 0.0:
            gain = max(gain, 1.0 - (box[5] - box[4]) / before2)
        if gain <= min_gain:
            break
    return consistent


@numba.njit(cache=True, nogil=True)
def pave(
    boxes_in,
    beam_angles,
    range_lo,
    range_hi,
    max_outliers,
    sat,
    free_sat,
    certain_sat,
    free_samples,
    origin_x,
    origin_y,
    resolution,
    margin,
    min_width,
    passes,
    min_gain,
    max_boxes,
    max_contractions,
):
    """Lines 2-12 of Algorithm 1 after prediction: contract, bisect while too big, drop empty boxes.

    Boxes are taken from the back of the list (``pop_back``). A box whose
    largest scaled width ``width_d / min_width_d`` exceeds 1 is bisected at
    the middle of that dimension and both halves go back to the working list,
    so that they are contracted in this same iteration. Once the output would
    exceed ``max_boxes`` or ``max_contractions`` contractions were spent,
    boxes are contracted but no longer bisected (still sound, only coarser).

    Returns ``(boxes (N, 6), consistent beams (N,), contractions, limited)``.
    """
    n = beam_angles.shape[0]
    scratch = np.empty((n, 12))
    beam_ok = np.empty(n, dtype=np.bool_)
    top = np.empty((6, max_outliers + 1))
    stack_capacity = boxes_in.shape[0] + _STACK_HEADROOM
    stack = np.empty((stack_capacity, 6))
    size = 0
    for k in range(boxes_in.shape[0] - 1, -1, -1):
        stack[size] = boxes_in[k]
        size += 1
    out_capacity = max_boxes + stack_capacity + 1
    out = np.empty((out_capacity, 6))
    out_consistent = np.empty(out_capacity, dtype=np.int64)
    count = 0
    contractions = 0
    limited = False
    box = np.empty(6)
    while size > 0:
        size -= 1
        box[:] = stack[size]
        consistent = _contract_to_fixpoint(box, beam_angles, range_lo, range_hi, max_outliers, sat, free_sat,
                                           certain_sat, free_samples, origin_x, origin_y, resolution, margin, scratch, beam_ok, top, passes, min_gain)
        contractions += 1
        if consistent < 0:
            continue
        widest = -1
        widest_ratio = 1.0
        for d in range(3):
            ratio = (box[2 * d + 1] - box[2 * d]) / min_width[d]
            if ratio > widest_ratio:
                widest_ratio = ratio
                widest = d
        if widest >= 0:
            room = count + size + 2 <= max_boxes and contractions < max_contractions and size + 2 <= stack_capacity
            if room:
                middle = 0.5 * (box[2 * widest] + box[2 * widest + 1])
                stack[size] = box
                stack[size, 2 * widest] = middle
                stack[size + 1] = box
                stack[size + 1, 2 * widest + 1] = middle
                size += 2
                continue
            limited = True
        out[count] = box
        out_consistent[count] = consistent
        count += 1
    return out[:count].copy(), out_consistent[:count].copy(), contractions, limited


@numba.njit(cache=True, nogil=True)
def merge_boxes(boxes, max_width):
    """Greedy grouping of boxes into hulls no wider than ``max_width`` (3,) [m, m, rad].

    Each box joins the first group whose hull stays within the limits when it
    is added (headings unwrapped around the group's first box), otherwise it
    starts a group. The union of the hulls contains the union of the boxes.
    """
    count = boxes.shape[0]
    hulls = np.empty((count, 6))
    reference = np.empty(count)
    groups = 0
    for i in range(count):
        centre = 0.5 * (boxes[i, 4] + boxes[i, 5])
        placed = False
        for g in range(groups):
            shift = math.floor((centre - reference[g]) / TWO_PI + 0.5) * TWO_PI
            t_lo = boxes[i, 4] - shift
            t_hi = boxes[i, 5] - shift
            lo0 = min(hulls[g, 0], boxes[i, 0])
            hi0 = max(hulls[g, 1], boxes[i, 1])
            lo1 = min(hulls[g, 2], boxes[i, 2])
            hi1 = max(hulls[g, 3], boxes[i, 3])
            lo2 = min(hulls[g, 4], t_lo)
            hi2 = max(hulls[g, 5], t_hi)
            if hi0 - lo0 <= max_width[0] and hi1 - lo1 <= max_width[1] and hi2 - lo2 <= max_width[2]:
                hulls[g, 0] = lo0
                hulls[g, 1] = hi0
                hulls[g, 2] = lo1
                hulls[g, 3] = hi1
                # A shifted heading is exact up to one rounding of the shift.
                hulls[g, 4] = lo2 - (OUTWARD if shift != 0.0 else 0.0)
                hulls[g, 5] = hi2 + (OUTWARD if shift != 0.0 else 0.0)
                placed = True
                break
        if not placed:
            hulls[groups] = boxes[i]
            reference[groups] = centre
            groups += 1
    return hulls[:groups].copy()
