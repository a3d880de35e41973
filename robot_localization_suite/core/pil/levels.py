"""Orientation-free level functions of PIL (Lambert et al. 2020, section 2.3).

A level function maps a range profile (intensities ``I = 1 - D / R`` around the
robot, section 2.2 equation 2) to one number that does not depend on the
robot's heading: for a 360 degree profile a change of heading is a circular
shift, and each function here is invariant to circular shifts.

* ``energy`` (paper, ``I_1``): the mean of the profile.
* ``pq`` (paper, ``I_2``): the fraction of samples with ``p <= I <= q``.
* ``harmonic1`` / ``harmonic2`` (ours): ``|F_m| / n``, the magnitude of the m-th
  DFT coefficient (the DFT shift theorem).
* ``low_quantile`` / ``high_quantile`` (ours): quantiles of the sorted profile.

Every function takes profiles ``(..., n)`` and returns ``(...)``; normalising
by ``n`` makes 4x finer learned profiles comparable with the live sensors.
:func:`learned_level_features` computes the same functions over the learned
bytes of every tile and heading sheet in one compiled pass, leaving out the rays
the map cannot predict.

Notes (why each is invariant, what each measures): docs/pil.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "LEVEL_FUNCTION_NAMES",
    "LevelFunction",
    "energy",
    "pq_fraction",
    "harmonic_magnitude",
    "profile_quantile",
    "fill_invalid_circular",
    "learned_level_features",
]

from .settings import LEVEL_FUNCTION_NAMES


def energy(profiles: NDArray[np.floating]) -> NDArray[np.float64]:
    """Energy ``E_1 = (1 / N_s) sum_k I_k`` (paper section 2.4) of profiles ``(..., n)``."""
    return np.asarray(profiles, dtype=np.float64).mean(axis=-1)


def pq_fraction(profiles: NDArray[np.floating], p: float, q: float) -> NDArray[np.float64]:
    """Percentage ``E_2 = card{p <= I_k <= q} / N_s`` (paper section 2.4) of profiles ``(..., n)``."""
    values = np.asarray(profiles)
    return ((values >= p) & (values <= q)).mean(axis=-1, dtype=np.float64)


def harmonic_magnitude(profiles: NDArray[np.floating], harmonic: int) -> NDArray[np.float64]:
    """``|DFT_m(profile)| / n`` for ``m = harmonic`` of profiles ``(..., n)``; shift-invariant (shift theorem)."""
    values = np.asarray(profiles, dtype=np.float64)
    n = values.shape[-1]
    if not 0 < harmonic <= n // 2:
        raise ValueError(f"harmonic must be in 1..{n // 2} for profiles of {n} samples, got {harmonic!r}")
    # One DFT coefficient is a dot product: cheaper than a full FFT per profile.
    phase = np.exp(-2j * np.pi * harmonic * np.arange(n) / n)
    return np.abs(values @ phase) / n


def profile_quantile(profiles: NDArray[np.floating], level: float) -> NDArray[np.float64]:
    """The ``level`` quantile (0..1, linear interpolation) of the sorted samples of profiles ``(..., n)``."""
    if not 0.0 <= level <= 1.0:
        raise ValueError(f"quantile level must be in [0, 1], got {level!r}")
    return np.quantile(np.asarray(profiles, dtype=np.float64), level, axis=-1)


@dataclass(frozen=True)
class LevelFunction:
    """One orientation-free level function of equation (4): its name, ``alpha_n`` and ``sigma_n``.

    Attributes:
        name: one of :data:`LEVEL_FUNCTION_NAMES`.
        alpha: weighting factor ``alpha_n`` (dimensionless).
        sigma: accepted tolerance ``sigma_n`` (units of the function, i.e. of ``I``).
        evaluate: profiles ``(..., n)`` -> values ``(...)``.
    """

    name: str
    alpha: float
    sigma: float
    evaluate: Callable[[NDArray[np.floating]], NDArray[np.float64]]

    def __post_init__(self) -> None:
        if self.name not in LEVEL_FUNCTION_NAMES:
            raise ValueError(f"unknown level function {self.name!r}; known: {', '.join(LEVEL_FUNCTION_NAMES)}")
        if not (np.isfinite(self.alpha) and self.alpha > 0.0):
            raise ValueError(f"alpha of level function {self.name!r} must be positive, got {self.alpha!r}")
        if not (np.isfinite(self.sigma) and self.sigma > 0.0):
            raise ValueError(f"sigma of level function {self.name!r} must be positive, got {self.sigma!r}")


def fill_invalid_circular(profile: NDArray[np.floating], valid: NDArray[np.bool_], *, circular: bool) -> NDArray[np.float64]:
    """Replace invalid samples of a live profile ``(n,)`` by linear interpolation between valid neighbours.

    Level functions need a complete profile; interpolating (circularly for a
    360 degree profile) is the least committal way to fill the gaps left by
    NaN readings. Raises ``ValueError`` when no sample is valid.
    """
    values = np.asarray(profile, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    if not valid.any():
        raise ValueError("profile has no valid sample")
    if valid.all():
        return values.copy()
    n = values.size
    index = np.arange(n, dtype=np.float64)
    known = index[valid]
    known_values = values[valid]
    if circular:
        return np.interp(index, known, known_values, period=float(n))
    return np.interp(index, known, known_values)


# Kernel ids of the level functions, in LEVEL_FUNCTION_NAMES order.
_KERNEL_IDS = {name: i for i, name in enumerate(LEVEL_FUNCTION_NAMES)}
_CODE_UNKNOWN = 255
_CODE_LEVELS = 254.0


def learned_level_features(
    codes: NDArray[np.uint8],
    sectors: NDArray[np.int64],
    names: Sequence[str],
    *,
    pq_low: float,
    pq_high: float,
    low_level: float,
    high_level: float,
    chunk: int = 1 << 14,
) -> NDArray[np.float32]:
    """Level functions ``(T, S, F)`` of every learned tile on every heading sheet, over its known rays.

    ``codes`` ``(T, J)`` are learned bytes (``learning.CODE_LEVELS`` levels of ``I``, 255
    unknown); ``sectors`` ``(S, n)`` the learned directions each sheet sees (contiguous,
    modulo ``J``). Unknown rays are left out, so unknown space is no evidence: energy,
    pq% and quantiles are those of the known rays; the harmonics are those of the profile
    with its unknown rays set to the known rays' mean (the DFT of the known rays minus
    their mean, over ``n``), which for a fully known profile is :func:`harmonic_magnitude`.
    A sheet with fewer than two known rays gets NaN. The result is float32; the matching keeps
    it as bytes (``matching.encode_features``).
    """
    ids = np.array([_KERNEL_IDS[name] for name in names], dtype=np.int64)
    tiles = codes.shape[0]
    starts = np.ascontiguousarray(sectors[:, 0] % codes.shape[1], dtype=np.int64)
    span = int(sectors.shape[1])
    out = np.empty((tiles, sectors.shape[0], ids.size), dtype=np.float32)
    k = np.arange(span, dtype=np.float64)
    phases = np.ascontiguousarray(np.stack([np.cos(2.0 * np.pi * k / span), np.sin(2.0 * np.pi * k / span),
                                            np.cos(4.0 * np.pi * k / span), np.sin(4.0 * np.pi * k / span)]))
    for first in range(0, tiles, chunk):  # a memory-mapped codes array is read in pieces
        block = np.ascontiguousarray(codes[first : first + chunk])
        _features_kernel(block, starts, span, ids, float(pq_low), float(pq_high), float(low_level), float(high_level),
                         phases, out[first : first + chunk])
    return out


@numba.njit(cache=True, nogil=True)
def _order_statistic(hist, rank):
    """Intensity of the ``rank``-th smallest known ray (0-based) from a histogram of codes."""
    seen = 0
    for code in range(254, -1, -1):  # intensity grows as the code falls
        seen += hist[code]
        if seen > rank:
            return 1.0 - code / _CODE_LEVELS
    return 1.0


@numba.njit(cache=True, nogil=True, parallel=True)
def _features_kernel(codes, starts, span, ids, pq_low, pq_high, low_level, high_level, phases, out):
    tiles, n = codes.shape
    sheets = starts.shape[0]
    functions = ids.shape[0]
    for t in numba.prange(tiles):
        hist = np.zeros(256, dtype=np.int64)
        for s in range(sheets):
            hist[:] = 0
            count = 0
            total = 0.0
            in_pq = 0
            start = starts[s]
            for i in range(span):
                j = start + i
                if j >= n:
                    j -= n
                code = codes[t, j]
                if code == _CODE_UNKNOWN:
                    continue
                value = 1.0 - code / _CODE_LEVELS
                hist[code] += 1
                count += 1
                total += value
                if pq_low <= value <= pq_high:
                    in_pq += 1
            if count < 2:
                for f in range(functions):
                    out[t, s, f] = np.nan
                continue
            mean = total / count
            re1 = im1 = re2 = im2 = 0.0
            for i in range(span):
                j = start + i
                if j >= n:
                    j -= n
                code = codes[t, j]
                if code == _CODE_UNKNOWN:
                    continue
                centred = 1.0 - code / _CODE_LEVELS - mean
                re1 += centred * phases[0, i]
                im1 -= centred * phases[1, i]
                re2 += centred * phases[2, i]
                im2 -= centred * phases[3, i]
            for f in range(functions):
                kind = ids[f]
                if kind == 0:
                    value = mean
                elif kind == 1:
                    value = in_pq / count
                elif kind == 2:
                    value = math.sqrt(re1 * re1 + im1 * im1) / span
                elif kind == 3:
                    value = math.sqrt(re2 * re2 + im2 * im2) / span
                else:
                    level = low_level if kind == 4 else high_level
                    h = (count - 1) * level
                    lower = int(math.floor(h))
                    a = _order_statistic(hist, lower)
                    b = _order_statistic(hist, min(lower + 1, count - 1))
                    value = a + (h - lower) * (b - a)
                out[t, s, f] = value
