"""A small simulated world for the MCL tests: a hand-made office map, a drive, scans and odometry.

The map is 16 m x 10 m at 5 cm with walls, doors and furniture placed so that
no two places look alike (no rotational or mirror symmetry). Scans come from
the shared RayCaster with Gaussian range noise and a few outliers; odometry
accumulates a few percent of noise on each step, as wheel odometry does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.scan import Scan
from robot_localization_suite.core.se2 import compose, relative, wrap_angle

RESOLUTION = 0.05
WIDTH_M, HEIGHT_M = 16.0, 10.0


def office_map() -> GridMap:
    """Occupied walls and boxes on a free floor; everything outside the walls unknown."""
    width, height = int(WIDTH_M / RESOLUTION), int(HEIGHT_M / RESOLUTION)
    data = np.zeros((height, width), dtype=np.int8)

    def box(x0: float, y0: float, x1: float, y1: float, value: int = 100) -> None:
        data[int(y0 / RESOLUTION) : int(np.ceil(y1 / RESOLUTION)), int(x0 / RESOLUTION) : int(np.ceil(x1 / RESOLUTION))] = value

    # outer walls
    box(0.0, 0.0, 16.0, 0.15)
    box(0.0, 9.85, 16.0, 10.0)
    box(0.0, 0.0, 0.15, 10.0)
    box(15.85, 0.0, 16.0, 10.0)
    # inner wall at x = 6 with a door at y in [3, 4.2]; wall at y = 6 from x = 6 to 16 with a door at x in [11, 12]
    box(5.9, 0.0, 6.1, 3.0)
    box(5.9, 4.2, 6.1, 10.0)
    box(6.0, 5.9, 11.0, 6.1)
    box(12.0, 5.9, 16.0, 6.1)
    # furniture (asymmetric)
    box(1.5, 1.5, 2.5, 2.0)
    box(3.5, 6.5, 4.0, 8.5)
    box(1.0, 8.0, 2.2, 8.4)
    box(8.0, 2.0, 9.5, 2.6)
    box(13.0, 1.0, 13.4, 3.5)
    box(8.0, 7.5, 8.6, 8.1)
    box(14.0, 8.0, 15.0, 9.2)
    box(10.2, 4.0, 10.5, 4.3)
    return GridMap(data, RESOLUTION, (0.0, 0.0))


# A loop through the three rooms, clear of obstacles [m, m].
WAYPOINTS = np.array(
    [
        [2.0, 4.0], [4.5, 4.5], [4.8, 3.6], [7.5, 3.6], [9.8, 3.4], [11.0, 1.5], [12.3, 4.0],
        [14.5, 4.5], [11.5, 5.0], [11.5, 7.5], [9.5, 8.8], [7.0, 8.8], [7.0, 7.0], [11.5, 7.2], [11.5, 5.0],
        [7.5, 4.0], [4.8, 3.6], [3.0, 5.5], [1.2, 6.0], [1.0, 3.0], [2.0, 4.0],
    ]
)


@dataclass
class Drive:
    """A simulated run: per step, time, true base pose, odometry pose and the scan."""

    stamps: np.ndarray
    truth: np.ndarray
    odometry: np.ndarray
    scans: list[Scan]


def _follow(waypoints: np.ndarray, start_index: int, steps: int, step_m: float) -> np.ndarray:
    """True poses ``(steps, 3)`` along the waypoint loop from waypoint ``start_index``."""
    path = np.roll(waypoints[:-1], -start_index, axis=0)
    path = np.vstack([path, path[:1]])
    target = 1
    position = path[0].astype(float)
    heading = float(np.arctan2(*(path[1] - path[0])[::-1]))
    truth = []
    for _ in range(steps):
        to_goal = path[target] - position
        if np.hypot(*to_goal) < step_m:
            target = target % (len(path) - 1) + 1
            to_goal = path[target] - position
        turn = float(wrap_angle(np.arctan2(to_goal[1], to_goal[0]) - heading))
        heading = float(wrap_angle(heading + np.clip(turn, -0.3, 0.3)))
        if abs(turn) < 0.6:
            position = position + step_m * np.array([np.cos(heading), np.sin(heading)])
        truth.append([position[0], position[1], heading])
    return np.array(truth)


def drive(
    grid_map: GridMap,
    *,
    steps: int,
    seed: int = 0,
    step_m: float = 0.05,
    beams: int = 181,
    fov: float = np.radians(270.0),
    range_max: float = 10.0,
    range_noise: float = 0.02,
    outlier_rate: float = 0.02,
    odometry_noise: float = 0.03,
    waypoints: np.ndarray = WAYPOINTS,
    start_index: int = 0,
    kidnap_step: int | None = None,
    kidnap_index: int = 9,
) -> Drive:
    """Follow the waypoint loop for ``steps`` scans, ``step_m`` apart (10 Hz at 0.5 m/s for 0.05 m).

    With ``kidnap_step``, the robot is carried to waypoint ``kidnap_index`` at that
    step and drives on from there; odometry sees no motion for the jump.
    """
    rng = np.random.default_rng(seed)
    caster = RayCaster(grid_map, max_range=range_max)
    angles = np.linspace(-fov / 2.0, fov / 2.0, beams)
    if kidnap_step is None:
        truth_arr = _follow(waypoints, start_index, steps, step_m)
    else:
        truth_arr = np.vstack(
            [
                _follow(waypoints, start_index, kidnap_step, step_m),
                _follow(waypoints, kidnap_index, steps - kidnap_step, step_m),
            ]
        )
    stamps = 0.1 * np.arange(steps)
    # odometry: integrate the true relative steps with multiplicative noise
    odometry = [np.zeros(3)]
    for k in range(1, steps):
        step_pose = np.zeros(3) if k == kidnap_step else relative(truth_arr[k - 1], truth_arr[k])
        noisy = step_pose * (1.0 + odometry_noise * rng.standard_normal(3))
        noisy[2] += 0.2 * odometry_noise * np.hypot(step_pose[0], step_pose[1]) * rng.standard_normal()
        odometry.append(compose(odometry[-1], noisy))
    ranges = caster.cast(truth_arr, angles).astype(np.float64)
    noise = range_noise * rng.standard_normal(ranges.shape)
    ranges = np.where(np.isfinite(ranges), ranges + noise, np.inf)
    outliers = rng.random(ranges.shape) < outlier_rate
    ranges[outliers] = rng.uniform(0.1, range_max, size=int(outliers.sum()))
    ranges[ranges >= range_max] = np.inf
    scans = [Scan(float(stamps[k]), angles.copy(), ranges[k], 0.05, range_max) for k in range(steps)]
    return Drive(stamps, truth_arr, np.array(odometry), scans)


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Position error [m] and absolute heading error [rad]."""
    return float(np.hypot(*(estimate[:2] - truth[:2]))), float(abs(wrap_angle(estimate[2] - truth[2])))
