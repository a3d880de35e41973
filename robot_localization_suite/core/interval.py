"""Interval arithmetic for interval-analysis localization: scalar (numba) and vectorised (numpy).

An interval is a pair ``(lo, hi)`` with ``lo <= hi``; many intervals are two
arrays of the same shape. Moore's rules (Jaulin, Kieffer, Didrit & Walter,
*Applied Interval Analysis*, Springer 2001, ch. 2) give the image of a sum, a
product, ``sin`` and ``cos``.

Soundness against floating point: rather than switching the FPU rounding
mode, every result is widened outward by :data:`OUTWARD` (1e-9, in the unit of
the quantity: metres or radians). A float64 operation errs by at most 2^-53
relative (``sin``/``cos`` of glibc by under one ulp); the compound expressions
here chain at most eight operations on values below :data:`MAX_COORDINATE`
(1e5 m), so their accumulated error stays under ``8 * 1e5 * 1.2e-16 < 1e-10``,
ten times less than the margin. Callers refuse maps larger than that.

Angles are unwrapped: an angle interval may lie anywhere on the real line
(``[3.0, 3.5]`` is a valid heading interval across the +-pi cut), and ``sin``
and ``cos`` detect every extremum inside it, so wrap-around never loses a
heading.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "OUTWARD",
    "MAX_COORDINATE",
    "TWO_PI",
    "interval_add",
    "interval_mul",
    "interval_cos",
    "interval_sin",
    "normalize_angle_intervals",
    "angle_hull",
    "compose_boxes",
    "scalar_mul",
    "scalar_cos",
    "scalar_sin",
]

OUTWARD = 1e-9
MAX_COORDINATE = 1e5
TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


# -- scalar versions (inside numba kernels) ------------------------------------------
@numba.njit(cache=True, inline="always")
def scalar_mul(alo: float, ahi: float, blo: float, bhi: float) -> tuple[float, float]:
    """``[a] * [b]`` widened outward by :data:`OUTWARD`."""
    p1 = alo * blo
    p2 = alo * bhi
    p3 = ahi * blo
    p4 = ahi * bhi
    lo = min(min(p1, p2), min(p3, p4))
    hi = max(max(p1, p2), max(p3, p4))
    return lo - OUTWARD, hi + OUTWARD


@numba.njit(cache=True, inline="always")
def scalar_cos(lo: float, hi: float) -> tuple[float, float]:
    """``cos([lo, hi])`` for any real interval, widened outward and clipped to [-1, 1].

    Extremum detection works on ``lo`` shifted into ``[0, 2 pi)``; an error of
    the shift near an extremum changes ``cos`` only to second order, far below
    the margin.
    """
    if hi - lo >= TWO_PI:
        return -1.0, 1.0
    shift = math.floor(lo / TWO_PI) * TWO_PI
    a = lo - shift
    b = hi - shift
    ca = math.cos(lo)
    cb = math.cos(hi)
    out_lo = min(ca, cb)
    out_hi = max(ca, cb)
    if (a <= math.pi <= b) or (a <= 3.0 * math.pi <= b):
        out_lo = -1.0
    if b >= TWO_PI or a <= 0.0:
        out_hi = 1.0
    return max(-1.0, out_lo - OUTWARD), min(1.0, out_hi + OUTWARD)


@numba.njit(cache=True, inline="always")
def scalar_sin(lo: float, hi: float) -> tuple[float, float]:
    """``sin([lo, hi])`` for any real interval, widened outward and clipped to [-1, 1]."""
    if hi - lo >= TWO_PI:
        return -1.0, 1.0
    shift = math.floor(lo / TWO_PI) * TWO_PI
    a = lo - shift
    b = hi - shift
    sa = math.sin(lo)
    sb = math.sin(hi)
    out_lo = min(sa, sb)
    out_hi = max(sa, sb)
    if (a <= _HALF_PI <= b) or (a <= 5.0 * _HALF_PI <= b):
        out_hi = 1.0
    if (a <= 3.0 * _HALF_PI <= b) or (a <= 7.0 * _HALF_PI <= b):
        out_lo = -1.0
    return max(-1.0, out_lo - OUTWARD), min(1.0, out_hi + OUTWARD)


# -- vectorised versions (many boxes at once) ----------------------------------------
def interval_add(alo: ArrayLike, ahi: ArrayLike, blo: ArrayLike, bhi: ArrayLike) -> tuple[NDArray, NDArray]:
    """``[a] + [b]`` elementwise, widened outward."""
    return np.asarray(alo) + blo - OUTWARD, np.asarray(ahi) + bhi + OUTWARD


def interval_mul(alo: ArrayLike, ahi: ArrayLike, blo: ArrayLike, bhi: ArrayLike) -> tuple[NDArray, NDArray]:
    """``[a] * [b]`` elementwise, widened outward."""
    alo, ahi, blo, bhi = (np.asarray(v, dtype=np.float64) for v in (alo, ahi, blo, bhi))
    products = np.stack(np.broadcast_arrays(alo * blo, alo * bhi, ahi * blo, ahi * bhi))
    return products.min(axis=0) - OUTWARD, products.max(axis=0) + OUTWARD


def _periodic_extrema(lo: NDArray, hi: NDArray, phase: float) -> NDArray[np.bool_]:
    """Whether ``[lo, hi]`` contains ``phase + 2 pi k`` for some integer k."""
    k = np.ceil((lo - phase) / TWO_PI)
    return phase + k * TWO_PI <= hi


def interval_cos(lo: ArrayLike, hi: ArrayLike) -> tuple[NDArray, NDArray]:
    """``cos`` of intervals (any real bounds, unwrapped), widened outward and clipped to [-1, 1]."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    ca, cb = np.cos(lo), np.cos(hi)
    out_lo = np.where(_periodic_extrema(lo, hi, math.pi), -1.0, np.minimum(ca, cb))
    out_hi = np.where(_periodic_extrema(lo, hi, 0.0), 1.0, np.maximum(ca, cb))
    full = hi - lo >= TWO_PI
    out_lo = np.where(full, -1.0, np.maximum(-1.0, out_lo - OUTWARD))
    out_hi = np.where(full, 1.0, np.minimum(1.0, out_hi + OUTWARD))
    return out_lo, out_hi


def interval_sin(lo: ArrayLike, hi: ArrayLike) -> tuple[NDArray, NDArray]:
    """``sin`` of intervals (any real bounds, unwrapped), widened outward and clipped to [-1, 1]."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    sa, sb = np.sin(lo), np.sin(hi)
    out_lo = np.where(_periodic_extrema(lo, hi, -_HALF_PI), -1.0, np.minimum(sa, sb))
    out_hi = np.where(_periodic_extrema(lo, hi, _HALF_PI), 1.0, np.maximum(sa, sb))
    full = hi - lo >= TWO_PI
    out_lo = np.where(full, -1.0, np.maximum(-1.0, out_lo - OUTWARD))
    out_hi = np.where(full, 1.0, np.minimum(1.0, out_hi + OUTWARD))
    return out_lo, out_hi


def normalize_angle_intervals(lo: ArrayLike, hi: ArrayLike) -> tuple[NDArray, NDArray]:
    """Shift angle intervals by multiples of 2 pi so that ``lo`` lies in ``[-pi, pi)``.

    An interval 2 pi wide or wider covers every heading and becomes ``[-pi, pi]``.
    The shift is exact up to one rounding, absorbed by an :data:`OUTWARD` widening.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    shift = np.floor((lo + math.pi) / TWO_PI) * TWO_PI
    new_lo = lo - shift
    new_hi = hi - shift
    moved = shift != 0.0
    new_lo = np.where(moved, new_lo - OUTWARD, new_lo)
    new_hi = np.where(moved, new_hi + OUTWARD, new_hi)
    full = hi - lo >= TWO_PI
    return np.where(full, -math.pi, new_lo), np.where(full, math.pi, new_hi)


def angle_hull(lo: ArrayLike, hi: ArrayLike) -> tuple[float, float]:
    """The shortest arc ``[start, end]`` (``end - start <= 2 pi``) containing every angle interval.

    Arcs crossing +-pi are split in two, the pieces merged in sorted order, and
    the hull is the complement of the widest gap left on the circle; ``start``
    lies in ``[-pi, pi)``. Empty input raises ValueError.
    """
    lo, hi = normalize_angle_intervals(lo, hi)
    lo = np.atleast_1d(lo)
    hi = np.atleast_1d(hi)
    if lo.size == 0:
        raise ValueError("angle_hull of no interval")
    if np.any(hi - lo >= TWO_PI):
        return -math.pi, math.pi
    wraps = hi > math.pi
    starts = np.concatenate([lo, np.full(int(wraps.sum()), -math.pi)])
    ends = np.concatenate([np.minimum(hi, math.pi), hi[wraps] - TWO_PI])
    order = np.argsort(starts, kind="stable")
    starts, ends = starts[order], ends[order]
    ends = np.maximum.accumulate(ends)
    # A gap follows piece i when the next piece starts after everything so far ended.
    gaps = np.append(starts[1:] - ends[:-1], starts[0] + TWO_PI - ends[-1])
    widest = int(np.argmax(gaps))
    if gaps[widest] <= 0.0:
        return -math.pi, math.pi
    if widest == len(gaps) - 1:
        return float(starts[0]), float(ends[-1])
    return float(starts[widest + 1]), float(ends[widest]) + TWO_PI


def compose_boxes(boxes: NDArray[np.float64], offset: ArrayLike) -> NDArray[np.float64]:
    """Boxes of poses ``(K, 6)`` composed with a fixed pose ``offset`` (3,): ``[q] (+) offset``, outward."""
    offset = np.asarray(offset, dtype=np.float64)
    out = np.array(boxes, dtype=np.float64, copy=True)
    if not np.any(offset):
        return out
    c_lo, c_hi = interval_cos(boxes[:, 4], boxes[:, 5])
    s_lo, s_hi = interval_sin(boxes[:, 4], boxes[:, 5])
    cx_lo, cx_hi = interval_mul(c_lo, c_hi, offset[0], offset[0])
    sy_lo, sy_hi = interval_mul(s_lo, s_hi, offset[1], offset[1])
    sx_lo, sx_hi = interval_mul(s_lo, s_hi, offset[0], offset[0])
    cy_lo, cy_hi = interval_mul(c_lo, c_hi, offset[1], offset[1])
    out[:, 0] = boxes[:, 0] + cx_lo - sy_hi - 3 * OUTWARD
    out[:, 1] = boxes[:, 1] + cx_hi - sy_lo + 3 * OUTWARD
    out[:, 2] = boxes[:, 2] + sx_lo + cy_lo - 3 * OUTWARD
    out[:, 3] = boxes[:, 3] + sx_hi + cy_hi + 3 * OUTWARD
    out[:, 4], out[:, 5] = normalize_angle_intervals(
        boxes[:, 4] + offset[2] - OUTWARD, boxes[:, 5] + offset[2] + OUTWARD
    )
    return out
