"""A hand-made world and the map a SLAM run would have left of it, for IAL on real-log-like data.

The world (14 m x 10 m at 1 cm) holds a building (1..13 m x 1..9 m, 12 cm walls) with a
window in its west wall, an inner wall with a door, a room the mapping run never entered
(seen only through its door) and some furniture; beyond the window, the world's own edge.
The map (5 cm) marks a cell occupied when its centre lies inside a wall (what SLAM does, so
walls are off by up to a cell: map_margin one cell), and leaves unknown everything outside
the building, the inside of the unmapped room and a 40 cm stretch of the inner wall (a wall
with a gap). The robot drives through the building with a 180-degree scanner: readings
through the window, through the room's door and onto the missing stretch end in unknown
space. Odometry is Thrun's model with the real-log bags' alphas (tools/carmen_to_bag.py),
its Gaussian draws stopped at 4 sigma so that the 4-sigma bounds of
config/ial_localizer_slam.yaml hold.
"""

from __future__ import annotations

import math

import numpy as np

from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.motion import OdometryMotionModel
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.scan import Scan

EPS = 0.04  # range noise bound [m], under the config's range_error
RANGE_MAX = 10.0
ANGLES_180 = np.radians(np.arange(-90.0, 90.0, 1.0))
ALPHAS = (1.2e-3, 1e-4, 4e-4, 1e-4)  # carmen_to_bag's defaults
WAYPOINTS = [(3.0, 2.0), (5.0, 3.6), (7.0, 3.6), (8.5, 4.2), (10.9, 4.6), (11.5, 3.0), (10.0, 2.0), (7.0, 3.4),
             (5.0, 3.5), (3.0, 4.5), (2.0, 4.5), (2.5, 7.5), (4.5, 8.0)]


def slam_world() -> tuple[GridMap, GridMap]:
    """``(world, slam_map)``: the 1 cm world the scans come from and the 5 cm map the localizer gets."""
    fine = np.zeros((1000, 1400), dtype=np.int8)

    def wall(x0: float, y0: float, x1: float, y1: float) -> None:
        fine[round(y0 * 100) : round(y1 * 100), round(x0 * 100) : round(x1 * 100)] = 100

    for box in (
        (0, 0, 14, 0.1), (0, 9.9, 14, 10), (0, 0, 0.1, 10), (13.9, 0, 14, 10),  # the world's edge
        (1, 1, 13, 1.12), (1, 8.88, 13, 9), (12.88, 1, 13, 9),  # the building
        (1, 1, 1.12, 4), (1, 5, 1.12, 9),  # its west wall, a window at y 4..5
        (5.94, 1, 6.06, 3), (5.94, 4.2, 6.06, 9),  # an inner wall, a door at y 3..4.2
        (9, 5.94, 10.4, 6.06), (11.4, 5.94, 13, 6.06), (8.94, 5.94, 9.06, 9),  # the room never entered
        (11.5, 7.5, 12.2, 8.2),  # furniture in it
        (3, 6.5, 3.8, 7.0), (8, 2, 8.5, 2.6),  # furniture in the mapped part
    ):
        wall(*box)
    data = np.where(fine[2::5, 2::5] > 0, 100, 0).astype(np.int8)  # a cell centre inside a wall: occupied

    def unknown(x0: float, y0: float, x1: float, y1: float) -> None:
        data[round(y0 * 20) : round(y1 * 20), round(x0 * 20) : round(x1 * 20)] = -1

    for box in (
        (0, 0, 14, 1), (0, 9, 14, 10), (0, 0, 1, 10), (13, 0, 14, 10),  # outside the building
        (9.1, 6.1, 12.85, 8.85),  # the room never entered
        (5.9, 6.5, 6.1, 6.9),  # a stretch of wall the map missed
    ):
        unknown(*box)
    return GridMap(fine, 0.01), GridMap(data, 0.05)


def drive(step: float = 0.3) -> np.ndarray:
    """True poses ``(N, 3)`` along the waypoints, heading along the way."""
    poses = []
    for (x0, y0), (x1, y1) in zip(WAYPOINTS[:-1], WAYPOINTS[1:], strict=True):
        heading = math.atan2(y1 - y0, x1 - x0)
        count = max(1, math.ceil(math.hypot(x1 - x0, y1 - y0) / step))
        poses += [(x0 + (x1 - x0) * k / count, y0 + (y1 - y0) * k / count, heading) for k in range(count)]
    return np.array(poses)


class _ClippedNormal:
    """Standard normal draws stopped at +-4: Gaussian odometry within the 4-sigma bounds."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def normal(self, loc: float, scale: float, size: int) -> np.ndarray:
        return np.clip(self.rng.normal(loc, scale, size), -4.0, 4.0)


def odometry(truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Odometry poses ``(N, 3)`` from the origin, each true step through Thrun's model (ALPHAS)."""
    model, noise = OdometryMotionModel(*ALPHAS), _ClippedNormal(rng)
    odom = np.zeros_like(truth)
    for k in range(1, len(truth)):
        odom[k] = model.sample(odom[k - 1 : k], truth[k - 1], truth[k], noise)[0]
    return odom


def scans(world: GridMap, truth: np.ndarray, rng: np.random.Generator) -> list[Scan]:
    """180-degree scans at the true poses, each reading within +-EPS of the world's range (float32)."""
    exact = RayCaster(world, max_range=RANGE_MAX).cast(truth, ANGLES_180).astype(np.float64)
    noisy = exact + rng.uniform(-EPS, EPS, exact.shape)
    return [Scan(0.1 * k, ANGLES_180.copy(), noisy[k].astype(np.float32).astype(np.float64), 0.05, RANGE_MAX)
            for k in range(len(truth))]


def unexplained(slam_map: GridMap, pose: np.ndarray, angles: np.ndarray, ranges: np.ndarray, margin: float) -> int:
    """Readings whose end point lies farther than ``margin`` from every occupied cell (unknown or free space)."""
    occupied = slam_map.occupied_mask
    resolution = slam_map.resolution
    count = 0
    for angle, distance in zip(angles, ranges, strict=True):
        x, y = pose[0] + distance * math.cos(pose[2] + angle), pose[1] + distance * math.sin(pose[2] + angle)
        col, row = int(x // resolution), int(y // resolution)
        near = False
        for r in range(row - 2, row + 3):
            for c in range(col - 2, col + 3):
                if 0 <= r < occupied.shape[0] and 0 <= c < occupied.shape[1] and occupied[r, c]:
                    dx = max(c * resolution - x, 0.0, x - (c + 1) * resolution)
                    dy = max(r * resolution - y, 0.0, y - (r + 1) * resolution)
                    near |= dx * dx + dy * dy <= margin * margin
        count += not near
    return count
