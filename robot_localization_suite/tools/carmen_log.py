"""Read a corrected CARMEN log: its front-laser scans, their timestamps and what is wrong with them.

The front laser is logged as ``FLASER`` (old style) or ``ROBOTLASER1`` (CARMEN's laser-new, which
states its own beam geometry); a log with both is read from its FLASER lines.

The line format, beam geometry and no-return rule are in ``carmen_to_bag``'s docstring;
the timestamp checks, fallbacks and what each of the four Radish logs needs are in
docs/benchmark.md ("Real logs: timestamps").
"""

from __future__ import annotations

import gzip
import math
import os
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.errors import LocalizationSuiteError
from ..core.grid_map import MAX_COORDINATE_M

__all__ = [
    "CarmenLogError",
    "CarmenScan",
    "CarmenLog",
    "StampCheck",
    "StampChoice",
    "parse_carmen_log",
    "beam_geometry",
    "scan_geometry",
    "detect_max_range",
    "check_stamps",
    "assign_stamps",
    "choose_stamps",
    "MIN_STAMP_STEP_S",
]

# Fields after the ranges: x y theta odom_x odom_y odom_theta ipc_timestamp (host and logger_timestamp optional).
_REQUIRED_TAIL = 7
_HOST_AND_LOGGER = 2  # a laser line ends at its timestamp or after both of these, nowhere else
# ROBOTLASER1 laser_type start_angle fov angular_resolution max_range accuracy remission_mode n r1..rn
#   m e1..em  laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv forward_safety side_safety
#   turn_axis timestamp (host and logger_timestamp optional)
_ROBOTLASER_HEAD = 9  # the tag and the eight fields up to and including n
_ROBOTLASER_TAIL = 12  # laser pose, robot pose, tv rv forward_safety side_safety turn_axis, timestamp
FLASER = "FLASER"
ROBOTLASER = "ROBOTLASER1"
# ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp: the ipc_timestamp's index.
_ODOM_STAMP_INDEX = 7

MIN_STAMP_STEP_S = 1e-3  # a stamp that does not increase is moved this far after the previous one [s]
MISSING_BELOW_S = 1e-6  # |stamp| below this is missing: 0, or the denormal garbage of the Orebro ODOM lines [s]
WHOLE_SECONDS_FRACTION = 0.9  # a source is rounded when this share of its valid stamps are whole seconds
VALID_FRACTION = 0.5  # a source is usable when at least this share of its stamps are valid ...
STEP_BACK_FRACTION = 0.1  # ... and at most this share of the steps between them (or one step) do not increase
OUTLIER_STEPS = 100  # a stamp more than this many median steps ahead of the stamps on both sides is wrong
_NAMED_OUTLIERS = 3  # a warning names the lines of this many outliers

SOURCE_IPC = "FLASER ipc_timestamp"  # check_stamps' default name; choose_stamps names the sources by the lines' tag
SOURCE_ODOM = "ODOM lines"
SOURCE_PERIOD = "--period"


class CarmenLogError(LocalizationSuiteError):
    """A CARMEN log cannot be converted (missing, unreadable, or without front-laser lines)."""


@dataclass(frozen=True)
class CarmenScan:
    """One front-laser line: raw ranges [m], corrected laser pose, and the times the log gives it [s].

    Attributes:
        timestamp: the line's ``ipc_timestamp``.
        logger_timestamp: the line's ``logger_timestamp`` (NaN if the line has none).
        odom_timestamp: ``ipc_timestamp`` of the last ODOM line before this one (NaN if none).
        angle_min, angle_increment: the beam geometry a ROBOTLASER1 line states [rad]; NaN for a
            FLASER line, whose geometry is :func:`beam_geometry`'s guess from the beam count.
    """

    line_number: int
    ranges: NDArray[np.float64]
    pose: NDArray[np.float64]
    timestamp: float
    logger_timestamp: float = math.nan
    odom_timestamp: float = math.nan
    angle_min: float = math.nan
    angle_increment: float = math.nan


@dataclass
class CarmenLog:
    """The front-laser scans of a log, the lines that were skipped (line number, reason) and their tag."""

    scans: list[CarmenScan]
    skipped: list[tuple[int, str]] = field(default_factory=list)
    message: str = FLASER


def _open_text(path: Path):
    with open(path, "rb") as probe:
        magic = probe.read(2)
    if magic == b"\x1f\x8b":
        return gzip.open(path, "rt", encoding="ascii", errors="replace")
    return open(path, encoding="ascii", errors="replace")


def _parse_flaser(tokens: list[str]) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float]:
    """Ranges, pose, ipc and logger timestamps of one FLASER line; ``ValueError`` saying what is wrong."""
    if len(tokens) < 2:
        raise ValueError("no beam count")
    try:
        count = int(tokens[1])
    except ValueError:
        raise ValueError(f"beam count {tokens[1]!r} is not an integer") from None
    if not 1 <= count <= 100_000:
        raise ValueError(f"beam count {count} out of range")
    needed = 2 + count + _REQUIRED_TAIL
    if len(tokens) < needed:
        raise ValueError(f"truncated: {len(tokens)} fields, {needed} needed for {count} beams")
    _check_field_count(tokens, needed, count)
    try:
        values = np.array(tokens[2:needed], dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens[2:needed] if not _is_number(t))
        raise ValueError(f"field {bad!r} is not a number") from None
    ranges = values[:count]
    pose = values[count : count + 3]
    _check_pose(pose)
    timestamp = float(values[count + 6])
    # host then logger_timestamp follow; old logs stop at the ipc_timestamp.
    logger = _number_or_nan(tokens[needed + 1]) if len(tokens) > needed + 1 else math.nan
    return ranges, pose, timestamp, logger


def _check_pose(pose: NDArray[np.float64]) -> None:
    """Refuse a pose that is not finite or lies farther than ``MAX_COORDINATE_M`` from the origin."""
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"pose {pose.tolist()!r} is not finite")
    if np.any(np.abs(pose[:2]) > MAX_COORDINATE_M):
        raise ValueError(f"pose {pose.tolist()!r} is farther than {MAX_COORDINATE_M:g} m from the origin")


def _check_field_count(tokens: list[str], needed: int, count: int) -> None:
    """Refuse a line that neither ends at its timestamp (``needed`` fields) nor after host and logger_timestamp.

    Any other count means the beam count does not match the readings, and every field after them would be
    read from the wrong place (the stamp from odom_theta).
    """
    if len(tokens) not in (needed, needed + _HOST_AND_LOGGER):
        raise ValueError(f"{len(tokens)} fields, {needed + _HOST_AND_LOGGER} expected for {count} beams "
                         "(the beam count does not match the readings)")


def _parse_robotlaser(
    tokens: list[str],
) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float, float, float]:
    """Ranges, laser pose, ipc and logger timestamps, angle_min and increment of one ROBOTLASER1 line."""
    if len(tokens) < _ROBOTLASER_HEAD:
        raise ValueError(f"truncated: {len(tokens)} fields before the readings")
    try:
        head = np.array(tokens[2:8], dtype=np.float64)
        count = int(tokens[8])
    except ValueError:
        raise ValueError(f"header {tokens[1:9]!r} is not numbers") from None
    start_angle, fov, resolution = float(head[0]), float(head[1]), float(head[2])
    if not 1 <= count <= 100_000:
        raise ValueError(f"beam count {count} out of range")
    if not (math.isfinite(start_angle) and math.isfinite(fov) and math.isfinite(resolution)):
        raise ValueError(f"beam geometry {[start_angle, fov, resolution]!r} is not finite")
    remissions_at = _ROBOTLASER_HEAD + count
    if len(tokens) <= remissions_at:
        raise ValueError(f"truncated: {len(tokens)} fields, {remissions_at + 1} needed for {count} beams")
    try:
        remissions = int(tokens[remissions_at])
    except ValueError:
        raise ValueError(f"remission count {tokens[remissions_at]!r} is not an integer") from None
    if remissions < 0:
        raise ValueError(f"remission count {remissions} is negative")
    tail_at = remissions_at + 1 + remissions
    needed = tail_at + _ROBOTLASER_TAIL
    if len(tokens) < needed:
        raise ValueError(f"truncated: {len(tokens)} fields, {needed} needed for {count} beams")
    _check_field_count(tokens, needed, count)
    try:
        ranges = np.array(tokens[_ROBOTLASER_HEAD:remissions_at], dtype=np.float64)
        tail = np.array(tokens[tail_at:needed], dtype=np.float64)
    except ValueError:
        fields = tokens[_ROBOTLASER_HEAD:remissions_at] + tokens[tail_at:needed]
        bad = next(t for t in fields if not _is_number(t))
        raise ValueError(f"field {bad!r} is not a number") from None
    pose = tail[:3]
    _check_pose(pose)
    # The stated resolution; a log that leaves it 0 spreads the field of view over the gaps.
    if resolution > 0.0:
        increment = resolution
    elif count > 1 and fov > 0.0:
        increment = fov / (count - 1)
    else:
        raise ValueError(f"angular resolution {resolution!r} and field of view {fov!r} give no beam spacing")
    logger = _number_or_nan(tokens[needed + 1]) if len(tokens) > needed + 1 else math.nan
    return ranges, pose, float(tail[11]), logger, start_angle, increment


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _number_or_nan(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


def _report_to_stderr(line_number: int, reason: str) -> None:
    print(f"carmen_to_bag: line {line_number}: {reason}; skipped", file=sys.stderr)


def parse_carmen_log(
    path: str | os.PathLike[str],
    *,
    on_skip: Callable[[int, str], None] | None = _report_to_stderr,
) -> CarmenLog:
    """Read the front-laser lines of a CARMEN log (plain or gzip), with the time of the ODOM line before each.

    FLASER lines if the log has any, else ROBOTLASER1 lines. A malformed or truncated line is
    reported through ``on_skip(line_number, reason)`` (1-based line numbers) and skipped. ODOM lines
    serve only as a fallback clock.

    Raises:
        CarmenLogError: the file is missing or unreadable, or holds no usable front-laser line.
    """
    path = Path(path)
    if not path.is_file():
        raise CarmenLogError(f"CARMEN log {str(path)!r} does not exist")
    found: dict[str, CarmenLog] = {FLASER: CarmenLog([], message=FLASER), ROBOTLASER: CarmenLog([], message=ROBOTLASER)}
    last_odom = math.nan
    try:
        with _open_text(path) as stream:
            for line_number, line in enumerate(stream, start=1):
                if line.startswith("ODOM"):
                    tokens = line.split()
                    if tokens[0] == "ODOM":
                        last_odom = _number_or_nan(tokens[_ODOM_STAMP_INDEX]) if len(tokens) > 7 else math.nan
                    continue
                if not line.startswith((FLASER, ROBOTLASER)):
                    continue
                tokens = line.split()
                log = found.get(tokens[0])
                if log is None:
                    continue
                try:
                    if log.message == FLASER:
                        ranges, pose, timestamp, logger = _parse_flaser(tokens)
                        angle_min = increment = math.nan
                    else:
                        ranges, pose, timestamp, logger, angle_min, increment = _parse_robotlaser(tokens)
                except ValueError as exc:
                    log.skipped.append((line_number, str(exc)))
                    if on_skip is not None:
                        on_skip(line_number, f"malformed {log.message} line ({exc})")
                    continue
                log.scans.append(
                    CarmenScan(line_number, ranges, pose, timestamp, logger, last_odom, angle_min, increment)
                )
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise CarmenLogError(f"CARMEN log {str(path)!r} cannot be read: {exc}") from exc
    for log in found.values():
        if log.scans:
            return log
    malformed = sum(len(log.skipped) for log in found.values())
    detail = f" ({malformed} malformed)" if malformed else ""
    raise CarmenLogError(f"CARMEN log {str(path)!r} holds no usable {FLASER} or {ROBOTLASER} line{detail}")


def beam_geometry(count: int) -> tuple[float, float]:
    """``(angle_min, angle_increment)`` [rad] of a CARMEN front laser with ``count`` beams."""
    if count in (180, 181):
        increment = math.pi / 180.0
    elif count in (360, 361):
        increment = math.pi / 360.0
    elif count > 1:
        increment = math.pi / (count - 1)
    else:
        increment = math.pi
    return -math.pi / 2.0, increment


def scan_geometry(scan: CarmenScan) -> tuple[float, float]:
    """``(angle_min, angle_increment)`` [rad] of one scan: what its line states, else :func:`beam_geometry`'s guess."""
    if math.isfinite(scan.angle_min) and math.isfinite(scan.angle_increment):
        return scan.angle_min, scan.angle_increment
    return beam_geometry(scan.ranges.size)


def detect_max_range(scans: Iterable[CarmenScan], tolerance: float) -> float:
    """The no-return threshold [m]: the log's largest finite reading minus ``tolerance``.

    NaN and +-inf readings are passed on as they are (REP 117) and play no part in it.
    """
    largest = max((float(s.ranges[np.isfinite(s.ranges)].max()) for s in scans if np.isfinite(s.ranges).any()),
                  default=-np.inf)
    if not np.isfinite(largest):
        raise CarmenLogError("cannot find the maximum range of the log (no finite reading)")
    if largest - tolerance <= 0.0:
        raise CarmenLogError(f"cannot find the maximum range of the log (largest reading {largest!r})")
    return largest - tolerance


# -- timestamps -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class StampCheck:
    """What is wrong with one source of scan times (counts over its ``count`` values).

    A stamp is *valid* when finite and at least ``MISSING_BELOW_S``; *missing* when its
    magnitude is below that (0 in practice); an *outlier* (indices in ``outliers``) when it is
    more than ``OUTLIER_STEPS`` median steps ahead of the stamps on both sides (the first: of the
    next). Steps are counted between consecutive valid stamps; in a rounded source equal steps are
    the rounding's, not counted as non-increasing.
    """

    source: str
    count: int
    missing: int
    negative: int
    non_finite: int
    whole_seconds: int
    non_increasing: int
    steps: int
    largest_step_back_s: float
    span_s: float
    outliers: tuple[int, ...] = ()

    @property
    def valid(self) -> int:
        return self.count - self.missing - self.negative - self.non_finite - len(self.outliers)

    @property
    def rounded(self) -> bool:
        """Nearly every valid stamp is a whole second: the log was written with no fraction."""
        return self.valid >= 3 and self.whole_seconds >= WHOLE_SECONDS_FRACTION * self.valid

    @property
    def usable(self) -> bool:
        """Enough valid stamps, rising nearly always and spanning some time."""
        return (
            self.valid >= max(2, VALID_FRACTION * self.count)
            and self.non_increasing <= max(1, STEP_BACK_FRACTION * self.steps)
            and self.span_s > 0.0
        )

    def problems(self) -> dict[str, int]:
        """Problem kind -> count, only the kinds present."""
        found = {
            "missing": self.missing,
            "negative": self.negative,
            "non_finite": self.non_finite,
            "outlier": len(self.outliers),
            "rounded": self.whole_seconds if self.rounded else 0,
            "non_increasing": self.non_increasing,
        }
        return {kind: n for kind, n in found.items() if n}

    def describe(self) -> str:
        """The problems in a few words, e.g. ``"18 zero, 92 negative, 44 of 92 steps back"``."""
        words = {
            "missing": f"{self.missing} zero",
            "negative": f"{self.negative} negative",
            "non_finite": f"{self.non_finite} not finite",
            "outlier": f"{len(self.outliers)} far ahead of both neighbours",
            "rounded": f"{self.whole_seconds} whole seconds",
            "non_increasing": f"{self.non_increasing} of {self.steps} steps not increasing",
        }
        problems = self.problems()
        if not problems and self.valid < 2:
            return "fewer than two valid stamps"
        return ", ".join(words[kind] for kind in problems) or "no problem"


def _outliers(values: NDArray[np.float64]) -> NDArray[np.int64]:
    """Indices of the stamps more than ``OUTLIER_STEPS`` median steps ahead of both neighbours (the first: of the next)."""
    steps = np.diff(values)
    forward = steps[steps > 0.0]
    if values.size < 3 or forward.size == 0:
        return np.zeros(0, dtype=np.int64)
    far = OUTLIER_STEPS * float(np.median(forward))
    ahead_of_previous = np.concatenate([[True], steps > far])
    ahead_of_next = np.concatenate([-steps > far, [False]])
    return np.flatnonzero(ahead_of_previous & ahead_of_next)


def check_stamps(raw: ArrayLike, source: str = SOURCE_IPC) -> StampCheck:
    """Count the problems of one sequence of scan times [s] (see :class:`StampCheck`)."""
    raw = np.asarray(raw, dtype=np.float64).reshape(-1)
    finite = np.isfinite(raw)
    with np.errstate(invalid="ignore"):
        missing = finite & (np.abs(raw) < MISSING_BELOW_S)
        negative = finite & (raw <= -MISSING_BELOW_S)
    index = np.flatnonzero(finite & ~missing & ~negative)
    outliers = index[_outliers(raw[index])]
    values = raw[np.setdiff1d(index, outliers)]
    whole = int(np.count_nonzero(values == np.round(values)))
    steps = np.diff(values)
    rounded = values.size >= 3 and whole >= WHOLE_SECONDS_FRACTION * values.size
    back = steps < 0.0 if rounded else steps <= 0.0
    return StampCheck(
        source=source,
        count=int(raw.size),
        missing=int(missing.sum()),
        negative=int(negative.sum()),
        non_finite=int((~finite).sum()),
        whole_seconds=whole,
        non_increasing=int(back.sum()),
        steps=int(steps.size),
        largest_step_back_s=float(-steps[back].min()) if back.any() else 0.0,
        span_s=float(values.max() - values.min()) if values.size else 0.0,
        outliers=tuple(outliers.tolist()),
    )


def _spread_whole_seconds(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """Runs of equal whole-second stamps ``s`` (n scans) become ``s + i / n``: CARMEN truncates to the second."""
    out = values.copy()
    start = 0
    for i in range(1, values.size + 1):
        if i == values.size or values[i] != values[start]:
            run = i - start
            out[start:i] = values[start] + np.arange(run) / run
            start = i
    return out


def _repair(raw: NDArray[np.float64], check: StampCheck, min_step: float) -> NDArray[np.float64]:
    """Increasing stamps from a usable source: de-round, fill the invalid ones and outliers, nudge steps back."""
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(raw) & (raw >= MISSING_BELOW_S)
    valid[list(check.outliers)] = False
    index = np.flatnonzero(valid)
    values = raw[valid]
    if check.rounded:
        values = _spread_whole_seconds(values)
    stamps = raw.copy()
    stamps[valid] = values
    if index.size < raw.size:
        # Invalid stamps: linear in the scan index between valid neighbours, the median step beyond the ends.
        gaps = np.diff(values) / np.diff(index)
        step = float(np.median(gaps[gaps > 0])) if np.any(gaps > 0) else min_step
        where = np.arange(raw.size)
        filled = np.interp(where, index, values)
        filled = np.where(where < index[0], values[0] - (index[0] - where) * step, filled)
        filled = np.where(where > index[-1], values[-1] + (where - index[-1]) * step, filled)
        stamps[~valid] = np.maximum(filled[~valid], min_step)
    for i in range(1, stamps.size):
        if stamps[i] <= stamps[i - 1]:
            stamps[i] = stamps[i - 1] + min_step
    return stamps


def assign_stamps(raw: ArrayLike, period: float, min_step: float = MIN_STAMP_STEP_S) -> NDArray[np.float64]:
    """Increasing stamps [s] from one source of times; one scan every ``period`` s if it is not usable."""
    raw = np.asarray(raw, dtype=np.float64).reshape(-1)
    if raw.size == 0:
        return raw
    check = check_stamps(raw)
    if not check.usable:
        return period * np.arange(1, raw.size + 1, dtype=np.float64)
    return _repair(raw, check, min_step)


@dataclass(frozen=True)
class StampChoice:
    """The stamps a conversion uses, where they come from, and the warnings (one line per problem kind)."""

    stamps: NDArray[np.float64]
    source: str
    warnings: tuple[str, ...]


def _problem_lines(check: StampCheck, *, repaired: bool, min_step: float, raw: NDArray[np.float64],
                   line_numbers: list[int]) -> list[str]:
    """One warning per problem kind of ``check``; ``repaired``: the source is used, say how it is fixed.

    ``raw``: the source's values, ``line_numbers``: each scan's line, to name the outliers.
    """
    n = check.count
    lines = []
    fill = "; filled in linearly between the scans around them" if repaired else ""
    if check.missing:
        lines.append(f"{check.missing} of {n} scans have no {check.source} (0){fill}")
    if check.negative:
        lines.append(f"{check.negative} of {n} scans have a negative {check.source}{fill}")
    if check.non_finite:
        lines.append(f"{check.non_finite} of {n} scans have a {check.source} that is not a finite number{fill}")
    if check.outliers:
        named = ", ".join(f"line {line_numbers[i]}: {float(raw[i])!r}" for i in check.outliers[:_NAMED_OUTLIERS])
        more = ", ..." if len(check.outliers) > _NAMED_OUTLIERS else ""
        lines.append(f"{len(check.outliers)} of {n} scans have a {check.source} more than {OUTLIER_STEPS} median "
                     f"steps ahead of the scans on both sides ({named}{more}){fill}")
    if check.rounded:
        how = "; scans sharing a second are spread evenly over it" if repaired else ""
        lines.append(f"{check.whole_seconds} of {check.valid} {check.source} values are whole seconds "
                     f"(rounded){how}")
    if check.non_increasing:
        how = f"; each moved {min_step * 1e3:g} ms after the one before" if repaired else ""
        lines.append(f"{check.non_increasing} of {check.steps} steps of {check.source} do not increase "
                     f"(largest step back {check.largest_step_back_s:.3g} s){how}")
    return lines


def choose_stamps(
    scans: list[CarmenScan], period: float, *, min_step: float = MIN_STAMP_STEP_S, message: str = FLASER
) -> StampChoice:
    """Scan stamps [s]: the laser line's ``ipc_timestamp``, else its ``logger_timestamp``, else the ODOM lines'
    times, else one scan every ``period`` s; with a warning line per problem kind and per fallback.
    ``message``: the lines' tag (``FLASER`` or ``ROBOTLASER1``), which the warnings name.
    """
    source_ipc, source_logger = f"{message} ipc_timestamp", f"{message} logger_timestamp"
    line_numbers = [s.line_number for s in scans]
    ipc = np.array([s.timestamp for s in scans], dtype=np.float64)
    check = check_stamps(ipc, source_ipc)
    if check.usable:
        return StampChoice(_repair(ipc, check, min_step), source_ipc, tuple(
            _problem_lines(check, repaired=True, min_step=min_step, raw=ipc, line_numbers=line_numbers)))
    warnings = _problem_lines(check, repaired=False, min_step=min_step, raw=ipc, line_numbers=line_numbers)
    if not check.problems():
        warnings.append(f"{check.source}: {check.describe()}")
    alternatives = [
        (source_logger, np.array([s.logger_timestamp for s in scans], dtype=np.float64)),
        (SOURCE_ODOM, np.array([s.odom_timestamp for s in scans], dtype=np.float64)),
    ]
    for source, raw in alternatives:
        if np.all(np.isnan(raw)):
            warnings.append(f"{source}: none in the log to fall back on")
            continue
        other = check_stamps(raw, source)
        if np.array_equal(raw, ipc, equal_nan=True):
            warnings.append(f"{source}: not usable either ({other.describe()}; the same values as the {source_ipc})")
            continue
        if other.usable:
            what = " (the last ODOM line before each scan)" if source == SOURCE_ODOM else ""
            warnings.append(f"{check.source} not usable: using the times of the {source}{what} instead")
            warnings.extend(_problem_lines(other, repaired=True, min_step=min_step, raw=raw, line_numbers=line_numbers))
            return StampChoice(_repair(raw, other, min_step), source, tuple(warnings))
        warnings.append(f"{source}: not usable either ({other.describe()})")
    warnings.append(f"no usable timestamps: assuming one scan every {period:g} s ({SOURCE_PERIOD})")
    stamps = period * np.arange(1, len(scans) + 1, dtype=np.float64)
    return StampChoice(stamps, SOURCE_PERIOD, tuple(warnings))
