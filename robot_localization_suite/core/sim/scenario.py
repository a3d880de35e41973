"""Simulator scenarios: the validated world (map, start, motion, kidnappings, people, sensor models).

A :class:`Scenario` checks itself on construction: every pose free and ``robot_radius`` from
obstacles (on the map in effect at its time), kidnappings, map changes and reinitialization
requests within the motion, a changed map in the same frame, people off the robot's path start; its
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
    MapChange,
    MotionPlan,
    OdometryConfig,
    Person,
    Reinitialization,
    finite_value,
    format_pose,
    non_negative_value,
    pose_value,
    positive_value,
)
from .trajectory import IntegratedMotion, Trajectory, integrate_motion

__all__ = ["Scenario", "MAX_DURATION_S", "MAX_STEPS", "MIN_SPEED"]

# The true trajectory is integrated at 10 ms sub-steps and kept in memory (about 30 kB a simulated second):
# a scenario lasts at most a day and a million laser steps, and a route is driven at MIN_SPEED m/s or rad/s
# at least (slower, a few metres take days).
MAX_DURATION_S = 86_400.0
MAX_STEPS = 1_000_000
MIN_SPEED = 0.01


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
    map_changes: tuple[MapChange, ...] = ()
    reinitializations: tuple[Reinitialization, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", pose_value("start", list(self.start)))
        non_negative_value("robot_radius", self.robot_radius)
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ScenarioError(f"seed must be an integer >= 0, got {self.seed!r}")  # numpy's SeedSequence needs it
        if self.duration is not None:
            duration = float(self.duration)
            if math.isnan(duration) or duration <= 0.0:
                raise ScenarioError(f"duration must be > 0, got {self.duration!r}")
        if self.motion is not None:
            self._check_motion(self.motion)
        self._check_length()
        self._check_events()
        self.check_pose(self.start, "start pose", self.map_at(0.0))
        for index, kidnap in enumerate(self.kidnappings):
            time = non_negative_value(f"kidnappings[{index}].time", kidnap.time)
            self.check_pose(kidnap.pose, f"kidnappings[{index}].pose (time {time} s)", self.map_at(time))
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
            events = [("kidnappings", k.time) for k in self.kidnappings]
            events += [("map_changes", c.time) for c in self.map_changes]
            events += [("reinitializations", r.time) for r in self.reinitializations]
            counters: dict[str, int] = {}
            for kind, time in events:
                index = counters[kind] = counters.get(kind, -1) + 1
                if time > end + 1e-9:
                    raise ScenarioError(f"{kind}[{index}].time {time!r} s is after the scenario end {end:.1f} s")
            self._check_trajectory()

    # -- world events -------------------------------------------------------------------
    def event_step(self, time: float) -> int:
        """The laser step an event at ``time`` [s] takes effect at: the first at or after it (as kidnappings)."""
        return max(0, int(math.ceil(float(time) / self.period - 1e-9 / self.period)))

    def map_at(self, time: float) -> GridMap:
        """The map the robot senses at ``time`` [s]: the last map change at or before it, else ``grid_map``."""
        current = self.grid_map
        for change in self.map_changes:
            if change.time <= time + 1e-9:
                current = change.grid_map
        return current

    def _check_events(self) -> None:
        """Map changes: times increasing, at least a step apart, the map in the frame of ``grid_map``.
        Reinitialization requests: times increasing."""
        previous = -math.inf
        for index, change in enumerate(self.map_changes):
            time = non_negative_value(f"map_changes[{index}].time", change.time)
            if math.isfinite(previous) and self.event_step(time) <= self.event_step(previous):
                raise ScenarioError(f"map_changes[{index}].time {time!r} s must be at least one laser step after "
                                    f"the previous map change ({previous!r} s)")
            previous = time
            grid, base = change.grid_map, self.grid_map
            name = f"map_changes[{index}].map {change.path or '(grid)'}"
            if not math.isclose(grid.resolution, base.resolution, rel_tol=1e-6):
                raise ScenarioError(f"{name} has resolution {grid.resolution!r} m, the scenario map "
                                    f"{base.resolution!r} m: a changed map must be in the same frame")
            if not np.allclose(grid.origin, base.origin, atol=1e-6):
                raise ScenarioError(f"{name} has origin {list(grid.origin)!r}, the scenario map "
                                    f"{list(base.origin)!r}: a changed map must be in the same frame")
        previous = -math.inf
        for index, request in enumerate(self.reinitializations):
            time = non_negative_value(f"reinitializations[{index}].time", request.time)
            if time < previous:
                raise ScenarioError(f"reinitializations[{index}].time {time!r} s is before the previous one "
                                    f"({previous!r} s): list them in time order")
            previous = time

    # -- validation helpers -----------------------------------------------------------
    def clearance(self, xy: Sequence[float] | NDArray[np.float64], grid_map: GridMap | None = None) -> float:
        """Distance [m] from a point to the nearest obstacle or unknown cell of ``grid_map`` (default: the
        scenario's first map); -1 off the map or not free."""
        grid = self.grid_map if grid_map is None else grid_map
        cell = grid.world_to_cell(np.asarray(xy[:2], dtype=np.float64))
        if not bool(grid.in_bounds(cell)):
            return -1.0
        if not bool(grid.free_mask[cell[1], cell[0]]):
            return -1.0
        field_m = grid.distance_field(unknown_is_obstacle=True)
        # Cell-centre distances: half a cell of slack either way.
        return float(field_m[cell[1], cell[0]]) - 0.5 * grid.resolution

    def check_pose(self, pose: Sequence[float], what: str, grid_map: GridMap | None = None) -> None:
        """Raise :class:`ScenarioError` naming ``what`` and the pose unless it is free with clearance
        on ``grid_map`` (default: the scenario's first map)."""
        grid = self.grid_map if grid_map is None else grid_map
        x0, x1, y0, y1 = grid.extent
        if not (x0 <= pose[0] < x1 and y0 <= pose[1] < y1):
            raise ScenarioError(f"{what} {format_pose(pose)} is off the map (x {x0:.2f}..{x1:.2f}, y {y0:.2f}..{y1:.2f})")
        clearance = self.clearance(pose, grid)
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
        for name in ("linear_speed", "angular_speed"):
            if positive_value(f"motion.{name}", getattr(motion, name)) < MIN_SPEED:
                raise ScenarioError(f"motion.{name} must be >= {MIN_SPEED:g}, got {getattr(motion, name)!r}")
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

    def _check_length(self) -> None:
        """Refuse a duration, velocity segments or an event later than a scenario may last, before integrating."""
        longest = self._longest
        beyond = f"longer than {longest:g} s, the most a scenario may last{self._longest_why}"
        if self.duration is not None and float(self.duration) > longest:
            raise ScenarioError(f"duration {self.duration!r} s is {beyond}")
        if self.duration is None and self.motion is not None and self.motion.segments:
            total = sum(float(segment.duration) for segment in self.motion.segments)
            if total > longest:
                raise ScenarioError(f"motion.segments last {total!r} s, {beyond}")
        for kind, times in (("kidnappings", [k.time for k in self.kidnappings]),
                            ("map_changes", [c.time for c in self.map_changes]),
                            ("reinitializations", [r.time for r in self.reinitializations])):
            for index, time in enumerate(times):
                if float(time) > longest:
                    raise ScenarioError(f"{kind}[{index}].time {time!r} s is after {longest:g} s, the most "
                                        f"a scenario may last{self._longest_why}")

    @property
    def _longest(self) -> float:
        """The most a scenario may last [s]: ``MAX_DURATION_S``, and ``MAX_STEPS`` laser steps at its rate."""
        return min(MAX_DURATION_S, (MAX_STEPS - 1) * self.period)

    @property
    def _longest_why(self) -> str:
        return f" ({MAX_DURATION_S:g} s and {MAX_STEPS} laser steps at laser.rate_hz {self.laser.rate_hz!r})"

    def _check_person(self, index: int, person: Person) -> None:
        positive_value(f"people[{index}].radius", person.radius)
        positive_value(f"people[{index}].speed", person.speed)
        if not person.waypoints:
            raise ScenarioError(f"people[{index}].waypoints must hold at least one [x, y]")
        points = np.asarray(person.waypoints, dtype=np.float64)
        closed = np.vstack([points, points[:1]]) if person.loop else points
        # People walk the whole scenario: their paths must be free on every map it has.
        for grid, which in self._maps():
            for a, b in zip(closed[:-1], closed[1:], strict=True):
                count = max(2, int(np.hypot(*(b - a)) / (0.5 * grid.resolution)) + 1)
                samples = np.linspace(a, b, count)
                free = grid.is_free(samples)
                if not free.all():
                    bad = samples[np.argmin(free)]
                    raise ScenarioError(
                        f"people[{index}] walks through an obstacle{which} at [{bad[0]:.2f}, {bad[1]:.2f}] "
                        f"between {a.tolist()} and {b.tolist()}"
                    )
            if len(points) == 1 and not grid.is_free(points).all():
                raise ScenarioError(f"people[{index}] stands in an obstacle{which} at {points[0].tolist()}")

    def _maps(self) -> list[tuple[GridMap, str]]:
        """Every map of the scenario with how a message names it (empty for the first one)."""
        return [(self.grid_map, "")] + [(c.grid_map, f" of map_changes[{i}] ({c.path or 'grid'})")
                                       for i, c in enumerate(self.map_changes)]

    def _check_trajectory(self) -> None:
        """Every sub-step pose of the true path must keep ``robot_radius`` from the obstacles of the map
        in effect at its time."""
        times, poses = self._dense_times, self._dense_poses
        clearance = np.full(len(poses), -1.0)
        starts = [-math.inf] + [c.time - 1e-9 for c in self.map_changes]
        for (grid, which), start, stop in zip(self._maps(), starts, starts[1:] + [math.inf], strict=True):
            span = (times >= start) & (times < stop)
            field_m = grid.distance_field(unknown_is_obstacle=True)
            cells = grid.world_to_cell(poses[:, :2])
            inside = grid.in_bounds(cells) & span
            ix, iy = cells[inside, 0], cells[inside, 1]
            free = grid.free_mask[iy, ix]
            clearance[inside] = np.where(free, field_m[iy, ix] - 0.5 * grid.resolution, -1.0)
            bad = np.nonzero((clearance < self.robot_radius) & span)[0]
            if bad.size:
                k = int(bad[0])
                raise ScenarioError(
                    f"the robot path reaches {format_pose(poses[k])} at t = {times[k]:.2f} s, "
                    f"{max(clearance[k], 0.0):.3f} m from an obstacle{which} (robot_radius {self.robot_radius} m)"
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
            cached = integrate_motion(
                self.motion, self.start, self.kidnappings, self.period, self.duration, max_time=self._longest
            )
            if self.duration is None and cached[0][-1] >= self._longest - 1e-9:
                raise ScenarioError(f"motion.waypoints do not end within {self._longest:g} s, the most a scenario "
                                    f"may last{self._longest_why}: a shorter route, shorter waits or a duration")
            self.__dict__["_integrated"] = cached
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
