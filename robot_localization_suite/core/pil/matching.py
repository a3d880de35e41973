"""PIL on-line matching (Lambert et al. 2020, sections 2.4-2.5) and what this package adds to it.

Pieces, in the order a query uses them:

* :class:`SensorLayout`: the ``N_s`` sensors over the field of view and the finer
  learned directions around the full circle.
* :class:`BeamMapping`: live beams -> ``N_s`` sensors, ``"nearest"`` (default)
  or ``"sector_min"``; a sensor with no valid beam is invalid (zero weight).
* :func:`sheet_features`: the level functions of every valid tile for each
  heading sheet (one for 360 degrees, ``K`` for a limited field of view).
* :func:`correlate_profiles`: theta of every candidate by circular
  cross-correlation (FFT) of the masked squared differences, the best local
  minima rescored by a truncated squared difference normalised by ``tau^2``.
* :func:`refine_poses`: optional sub-tile Gauss-Newton refinement on the
  distance field.

Notes (the reading of the paper's correlation, measured figures): docs/pil.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from ..errors import ScanError
from ..scan import Scan
from ..se2 import wrap_angle
from .levels import LevelFunction
from .settings import BEAM_MAPPINGS

__all__ = [
    "SensorLayout",
    "BeamMapping",
    "LiveProfile",
    "sheet_features",
    "feature_distances",
    "correlate_profiles",
    "truncated_scores",
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
        upsampling: learned directions per sensor step.
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
    def angle_count(self) -> int:
        """Learned directions over the full circle."""
        return self.circle_sensors * self.upsampling

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
    sheet j covers the ``N_s * upsampling`` directions from half a sensor step
    before ``h_j + phi_0`` (``phi_0`` the first sensor's angle).
    """
    n = layout.angle_count
    if layout.full_circle:
        return np.arange(n, dtype=np.int64)[None, :]
    step = _TWO_PI / n
    span = layout.sensor_count * layout.upsampling
    sheets = []
    for j in range(headings):
        start = int(round((_TWO_PI * j / headings + first_sensor_angle) / step)) - layout.upsampling // 2
        sheets.append((start + np.arange(span)) % n)
    return np.asarray(sheets, dtype=np.int64)


def sheet_features(
    intensities: NDArray[np.float32],
    sectors: NDArray[np.int64],
    functions: Sequence[LevelFunction],
    *,
    chunk: int = 4096,
) -> NDArray[np.float32]:
    """Level functions ``(S, F, T)`` of every learned tile on every heading sheet (section 2.3)."""
    tiles = intensities.shape[0]
    out = np.empty((sectors.shape[0], len(functions), tiles), dtype=np.float32)
    for s, sector in enumerate(sectors):
        full = sector.size == intensities.shape[1] and np.array_equal(sector, np.arange(sector.size))
        for first in range(0, tiles, chunk):
            block = intensities[first : first + chunk]
            profiles = block if full else block[:, sector]
            for f, function in enumerate(functions):
                out[s, f, first : first + chunk] = function.evaluate(profiles)
    return out


def feature_distances(
    features: NDArray[np.float32],
    live: NDArray[np.float64],
    alphas: NDArray[np.float64],
    sigmas: NDArray[np.float64],
    term_cap: float = np.inf,
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Equation (4) and a ranking from the same terms.

    Args:
        features: ``(S, F, T)`` learned ``I_n`` per sheet.
        live: ``(F,)`` live ``E_n``.
        alphas, sigmas: ``(F,)``.
        term_cap: each function's term of the ranking is capped at this, so that one
            function thrown off by an unlearned obstacle (a person next to the robot
            moves the near-range quantile a lot) cannot push the true tile out.

    Returns:
        ``passes`` ``(T,)``: ``AND_n alpha_n |I_n - E_n| < sigma_n`` on at least one sheet (the
        binary image of equation 4), and ``rank`` ``(T,)``: ``min over sheets of
        sum_n min((alpha_n |I_n - E_n| / sigma_n)^2, term_cap)`` (smaller is more alike).
    """
    if features.shape[1] == 0:
        tiles = features.shape[2]
        return np.ones(tiles, dtype=bool), np.zeros(tiles)
    scaled = np.abs(features - live[None, :, None].astype(np.float32)) * (alphas / sigmas)[None, :, None].astype(
        np.float32
    )
    passes: NDArray[np.bool_] = np.asarray((scaled < 1.0).all(axis=1).any(axis=0))
    squared = scaled * scaled
    if np.isfinite(term_cap):
        np.minimum(squared, np.float32(term_cap), out=squared)
    rank = squared.sum(axis=1).min(axis=0)
    return passes, rank.astype(np.float64)


@dataclass(frozen=True)
class Correlation:
    """Theta of each candidate tile (section 2.5).

    Attributes:
        shifts: ``(P,)`` best learned-direction shift (fractional after parabolic interpolation).
        scores: ``(P,)`` normalised truncated squared difference at that shift (0 best, 1 worst).
    """

    shifts: NDArray[np.float64]
    scores: NDArray[np.float64]


def correlate_profiles(
    intensities: NDArray[np.float32],
    spectra: tuple[NDArray[np.complex64], NDArray[np.complex64]],
    tiles: NDArray[np.int64],
    live: LiveProfile,
    upsampling: int,
    truncation: float,
    hypotheses: int = 3,
) -> Correlation:
    """Circular cross-correlation by FFT of the live profile with each candidate's learned profile.

    Live sensor k at heading theta looks along world direction ``theta + phi_k``;
    with learned direction index ``s + k * upsampling`` this is shift ``s`` and
    ``theta = s * step - phi_0``. The masked SSD over all shifts is
    ``sum w a^2 + irfft(conj(W) * F[I^2] - 2 conj(A) * F[I])`` with the learned
    spectra precomputed (:attr:`PilLearning.spectra`), so one inverse FFT per
    candidate gives every shift at once.

    Args:
        intensities: ``(T, J)`` learned intensities of all tiles.
        spectra: ``(rfft(I), rfft(I^2))`` of all tiles.
        tiles: ``(P,)`` the candidate tiles.
        live: the live profile (``N_s`` sensors, ``N_s * upsampling <= J``).
        upsampling: learned directions per sensor step.
        truncation: ``tau`` of the truncated score [intensity units].
        hypotheses: local minima of the SSD rescored per candidate with the truncated score.
    """
    candidates = tiles.size
    n = intensities.shape[1]
    if candidates == 0:
        return Correlation(np.zeros(0), np.zeros(0))
    weights = live.weights
    offsets = np.arange(live.intensities.size) * upsampling
    weighted_live = np.zeros(n)
    weighted_live[offsets] = weights * live.intensities
    mask = np.zeros(n)
    mask[offsets] = weights
    live_spectrum = np.conj(np.fft.rfft(weighted_live)).astype(np.complex64)
    mask_spectrum = np.conj(np.fft.rfft(mask)).astype(np.complex64)
    spectrum, spectrum_sq = spectra
    combined = spectrum_sq[tiles] * mask_spectrum[None, :]
    combined -= np.complex64(2.0) * spectrum[tiles] * live_spectrum[None, :]
    ssd = np.fft.irfft(combined, n, axis=1).astype(np.float32)  # masked SSD minus the constant sum w a^2
    shifts = np.empty(candidates)
    scores = np.empty(candidates)
    _score_shifts(
        ssd,
        intensities,
        np.ascontiguousarray(tiles, dtype=np.int64),
        np.ascontiguousarray(live.intensities, dtype=np.float64),
        np.ascontiguousarray(weights, dtype=np.float64),
        int(upsampling),
        float(truncation),
        max(1, int(hypotheses)),
        shifts,
        scores,
    )
    return Correlation(shifts, scores)


@numba.njit(cache=True, nogil=True)
def _score_shifts(ssd, intensities, tiles, live, weights, upsampling, truncation, hypotheses, out_shift, out_score):
    """Per candidate: the best local minima of the SSD, rescored by truncated squared difference; parabolic sub-step."""
    candidates, n = ssd.shape
    sensors = live.shape[0]
    tau2 = truncation * truncation
    total = 0.0
    for k in range(sensors):
        total += weights[k]
    norm = max(total, 1.0) * tau2
    best_value = np.empty(hypotheses)
    best_index = np.empty(hypotheses, dtype=np.int64)
    for p in range(candidates):
        row = ssd[p]
        found = 0
        for s in range(n):
            v = row[s]
            before = row[s - 1] if s > 0 else row[n - 1]
            after = row[s + 1] if s + 1 < n else row[0]
            if not (v <= before and v < after):
                continue
            # Keep the `hypotheses` smallest minima (insertion into a short sorted list).
            if found < hypotheses:
                j = found
                found += 1
            elif v < best_value[hypotheses - 1]:
                j = hypotheses - 1
            else:
                continue
            while j > 0 and best_value[j - 1] > v:
                best_value[j] = best_value[j - 1]
                best_index[j] = best_index[j - 1]
                j -= 1
            best_value[j] = v
            best_index[j] = s
        if found == 0:  # a flat curve has no strict minimum: take its first smallest value
            best_index[0] = np.argmin(row)
            found = 1
        tile = tiles[p]
        chosen = best_index[0]
        chosen_score = np.inf
        for h in range(found):
            s = best_index[h]
            acc = 0.0
            for k in range(sensors):
                if weights[k] == 0.0:
                    continue
                d = intensities[tile, (s + k * upsampling) % n] - live[k]
                d2 = d * d
                acc += weights[k] * (d2 if d2 < tau2 else tau2)
            if acc < chosen_score:
                chosen_score = acc
                chosen = s
        centre = row[chosen]
        before = row[chosen - 1] if chosen > 0 else row[n - 1]
        after = row[chosen + 1] if chosen + 1 < n else row[0]
        curvature = before - 2.0 * centre + after
        offset = 0.0
        if curvature > 1e-9:
            offset = 0.5 * (before - after) / curvature
            offset = min(0.5, max(-0.5, offset))
        out_shift[p] = chosen + offset
        out_score[p] = chosen_score / norm


def truncated_scores(learned: NDArray[np.floating], live: LiveProfile, truncation: float) -> NDArray[np.float64]:
    """Normalised truncated squared difference of aligned profiles ``(P, N_s)`` with the live one."""
    weights = live.weights
    squared = np.minimum((np.asarray(learned, dtype=np.float64) - live.intensities[None, :]) ** 2, truncation**2)
    return (squared * weights).sum(axis=1) / (max(float(weights.sum()), 1.0) * truncation**2)


def check_live_profile(profile: LiveProfile, min_valid_fraction: float) -> None:
    """Raise :class:`ScanError` when too few sensors received a valid beam."""
    valid = int(profile.valid.sum())
    needed = max(3, int(math.ceil(min_valid_fraction * profile.valid.size)))
    if valid < needed:
        raise ScanError(f"only {valid} of {profile.valid.size} PIL sensors received a valid beam (need {needed})")
