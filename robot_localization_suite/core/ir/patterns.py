"""Patterns of a ray fan or a scan (Aycard & Brouard, section IV-B-1) and the hits they yield (IV-B-2).

A *pattern* is a run of consecutive hits between no-return readings (and, beyond the paper, range
jumps larger than ``split_at_jump``); a first-level *hit* is ``(anchor side, offset, range bin)``:
the quantised range of the beam ``offset`` beams inside a pattern, counted from the delimiter at
its start (side 0) or its end (side 1). Compiled kernels over byte-quantised fans. Notes: docs/ir.md.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from .settings import MAX_HIT_CODE

__all__ = ["NO_RETURN", "extract_runs", "pattern_terms", "count_fan_runs", "fill_fan_runs", "count_view_runs",
           "fill_view_runs", "fill_view_terms", "fill_terms_all_valid"]

#: Byte code of a reading with no return within the model's maximum range.
NO_RETURN = 255
# FNV-1a 64-bit constants (pattern hashes).
_FNV_OFFSET = np.uint64(14695981039346656037)
_FNV_PRIME = np.uint64(1099511628211)


@numba.njit(cache=True, nogil=True)
def _runs_of_row(codes, valid, cap, jump, min_len, circular, starts, lengths, anchors):
    """Runs of hits in one row of codes; returns their count.

    A run starts at a hit whose predecessor is a no-return, or across a range jump.
    ``anchors`` bit 0: the start is delimited (not the edge of a limited view);
    bit 1: the end is. Invalid readings (``valid`` False) continue a run.
    With ``circular`` the row wraps around; a row of hits with no delimiter has no run.
    """
    m = codes.shape[0]
    count = 0

    def is_hit(i):
        return (not valid[i]) or codes[i] <= cap

    def breaks(i, j):
        # Whether consecutive readings i -> j are not part of one run.
        if not (is_hit(i) and is_hit(j)):
            return True
        if jump > 0 and valid[i] and valid[j]:
            d = np.int64(codes[i]) - np.int64(codes[j])
            if d > jump or -d > jump:
                return True
        return False

    if circular:
        first = -1
        for i in range(m):
            if is_hit(i) and breaks((i - 1) % m, i):
                first = i
                break
        if first < 0:
            return 0
        i = first
        visited = 0
        while visited < m:
            if is_hit(i) and breaks((i - 1) % m, i):
                length = 1
                j = i
                while length < m and not breaks(j, (j + 1) % m):
                    j = (j + 1) % m
                    length += 1
                if length >= min_len:
                    starts[count] = i
                    lengths[count] = length
                    anchors[count] = 3
                    count += 1
                i = (i + length) % m
                visited += length
            else:
                i = (i + 1) % m
                visited += 1
        return count
    i = 0
    while i < m:
        if is_hit(i):
            start_anchor = 0 if i == 0 else (1 if breaks(i - 1, i) else 0)
            length = 1
            j = i
            while j + 1 < m and not breaks(j, j + 1):
                j += 1
                length += 1
            end_anchor = 2 if j + 1 < m else 0
            # Invalid readings at a delimiter cannot anchor: the delimiter may be a hit.
            if start_anchor and not valid[i]:
                start_anchor = 0
            if end_anchor and not valid[j]:
                end_anchor = 0
            if length >= min_len:
                starts[count] = i
                lengths[count] = length
                anchors[count] = start_anchor | end_anchor
                count += 1
            i = j + 1
        else:
            i += 1
    return count


@numba.njit(cache=True, nogil=True)
def _fnv_run(codes, start, length, divisor):
    """FNV-1a hash of the binned codes of a circular run (identifies a pattern)."""
    m = codes.shape[0]
    h = (_FNV_OFFSET ^ np.uint64(length)) * _FNV_PRIME
    for k in range(length):
        h = (h ^ np.uint64(codes[(start + k) % m] // divisor)) * _FNV_PRIME
    return h


@numba.njit(cache=True, nogil=True, parallel=True)
def count_fan_runs(fans, cap, jump, min_len):
    count = np.zeros(fans.shape[0], dtype=np.int64)
    m = fans.shape[1]
    for p in numba.prange(fans.shape[0]):
        starts = np.empty(m, dtype=np.int64)
        lengths = np.empty(m, dtype=np.int64)
        anchors = np.empty(m, dtype=np.int64)
        valid = np.ones(m, dtype=np.bool_)
        count[p] = _runs_of_row(fans[p], valid, cap, jump, min_len, True, starts, lengths, anchors)
    return count


@numba.njit(cache=True, nogil=True, parallel=True)
def fill_fan_runs(fans, cap, jump, min_len, divisor, offsets, out_start, out_length, out_hash):
    m = fans.shape[1]
    for p in numba.prange(fans.shape[0]):
        starts = np.empty(m, dtype=np.int64)
        lengths = np.empty(m, dtype=np.int64)
        anchors = np.empty(m, dtype=np.int64)
        valid = np.ones(m, dtype=np.bool_)
        n = _runs_of_row(fans[p], valid, cap, jump, min_len, True, starts, lengths, anchors)
        for r in range(n):
            o = offsets[p] + r
            out_start[o] = starts[r]
            out_length[o] = lengths[r]
            out_hash[o] = _fnv_run(fans[p], starts[r], lengths[r], divisor)


@numba.njit(cache=True, nogil=True)
def _fnv_view_run(codes, start, length, anchors, divisor):
    """FNV-1a hash of a run of a limited view: its binned codes and which ends are delimited."""
    h = _fnv_run(codes, start, length, divisor)
    return (h ^ np.uint64(anchors)) * _FNV_PRIME


@numba.njit(cache=True, nogil=True)
def _view_runs(fans, view_rays, q, cap, jump, min_len):
    """Runs of view row ``q``: view ``q % V`` of fan ``q // V``, the fan's readings ``view_rays[q % V]`` (a
    limited view: its edges delimit nothing). Returns the view's codes, starts, lengths, anchors and count."""
    views = view_rays.shape[0]
    m = view_rays.shape[1]
    codes = fans[q // views][view_rays[q % views]]
    starts = np.empty(m, dtype=np.int64)
    lengths = np.empty(m, dtype=np.int64)
    anchors = np.empty(m, dtype=np.int64)
    n = _runs_of_row(codes, np.ones(m, dtype=np.bool_), cap, jump, min_len, False, starts, lengths, anchors)
    return codes, starts, lengths, anchors, n


@numba.njit(cache=True, nogil=True, parallel=True)
def count_view_runs(fans, view_rays, cap, jump, min_len):
    """Runs with a delimited end in each view row (see :func:`_view_runs`)."""
    count = np.zeros(fans.shape[0] * view_rays.shape[0], dtype=np.int64)
    for q in numba.prange(count.shape[0]):
        _, _, _, anchors, n = _view_runs(fans, view_rays, q, cap, jump, min_len)
        count[q] = np.count_nonzero(anchors[:n])
    return count


@numba.njit(cache=True, nogil=True, parallel=True)
def fill_view_runs(fans, view_rays, cap, jump, min_len, divisor, offsets, out_start, out_length, out_anchors,
                   out_hash):
    """The runs :func:`count_view_runs` counts: start, length, anchor bits and hash of each."""
    for q in numba.prange(fans.shape[0] * view_rays.shape[0]):
        codes, starts, lengths, anchors, n = _view_runs(fans, view_rays, q, cap, jump, min_len)
        o = offsets[q]
        for r in range(n):
            if anchors[r] > 0:
                out_start[o] = starts[r]
                out_length[o] = lengths[r]
                out_anchors[o] = anchors[r]
                out_hash[o] = _fnv_view_run(codes, starts[r], lengths[r], anchors[r], divisor)
                o += 1


@numba.njit(cache=True, nogil=True)
def _fill_terms(fans, rows, starts, lengths, anchors, valid_rows, per_end, divisor, bins, offsets, out, circular):
    """Term ids of runs: ``((side * per_end) + offset) * bins + range_bin``; -1 where a reading is invalid."""
    m = fans.shape[1]
    for r in range(rows.shape[0]):
        codes = fans[rows[r]]
        valid = valid_rows[rows[r]]
        o = offsets[r]
        n = min(per_end, lengths[r])
        for k in range(n):
            if anchors[r] & 1:
                i = (starts[r] + k) % m if circular else starts[r] + k
                out[o] = (k * bins + codes[i] // divisor) if valid[i] else -1
                o += 1
            if anchors[r] & 2:
                i = (starts[r] + lengths[r] - 1 - k) % m if circular else starts[r] + lengths[r] - 1 - k
                out[o] = ((per_end + k) * bins + codes[i] // divisor) if valid[i] else -1
                o += 1


def extract_runs(
    codes: NDArray[np.uint8],
    valid: NDArray[np.bool_],
    *,
    cap_code: int,
    jump_codes: int,
    min_len: int,
    circular: bool,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Patterns of one row of codes: ``(starts, lengths, anchors)`` (anchors bit 0 start, bit 1 end)."""
    m = codes.shape[0]
    starts = np.empty(m, dtype=np.int64)
    lengths = np.empty(m, dtype=np.int64)
    anchors = np.empty(m, dtype=np.int64)
    n = _runs_of_row(
        np.ascontiguousarray(codes, dtype=np.uint8),
        np.ascontiguousarray(valid, dtype=np.bool_),
        cap_code,
        jump_codes,
        min_len,
        circular,
        starts,
        lengths,
        anchors,
    )
    return starts[:n], lengths[:n], anchors[:n]


def pattern_terms(
    codes: NDArray[np.uint8],
    valid: NDArray[np.bool_],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    anchors: NDArray[np.int64],
    *,
    per_end: int,
    divisor: int,
    circular: bool,
) -> list[NDArray[np.int64]]:
    """First-level hits (term ids, see the module docstring) of each pattern of one row."""
    bins = MAX_HIT_CODE // divisor + 1
    ends = ((anchors & 1) > 0).astype(np.int64) + ((anchors & 2) > 0).astype(np.int64)
    counts = np.minimum(lengths, per_end) * ends
    offsets = np.concatenate([[0], np.cumsum(counts)])
    out = np.empty(offsets[-1], dtype=np.int64)
    _fill_terms(
        np.ascontiguousarray(codes, dtype=np.uint8).reshape(1, -1),
        np.zeros(len(starts), dtype=np.int64),
        starts,
        lengths,
        anchors,
        np.ascontiguousarray(valid, dtype=np.bool_).reshape(1, -1),
        per_end,
        divisor,
        bins,
        offsets[:-1],
        out,
        circular,
    )
    return [out[offsets[i] : offsets[i + 1]] for i in range(len(starts))]


# --------------------------------------------------------------------------------------------
# The index (IV-B-2)
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True, nogil=True)
def fill_terms_all_valid(fans, rows, starts, lengths, per_end, divisor, bins, offsets, out):
    """Term ids of complete (both ends anchored) circular patterns of the fans."""
    m = fans.shape[1]
    for r in range(rows.shape[0]):
        codes = fans[rows[r]]
        o = offsets[r]
        n = min(per_end, lengths[r])
        for k in range(n):
            out[o] = k * bins + codes[(starts[r] + k) % m] // divisor
            out[o + 1] = (per_end + k) * bins + codes[(starts[r] + lengths[r] - 1 - k) % m] // divisor
            o += 2


@numba.njit(cache=True, nogil=True)
def fill_view_terms(fans, view_rays, rows, starts, lengths, anchors, per_end, divisor, bins, offsets, out):
    """Term ids of runs of views (rows as in :func:`count_view_runs`), from each delimited end only."""
    views = view_rays.shape[0]
    for r in range(rows.shape[0]):
        fan = fans[rows[r] // views]
        rays = view_rays[rows[r] % views]
        o = offsets[r]
        n = min(per_end, lengths[r])
        for k in range(n):
            if anchors[r] & 1:
                out[o] = k * bins + fan[rays[starts[r] + k]] // divisor
                o += 1
            if anchors[r] & 2:
                out[o] = (per_end + k) * bins + fan[rays[starts[r] + lengths[r] - 1 - k]] // divisor
                o += 1
