"""Map coverage of a bag's scans: per ``/scan``, the share of its hit end points a map explains at the true pose.

The metric is ``core.metrics.map_coverage`` (docs/benchmark.md, "Map coverage"); this module
only reads the bag. ``ScanCoverage.at`` gives each localizer output its scan's coverage.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core import metrics
from ..core.errors import BagError
from ..core.grid_map import GridMap
from ..core.scan import LaserMount
from ..ros import conversions
from ..ros.bag import read_bag

__all__ = ["ScanCoverage", "bag_scan_coverage"]


@dataclass(frozen=True)
class ScanCoverage:
    """Per scan of a bag: its stamp [s] and its map coverage (NaN: no hit, or no ground truth)."""

    stamps: NDArray[np.float64]
    coverage: NDArray[np.float64]

    def at(self, output_stamps: ArrayLike) -> NDArray[np.float64]:
        """Coverage of the scan each output was computed from (outputs carry their scan's stamp)."""
        return metrics.coverage_at_stamps(output_stamps, self.stamps, self.coverage)

    @property
    def median(self) -> float | None:
        finite = self.coverage[np.isfinite(self.coverage)]
        return float(np.median(finite)) if finite.size else None


def bag_scan_coverage(
    bag: str | os.PathLike[str],
    grid_map: GridMap,
    *,
    mount: LaserMount | None = None,
    tolerance: float | None = None,
    scan_topic: str = "/scan",
    truth_topic: str = "/ground_truth",
    odom_topic: str = "/odom",
    remap: Mapping[str, str] | None = None,
) -> ScanCoverage:
    """``metrics.map_coverage`` of every scan of ``bag`` on ``grid_map``, at the ground truth.

    The truth (robot base poses) is interpolated at each scan's stamp, never across a
    kidnapping (``metrics.detect_kidnappings`` with the bag's odometry), and the laser placed
    by ``mount`` (its scans levelled). ``tolerance`` [m] defaults to two map cells; ``remap`` as ``read_bag``.

    Raises:
        BagError: the bag cannot be read, or has no scan or no ground truth.
    """
    scans, truth, odom = [], [], []
    for item in read_bag(bag, [scan_topic, truth_topic, odom_topic], remap=remap):
        if item.topic == scan_topic:
            scans.append(conversions.scan_from_msg(item.msg))
        elif item.topic == truth_topic:
            truth.append(conversions.odometry_from_msg(item.msg))
        else:
            odom.append(conversions.odometry_from_msg(item.msg))
    if not scans:
        raise BagError(f"bag {str(bag)!r} has no {scan_topic} message")
    if not truth:
        raise BagError(f"bag {str(bag)!r} has no {truth_topic} message: coverage needs the true pose")
    ground_truth = metrics.Trajectory(np.array([s for s, _ in truth]), np.array([p for _, p in truth]))
    odometry = metrics.Trajectory(np.array([s for s, _ in odom]), np.array([p for _, p in odom])) if odom else None
    stamps = np.array([scan.stamp for scan in scans])
    base = metrics.interpolate_poses(ground_truth, stamps,
                                     breaks=metrics.detect_kidnappings(ground_truth, odometry))
    mount = mount or LaserMount()
    laser = mount.laser_poses(base)
    scans = [mount.level(scan) for scan in scans]
    beams = max(scan.beam_count for scan in scans)
    ranges = np.full((len(scans), beams), np.nan)
    angles = np.zeros((len(scans), beams))
    for row, scan in enumerate(scans):
        ranges[row, : scan.beam_count] = scan.ranges
        angles[row, : scan.beam_count] = scan.angles
    coverage = metrics.map_coverage(
        grid_map,
        np.nan_to_num(laser),
        angles,
        ranges,
        range_max=np.array([scan.range_max for scan in scans]),
        range_min=np.array([scan.range_min for scan in scans]),
        tolerance=tolerance,
    )
    coverage[~np.all(np.isfinite(laser), axis=1)] = np.nan
    return ScanCoverage(stamps, coverage)
