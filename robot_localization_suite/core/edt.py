"""The one exact Euclidean distance transform of the package (compiled; no OpenCV).

:func:`distance_to_marked` is what ``GridMap.distance_field`` and the ray caster's clearance codes
are built from. It is Felzenszwalb and Huttenlocher's lower-envelope algorithm ("Distance
Transforms of Sampled Functions", Theory of Computing 8, 2012, section 2.1): one pass over the
columns, one over the rows, exact squared distances between cell centres, float32 results as
OpenCV's ``distanceTransform(DIST_L2, DIST_MASK_PRECISE)`` gives them. It lives here rather than in
OpenCV so that the laser localizers never load OpenCV (about 33 MB of a node's resident memory,
docs/footprint.md).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["distance_to_marked"]

# "No marked cell on this line yet": larger than any squared distance on a map that fits in memory.
_FAR = 1e30


@numba.njit(cache=True, nogil=True)
def _lower_envelope(f, out, v, z):  # pragma: no cover - compiled
    """Squared distances ``out[q] = min_p (q - p)^2 + f[p]`` of one line (section 2.1 of the paper)."""
    n = f.shape[0]
    k = 0
    v[0] = 0
    z[0] = -math.inf
    z[1] = math.inf
    for q in range(1, n):
        s = ((f[q] + q * q) - (f[v[k]] + v[k] * v[k])) / (2.0 * q - 2.0 * v[k])
        while s <= z[k]:
            k -= 1
            s = ((f[q] + q * q) - (f[v[k]] + v[k] * v[k])) / (2.0 * q - 2.0 * v[k])
        k += 1
        v[k] = q
        z[k] = s
        z[k + 1] = math.inf
    k = 0
    for q in range(n):
        while z[k + 1] < q:
            k += 1
        out[q] = (q - v[k]) * (q - v[k]) + f[v[k]]


@numba.njit(cache=True, nogil=True)
def _squared_distances(marked):  # pragma: no cover - compiled
    height, width = marked.shape
    size = max(height, width)
    line = np.empty(size)
    result = np.empty(size)
    v = np.empty(size, dtype=np.int64)
    z = np.empty(size + 1)
    # float32 as the result: squared distances stay exact up to 4,096 cells (2**24).
    squared = np.empty((height, width), dtype=np.float32)
    for c in range(width):
        for r in range(height):
            line[r] = 0.0 if marked[r, c] else _FAR
        _lower_envelope(line[:height], result[:height], v, z)
        for r in range(height):
            squared[r, c] = result[r]
    for r in range(height):
        for c in range(width):
            line[c] = squared[r, c]
        _lower_envelope(line[:width], result[:width], v, z)
        for c in range(width):
            squared[r, c] = result[c]
    return squared


def distance_to_marked(marked: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Distance [cells] from each cell centre ``(H, W)`` to the nearest centre of a ``marked`` cell.

    With no marked cell at all every distance is about 1e15 (the caller decides what that means).
    """
    mask = np.ascontiguousarray(marked, dtype=np.bool_)
    if mask.size == 0:
        return np.zeros(mask.shape, dtype=np.float32)
    squared = _squared_distances(mask)
    np.sqrt(squared, out=squared)
    return squared
