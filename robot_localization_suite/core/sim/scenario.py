"""Simulator scenarios: the validated world (map, start, motion, kidnappings, people, sensor models).

A :class:`Scenario` checks itself on construction: every pose free and ``robot_radius`` from
obstacles, kidnappings on the map and within the motion, people off the robot's path start; its
true :attr:`Scenario.trajectory` is integrated once (:mod:`.trajectory`). Loading from YAML:
:func:`.scenario_yaml.load_scenario`. Layout and choices: docs/simulator.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import ScenarioError
from ..grid_map import GridMap
from .config import (
    CameraConfig,
    Kidnapping,
    LaserConfig,
    MotionPlan,
    OdometryConfig,
    Person,
    finite_value,
    format_pose,
    non_negative_value,
    pose_value,
    positive_value,
)
from .trajectory import IntegratedMotion, Trajectory, integrate_motion

__all__ = ["Scenario"]


# -- the scenario -----------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Scenario:
    """A complete, validated simulation setup. Build with :func:`load_scenario` or directly.

    ``motion`` may be ``None`` (the robot is driven by velocity commands, as
    ``scan_sim`` does with ``cmd_vel``); then ``duration`` may be infinite.
    """

    grid_map: GridMap
    start: tuple[float, float, float]
    motion: MotionPlan | None = None
    kidnappings: tuple[Kidnapping, ...] = ()
    people: tuple[Person, ...] = ()
    laser: LaserConfig = field(default_factory=LaserConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    camera: CameraConfig | None = None
    duration: float | None = None
    robot_radius: float = 0.2
    seed: int = 0
    name: str = "scenario"
    map_path: Path | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", pose_value("start", list(self.start)))
        non_negative_value("robot_radius", self.robot_radius)
        if self.duration is not None:
            duration = float(self.duration)
            if math.isnan(duration) or duration <= 0.0:
                raise ScenarioError(f"duration must be > 0, got {self.duration!r}")
        if self.motion is not None:
            self._check_motion(self.motion)
        self.check_pose(self.start, "start pose")
        for index, kidnap in enumerate(self.kidnappings):
            time = non_negative_value(f"kidnappings[{index}].time", kidnap.time)
            self.check_pose(kidnap.pose, f"kidnappings[{index}].pose (time {time} s)")
            if kidnap.continue_at is not None:
                count = len(self.motion.waypoints) if self.motion is not None else 0
                if not 0 <= kidnap.continue_at < count:
                    raise ScenarioError(
                        f"kidnappings[{index}].continue_at {kidnap.continue_at!r} is not a waypoint index "
                        f"(the motion has {count} waypoints)"
                    )
        for index, person in enumerate(self.people):
            self._check_person(index, person)
        if self.motion is not None:
            end = self.end_time
            for index, kidnap in enumerate(self.kidnappings):
                if kidnap.time > end + 1e-9:
                    raise ScenarioError(
                        f"kidnappings[{index}].time {kidnap.time!r} s is after the scenario end {end:.1f} s"
                    )
            self._check_trajectory()

    # -- validation helpers -----------------------------------------------------------
    def clearance(self, xy: Sequence[float] | NDArray[np.float64]) -> float:
        """Distance [m] from a point to the nearest obstacle or unknown cell; -1 off the map or not free."""
        cell = self.grid_map.world_to_cell(np.asarray(xy[:2], dtype=np.float64))
        if not bool(self.grid_map.in_bounds(cell)):
            return -1.0
        if not bool(self.grid_map.free_mask[cell[1], cell[0]]):
            return -1.0
        field_m = self.grid_map.distance_field(unknown_is_obstacle=True)
        # Cell-centre distances: half a cell of slack either way.
        return float(field_m[cell[1], cell[0]]) - 0.5 * self.grid_map.resolution

    def check_pose(self, pose: Sequence[float], what: str) -> None:
        """Raise :class:`ScenarioError` naming ``what`` and the pose unless it is free with clearance."""
        x0, x1, y0, y1 = self.grid_map.extent
        if not (x0 <= pose[0] < x1 and y0 <= pose[1] < y1):
            raise ScenarioError(f"{what} {format_pose(pose)} is off the map (x {x0:.2f}..{x1:.2f}, y {y0:.2f}..{y1:.2f})")
        clearance = self.clearance(pose)
        if clearance < 0.0:
            raise ScenarioError(f"{what} {format_pose(pose)} lies in an obstacle or unknown cell of the map")
        if clearance < self.robot_radius:
            raise ScenarioError(
                f"{what} {format_pose(pose)} is {clearance:.3f} m from an obstacle, "
                f"closer than robot_radius {self.robot_radius!r} m"
            )

    def _check_motion(self, motion: MotionPlan) -> None:
        if bool(motion.waypoints) == bool(motion.segments):
            raise ScenarioError("motion needs either waypoints or segments (exactly one of them)")
        positive_value("motion.linear_speed", motion.linear_speed)
        positive_value("motion.angular_speed", motion.angular_speed)
        x0, x1, y0, y1 = self.grid_map.extent
        for index, waypoint in enumerate(motion.waypoints):
            if waypoint.is_wait:
                non_negative_value(f"motion.waypoints[{index}].wait", waypoint.wait)
                continue
            if waypoint.x is None or waypoint.y is None:
                raise ScenarioError(f"motion.waypoints[{index}] needs both x and y, got {waypoint!r}")
            if not (x0 <= waypoint.x < x1 and y0 <= waypoint.y < y1):
                raise ScenarioError(
                    f"motion.waypoints[{index}] [{waypoint.x}, {waypoint.y}] is off the map "
                    f"(x {x0:.2f}..{x1:.2f}, y {y0:.2f}..{y1:.2f})"
                )
        for index, segment in enumerate(motion.segments):
            finite_value(f"motion.segments[{index}].v", segment.v)
            finite_value(f"motion.segments[{index}].w", segment.w)
            positive_value(f"motion.segments[{index}].duration", segment.duration)

    def _check_person(self, index: int, person: Person) -> None:
        positive_value(f"people[{index}].radius", person.radius)
        positive_value(f"people[{index}].speed", person.speed)
        if not person.waypoints:
            raise ScenarioError(f"people[{index}].waypoints must hold at least one [x, y]")
        points = np.asarray(person.waypoints, dtype=np.float64)
        closed = np.vstack([points, points[:1]]) if person.loop else points
        for a, b in zip(closed[:-1], closed[1:], strict=True):
            count = max(2, int(np.hypot(*(b - a)) / (0.5 * self.grid_map.resolution)) + 1)
            samples = np.linspace(a, b, count)
            free = self.grid_map.is_free(samples)
            if not free.all():
                bad = samples[np.argmin(free)]
                raise ScenarioError(
                    f"people[{index}] walks through an obstacle at [{bad[0]:.2f}, {bad[1]:.2f}] "
                    f"between {a.tolist()} and {b.tolist()}"
                )
        if len(points) == 1 and not self.grid_map.is_free(points).all():
            raise ScenarioError(f"people[{index}] stands in an obstacle at {points[0].tolist()}")

    def _check_trajectory(self) -> None:
        """Every sub-step pose of the true path must keep ``robot_radius`` from obstacles."""
        times, poses = self._dense_times, self._dense_poses
        field_m = self.grid_map.distance_field(unknown_is_obstacle=True)
        cells = self.grid_map.world_to_cell(poses[:, :2])
        inside = self.grid_map.in_bounds(cells)
        clearance = np.full(len(poses), -1.0)
        ix, iy = cells[inside, 0], cells[inside, 1]
        free = self.grid_map.free_mask[iy, ix]
        clearance[inside] = np.where(free, field_m[iy, ix] - 0.5 * self.grid_map.resolution, -1.0)
        bad = np.nonzero(clearance < self.robot_radius)[0]
        if bad.size:
            k = int(bad[0])
            raise ScenarioError(
                f"the robot path reaches {format_pose(poses[k])} at t = {times[k]:.2f} s, "
                f"{max(clearance[k], 0.0):.3f} m from an obstacle (robot_radius {self.robot_radius} m)"
            )

    # -- timing ---------------------------------------------------------------------------
    @property
    def period(self) -> float:
        return self.laser.period

    @property
    def end_time(self) -> float:
        """When the scenario ends [s] (``inf`` for a command-driven scenario without a duration)."""
        if self.motion is None:
            return math.inf if self.duration is None else float(self.duration)
        return float(self.trajectory.times[-1])

    @property
    def step_count(self) -> int:
        """Number of laser steps including the one at t = 0 (requires a motion plan or a duration)."""
        if self.motion is None:
            if self.duration is None:
                raise ScenarioError("a command-driven scenario without a duration has no step count")
            return int(math.ceil(float(self.duration) / self.period - 1e-9)) + 1
        return len(self.trajectory.times)

    # -- the true trajectory ------------------------------------------------------------------
    def _integrate(self) -> IntegratedMotion:
        """The integrated motion (:func:`.trajectory.integrate_motion`), computed once."""
        cached = self.__dict__.get("_integrated")
        if cached is None:
            assert self.motion is not None
            cached = self.__dict__["_integrated"] = integrate_motion(
                self.motion, self.start, self.kidnappings, self.period, self.duration
            )
        return cached

    @property
    def _dense_times(self) -> NDArray[np.float64]:
        return self._integrate()[0]

    @property
    def _dense_poses(self) -> NDArray[np.float64]:
        return self._integrate()[1]

    @cached_property
    def trajectory(self) -> Trajectory:
        """The true trajectory at every laser step (requires a motion plan)."""
        if self.motion is None:
            raise ScenarioError("a scenario without motion has no precomputed trajectory")
        _, _, poses, motion_end, velocities, kidnapped = self._integrate()
        count = len(poses)
        return Trajectory(
            times=np.arange(count, dtype=np.float64) * self.period,
            poses=poses,
            motion_end=motion_end,
            velocities=velocities,
            kidnapped=kidnapped,
        )

    def people_at(self, time: float) -> NDArray[np.float64]:
        """``(K, 3)`` people as ``x, y, radius`` [m] at ``time`` [s]."""
        if not self.people:
            return np.zeros((0, 3))
        return np.array([[*person.position(time), person.radius] for person in self.people])
