"""The outlier case of Guyonneau et al. 2014, section 5.3 (Figures 13 and 14), as arrays and as a bag.

    python -m robot_localization_suite.tools.ial_outlier_case bags/room_outliers_bounded

A room 8 m x 5 m whose walls and furniture are symmetric under a half turn
about its centre, except one cabinet. The robot (laser) stands at ``A`` and
turns in place; ``B`` is the image of ``A`` under the half turn. Seen from
``A`` and seen (in the map) from ``B``, the scans differ in exactly 8 of the
36 beams (those that meet the cabinet from one pose and not the other). In
every scan those 8 readings are *outliers*: they read what ``B`` would see
(a person occluding, a glass pane, a reflection: anything the bounded-error
model does not describe), the other 28 read ``A``'s true ranges within
+-3 cm. So the pose that best explains the scan is ``B``, not ``A``: a
filter that maximises ``p(y | q)`` (MCL) settles on ``B``, while IAL with
``n_o = 8`` keeps ``A`` in its boxes (and ``B``: the data cannot tell them
apart under that bound).

The robot turns by exactly one beam spacing (10 degrees) per scan, so that
each scan is the first one shifted by whole beams and the outliers stay
exactly 8; odometry reports the turn exactly and the robot does not
translate, which is inside any odometry bound.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..core.grid_map import GridMap
from ..core.raycast import RayCaster
from ..core.scan import Scan
from ..core.se2 import wrap_angle

__all__ = ["OutlierCase", "symmetric_room", "outlier_case", "write_bag", "main"]

RESOLUTION = 0.05
ROOM_W, ROOM_H = 8.0, 5.0
BEAMS = 36
RANGE_MIN, RANGE_MAX = 0.1, 10.0
RANGE_NOISE = 0.03  # [m], inside IAL's eps_y = 0.05
# The only feature without a half-turn twin [m]: x0, y0, x1, y1.
CABINET = (5.0, 0.5, 6.4, 1.3)
TRUE_POSE = (5.2, 2.4, 0.4)


@dataclass(frozen=True)
class OutlierCase:
    """The world and the scans of the section 5.3 case.

    Attributes:
        grid_map: the room.
        true_poses: ``(N, 3)`` laser (= robot) poses at each scan, ``A`` turning in place.
        twin_poses: ``(N, 3)`` the half-turn images ``B`` of those poses.
        scans: the ``N`` scans.
        outliers: ``(N, 36)`` which readings are outliers.
        stamps: ``(N,)`` [s].
    """

    grid_map: GridMap
    true_poses: NDArray[np.float64]
    twin_poses: NDArray[np.float64]
    scans: list[Scan]
    outliers: NDArray[np.bool_]
    stamps: NDArray[np.float64]


def symmetric_room() -> GridMap:
    """The room: walls and two pieces of furniture symmetric under a half turn, plus the cabinet."""
    data = np.zeros((int(round(ROOM_H / RESOLUTION)), int(round(ROOM_W / RESOLUTION))), dtype=np.int8)

    def block(x0: float, y0: float, x1: float, y1: float) -> None:
        data[int(round(y0 / RESOLUTION)) : int(round(y1 / RESOLUTION)),
             int(round(x0 / RESOLUTION)) : int(round(x1 / RESOLUTION))] = 100

    def twin_blocks(x0: float, y0: float, x1: float, y1: float) -> None:
        block(x0, y0, x1, y1)
        block(ROOM_W - x1, ROOM_H - y1, ROOM_W - x0, ROOM_H - y0)

    twin_blocks(0.0, 0.0, ROOM_W, 0.15)
    twin_blocks(0.0, 0.0, 0.15, ROOM_H)
    twin_blocks(2.0, 1.0, 2.6, 1.4)
    twin_blocks(1.0, 3.5, 1.3, 4.2)
    block(*CABINET)
    return GridMap(data, RESOLUTION, (0.0, 0.0))


def half_turn(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Images of poses ``(N, 3)`` under the half turn about the room's centre."""
    out = np.empty_like(poses)
    out[:, 0] = ROOM_W - poses[:, 0]
    out[:, 1] = ROOM_H - poses[:, 1]
    out[:, 2] = wrap_angle(poses[:, 2] + math.pi)
    return out


def outlier_case(scans: int = 150, *, seed: int = 0, rate_hz: float = 10.0) -> OutlierCase:
    """The robot at ``A`` turning 10 degrees per scan; 8 outliers per scan read ``B``'s ranges."""
    grid_map = symmetric_room()
    angles = -math.pi + 2.0 * math.pi * np.arange(BEAMS) / BEAMS
    steps = np.arange(scans)
    true = np.tile(np.asarray(TRUE_POSE, dtype=np.float64), (scans, 1))
    true[:, 2] = wrap_angle(TRUE_POSE[2] + steps * (2.0 * math.pi / BEAMS))
    twin = half_turn(true)
    caster = RayCaster(grid_map, max_range=RANGE_MAX)
    from_true = caster.cast(true, angles).astype(np.float64)
    from_twin = caster.cast(twin, angles).astype(np.float64)
    outliers = np.abs(from_true - from_twin) > 0.1
    rng = np.random.default_rng(seed)
    ranges = np.where(outliers, from_twin, from_true) + rng.uniform(-RANGE_NOISE, RANGE_NOISE, from_true.shape)
    stamps = steps / rate_hz
    scan_list = [Scan(float(stamps[k]), angles.copy(), ranges[k].astype(np.float32).astype(np.float64),
                      RANGE_MIN, RANGE_MAX) for k in range(scans)]
    return OutlierCase(grid_map, true, twin, scan_list, outliers, stamps)


def write_bag(path: str | Path, case: OutlierCase | None = None) -> Path:
    """Write the case as an MCAP bag with ``/map``, ``/odom``, ``/ground_truth`` and ``/scan`` (as scan_sim does)."""
    from ..ros import conversions
    from ..ros.bag import BagWriter

    case = case or outlier_case()
    start = case.true_poses[0]
    angles = case.scans[0].angles
    with BagWriter(path, compress=True) as writer:
        writer.write("/map", conversions.grid_map_to_msg(case.grid_map, 0.0), 0)
        for k, scan in enumerate(case.scans):
            stamp_ns = int(round(case.stamps[k] * 1e9))
            odom = np.array([0.0, 0.0, float(wrap_angle(case.true_poses[k, 2] - start[2]))])
            writer.write("/odom", conversions.odometry_to_msg(case.stamps[k], odom, frame_id="odom"), stamp_ns)
            writer.write("/ground_truth",
                         conversions.odometry_to_msg(case.stamps[k], case.true_poses[k], frame_id="map"), stamp_ns)
            writer.write("/scan", conversions.scan_to_msg(
                case.stamps[k], "laser", angle_min=float(angles[0]), angle_increment=float(angles[1] - angles[0]),
                ranges=scan.ranges, range_min=RANGE_MIN, range_max=RANGE_MAX, scan_time=0.1), stamp_ns)
    return Path(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ial_outlier_case", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", help="new bag directory, e.g. bags/room_outliers_bounded")
    parser.add_argument("--scans", type=int, default=150)
    args = parser.parse_args(argv)
    case = outlier_case(args.scans)
    write_bag(args.bag, case)
    print(f"ial_outlier_case: {args.scans} scans, {int(case.outliers.sum(axis=1).max())} outliers per scan "
          f"at most, written to {args.bag!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
