"""Laser scans as arrays: the one place raw readings are classified.

Each reading of a ``sensor_msgs/LaserScan`` is one of (REP 117):

* a *hit*: finite and inside ``[range_min, range_max)``;
* a *no-return*: ``+inf`` or at/above ``range_max`` (nothing within range);
* *invalid*: NaN, ``-inf``, negative or below ``range_min``.

Algorithms use hits, and some use no-returns (PIL and IR treat them as "free
up to the maximum range"); invalid readings are never used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ScanError
from .se2 import compose

__all__ = ["Scan", "LaserMount"]


MAX_MOUNT_OFFSET_M = 100.0  # a laser farther than this from the base is a wrong transform, not a mount [m]


@dataclass(frozen=True)
class LaserMount:
    """Pose of the laser in the robot base frame [m, m, rad] (tf2 is not available).

    ``yaw`` is the heading of the laser's x axis. ``upside_down``: its z axis points down (a laser
    mounted upside down, roll or pitch of pi), so its beam angles turn clockwise seen from above:
    :meth:`level` gives the scan a level laser there would have read (README, "ROS interface").
    """

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    upside_down: bool = False

    def __post_init__(self) -> None:
        values = (self.x, self.y, self.yaw)
        if not all(np.isfinite(values)) or max(abs(self.x), abs(self.y)) > MAX_MOUNT_OFFSET_M:
            raise ValueError(f"laser mount ({self.x!r} m, {self.y!r} m, {self.yaw!r} rad) is not a mount: its x "
                             f"and y must be finite and within {MAX_MOUNT_OFFSET_M:g} m of the base")

    @property
    def pose(self) -> NDArray[np.float64]:
        return np.array([self.x, self.y, self.yaw], dtype=np.float64)

    def laser_poses(self, base_poses: ArrayLike) -> NDArray[np.float64]:
        """Laser poses ``(N, 3)`` in the map for robot base poses ``(N, 3)``."""
        return compose(np.asarray(base_poses, dtype=np.float64), self.pose)

    def level(self, scan: Scan) -> Scan:
        """``scan`` as a level laser at this pose reads it: beam angle ``a`` of an upside-down laser is
        ``-a`` of a level one (beams reordered so that the angles still increase); unchanged otherwise."""
        if not self.upside_down:
            return scan
        return Scan(scan.stamp, -scan.angles[::-1], scan.ranges[::-1].copy(), scan.range_min, scan.range_max)


@dataclass(frozen=True, eq=False)
class Scan:
    """One laser scan in the laser frame.

    Attributes:
        stamp: time [s].
        angles: ``(B,)`` beam angles [rad].
        ranges: ``(B,)`` raw readings [m] as received (NaN / inf kept).
        range_min, range_max: the sensor's valid interval [m].
    """

    stamp: float
    angles: NDArray[np.float64]
    ranges: NDArray[np.float64]
    range_min: float
    range_max: float

    def __post_init__(self) -> None:
        if self.angles.shape != self.ranges.shape or self.ranges.ndim != 1:
            raise ScanError(f"scan angles {self.angles.shape!r} and ranges {self.ranges.shape!r} differ")
        if not (np.isfinite(self.range_max) and np.isfinite(self.range_min)) or not (
            0.0 <= self.range_min < self.range_max
        ):
            raise ScanError(f"scan needs 0 <= range_min < range_max, got {self.range_min!r}, {self.range_max!r}")

    @classmethod
    def from_laser_fields(
        cls,
        *,
        stamp: float,
        angle_min: float,
        angle_increment: float,
        ranges: ArrayLike,
        range_min: float,
        range_max: float,
    ) -> Scan:
        """Build from the fields of a ``sensor_msgs/LaserScan``; a clockwise sweep (negative ``angle_increment``)
        is given with its beams reordered so that the angles increase, as every other scanner's."""
        ranges_arr = np.asarray(ranges, dtype=np.float64).reshape(-1)
        if ranges_arr.size == 0:
            raise ScanError("scan has no readings")
        if not np.isfinite(angle_min) or not np.isfinite(angle_increment) or angle_increment == 0.0:
            raise ScanError(f"scan angle_min {angle_min!r} / angle_increment {angle_increment!r} unusable")
        angles = angle_min + angle_increment * np.arange(ranges_arr.size, dtype=np.float64)
        if angle_increment < 0.0:
            return cls(float(stamp), angles[::-1].copy(), ranges_arr[::-1].copy(), float(range_min), float(range_max))
        return cls(float(stamp), angles, ranges_arr, float(range_min), float(range_max))

    # -- classification -----------------------------------------------------------
    @property
    def hit_mask(self) -> NDArray[np.bool_]:
        with np.errstate(invalid="ignore"):
            return np.isfinite(self.ranges) & (self.ranges >= self.range_min) & (self.ranges < self.range_max)

    @property
    def no_return_mask(self) -> NDArray[np.bool_]:
        with np.errstate(invalid="ignore"):
            return (self.ranges == np.inf) | (np.isfinite(self.ranges) & (self.ranges >= self.range_max))

    @property
    def invalid_mask(self) -> NDArray[np.bool_]:
        return ~(self.hit_mask | self.no_return_mask)

    @property
    def beam_count(self) -> int:
        return int(self.ranges.size)

    @property
    def field_of_view(self) -> float:
        """Angular span covered by the beams [rad] (one increment added to the end-to-end span)."""
        if self.angles.size < 2:
            return 0.0
        step = abs(self.angles[1] - self.angles[0])
        return float(min(abs(self.angles[-1] - self.angles[0]) + step, 2.0 * np.pi))

    def clean_ranges(self) -> NDArray[np.float64]:
        """Ranges with no-returns as ``inf`` and invalid readings as NaN."""
        out = np.where(self.hit_mask, self.ranges, np.nan)
        out[self.no_return_mask] = np.inf
        return out

    def hits(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(angles, ranges)`` of the hits only."""
        mask = self.hit_mask
        return self.angles[mask], self.ranges[mask]

    def subsample(self, max_beams: int) -> Scan:
        """At most ``max_beams`` beams, evenly spaced over the scan (as nav2_amcl's ``max_beams``)."""
        if max_beams <= 0 or max_beams >= self.beam_count:
            return self
        index = np.unique(np.round(np.linspace(0, self.beam_count - 1, max_beams)).astype(np.int64))
        return Scan(self.stamp, self.angles[index], self.ranges[index], self.range_min, self.range_max)

    def hit_endpoints(self, laser_pose: ArrayLike) -> NDArray[np.float64]:
        """World points ``(H, 2)`` of the hits seen from ``laser_pose`` ``(3,)``."""
        pose = np.asarray(laser_pose, dtype=np.float64)
        angles, ranges = self.hits()
        heading = pose[2] + angles
        return np.stack([pose[0] + ranges * np.cos(heading), pose[1] + ranges * np.sin(heading)], axis=-1)
