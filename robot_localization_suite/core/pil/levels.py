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

Notes (why each is invariant, what each measures): docs/pil.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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
