"""Simulator scenarios: what the simulated world and robot do, loaded from YAML.

A scenario names a map (nav2 map_server YAML, path relative to the scenario
file), a start pose, how the robot moves (waypoints, followed
rotate-then-drive, or velocity segments), when it is kidnapped, which
unmapped people walk around, and the laser, odometry and (optionally) camera
models. Everything is validated on load; a :class:`ScenarioError` names the
field and the bad value. The true trajectory does not depend on any noise: it
is integrated once (exact unicycle arcs) and checked to keep ``robot_radius``
from obstacles.

YAML layout and the choices made here: docs/simulator.md.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from ..errors import MapError, ScenarioError
from ..grid_map import GridMap, load_map_yaml
from ..se2 import angle_difference, wrap_angle

__all__ = [
    "LaserConfig",
    "OdometryConfig",
    "CameraConfig",
    "Person",
    "Kidnapping",
    "Waypoint",
    "VelocitySegment",
    "MotionPlan",
    "Trajectory",
    "Scenario",
    "load_scenario",
    "RANGE_NOISE_MODELS",
    "ODOMETRY_MODELS",
    "CAMERA_ENCODINGS",
]

RANGE_NOISE_MODELS = ("gaussian", "uniform")
ODOMETRY_MODELS = ("alphas", "bounded")
CAMERA_ENCODINGS = ("mono8", "rgb8")

# Longest integration sub-step of the true motion [s].
_MAX_SUBSTEP = 0.01


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise ScenarioError(f"{name} must be a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ScenarioError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ScenarioError(f"{name} must be finite, got {value!r}")
    return number


def _non_negative(name: str, value: Any) -> float:
    number = _finite(name, value)
    if number < 0.0:
        raise ScenarioError(f"{name} must be >= 0, got {value!r}")
    return number


def _positive(name: str, value: Any) -> float:
    number = _finite(name, value)
    if number <= 0.0:
        raise ScenarioError(f"{name} must be > 0, got {value!r}")
    return number


def _probability(name: str, value: Any) -> float:
    number = _finite(name, value)
    if not 0.0 <= number <= 1.0:
        raise ScenarioError(f"{name} must be within [0, 1], got {value!r}")
    return number


def _pose(name: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ScenarioError(f"{name} must be [x, y, yaw], got {value!r}")
    x, y, yaw = (_finite(name, v) for v in value)
    return (x, y, float(wrap_angle(yaw)))


def _point(name: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ScenarioError(f"{name} must be [x, y], got {value!r}")
    return (_finite(name, value[0]), _finite(name, value[1]))


def _fmt_pose(pose: Sequence[float]) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in pose) + "]"


# -- sensor and odometry models -------------------------------------------------------
@dataclass(frozen=True)
class LaserConfig:
    """The simulated 2-D laser scanner.

    Defaults describe a 360 degree indoor scanner (e.g. a SICK/Hokuyo pair or an
    RPLIDAR class sensor): 1 degree beams, 12 m range, 10 Hz, 1.5 cm range noise
    (manufacturers quote 1-3 cm), 1.5 % outliers, 0.5 % dropouts.

    Attributes:
        beams: number of beams.
        fov_deg: field of view [deg], 90..360. At 360 the beams are ``2 pi / beams``
            apart starting at ``-pi`` (no duplicate beam); below 360 they span
            ``[-fov/2, +fov/2]`` end to end.
        range_min, range_max: valid interval [m]; readings at or beyond ``range_max``
            are published as ``+inf``, hits closer than ``range_min`` as ``-inf`` (REP 117).
        rate_hz: scans per second; the simulator steps at this rate.
        range_noise_std: standard deviation of Gaussian range noise [m].
        range_noise_model: ``gaussian`` or ``uniform`` (bounded: ``+-range_noise_bound``,
            what interval methods assume).
        range_noise_bound: half-width of the uniform noise [m].
        outlier_prob: probability that a beam reads a random range uniform in
            ``[range_min, range_max)`` (Probabilistic Robotics' ``p_rand``).
        dropout_prob: probability that a beam returns nothing (``+inf``).
        mount: laser pose in the robot base frame [m, m, rad].
    """

    beams: int = 360
    fov_deg: float = 360.0
    range_min: float = 0.1
    range_max: float = 12.0
    rate_hz: float = 10.0
    range_noise_std: float = 0.015
    range_noise_model: str = "gaussian"
    range_noise_bound: float = 0.05
    outlier_prob: float = 0.015
    dropout_prob: float = 0.005
    mount: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if isinstance(self.beams, bool) or not isinstance(self.beams, (int, np.integer)) or self.beams < 2:
            raise ScenarioError(f"laser.beams must be an integer >= 2, got {self.beams!r}")
        fov = _finite("laser.fov_deg", self.fov_deg)
        if not 90.0 <= fov <= 360.0:
            raise ScenarioError(f"laser.fov_deg must be within [90, 360], got {self.fov_deg!r}")
        range_min = _non_negative("laser.range_min", self.range_min)
        range_max = _positive("laser.range_max", self.range_max)
        if range_min >= range_max:
            raise ScenarioError(f"laser.range_min {self.range_min!r} must be below laser.range_max {self.range_max!r}")
        _positive("laser.rate_hz", self.rate_hz)
        _non_negative("laser.range_noise_std", self.range_noise_std)
        _non_negative("laser.range_noise_bound", self.range_noise_bound)
        if self.range_noise_model not in RANGE_NOISE_MODELS:
            raise ScenarioError(
                f"laser.range_noise_model must be one of {RANGE_NOISE_MODELS}, got {self.range_noise_model!r}"
            )
        _probability("laser.outlier_prob", self.outlier_prob)
        _probability("laser.dropout_prob", self.dropout_prob)
        object.__setattr__(self, "mount", _pose("laser.mount", list(self.mount)))

    @property
    def angle_increment(self) -> float:
        """Angle between neighbouring beams [rad]."""
        fov = math.radians(self.fov_deg)
        return fov / self.beams if self.fov_deg >= 360.0 else fov / (self.beams - 1)

    @property
    def angle_min(self) -> float:
        """Angle of the first beam in the laser frame [rad]."""
        return -math.pi if self.fov_deg >= 360.0 else -math.radians(self.fov_deg) / 2.0

    @property
    def angles(self) -> NDArray[np.float64]:
        """``(beams,)`` beam angles in the laser frame [rad]."""
        return self.angle_min + self.angle_increment * np.arange(self.beams, dtype=np.float64)

    @property
    def period(self) -> float:
        return 1.0 / float(self.rate_hz)


@dataclass(frozen=True)
class OdometryConfig:
    """Wheel odometry error: random noise plus systematic drift.

    ``model: alphas`` perturbs each step (one laser period) with
    :class:`~robot_localization_suite.core.motion.OdometryMotionModel` and these
    alphas (nav2_amcl's meaning: alpha scales a variance). Driving a metre in
    5 cm steps, the defaults give about 5 cm of translation error and 1.3
    degrees of heading error (one standard deviation); a full turn in place
    in 0.1 rad steps about 4 degrees: a usable wheel odometry that nav2-like filters (nav2's alphas are
    0.2 per update) track easily.

    ``model: bounded`` draws each component of the step's rot1-trans-rot2
    decomposition uniformly inside ``value +- (relative * |value| + absolute)``
    (:meth:`OdometryMotionModel.bounds`); drift is added and the total error
    is clipped to the bounds, so the bounds hold for every step, as interval
    methods require. A step with no true motion gives no odometry motion.

    Drift (both models) is systematic, as from a wrong wheel diameter or wheel
    base (Borenstein's UMBmark): the reported translation is scaled by
    ``1 + scale_error`` and the heading turns by ``heading_drift`` rad per metre.
    """

    model: str = "alphas"
    alpha1: float = 0.01
    alpha2: float = 0.005
    alpha3: float = 0.05
    alpha4: float = 0.01
    relative_translation: float = 0.05
    absolute_translation: float = 0.002
    relative_rotation: float = 0.05
    absolute_rotation: float = 0.002
    scale_error: float = 0.0
    heading_drift: float = 0.0

    def __post_init__(self) -> None:
        if self.model not in ODOMETRY_MODELS:
            raise ScenarioError(f"odometry.model must be one of {ODOMETRY_MODELS}, got {self.model!r}")
        for name in (
            "alpha1",
            "alpha2",
            "alpha3",
            "alpha4",
            "relative_translation",
            "absolute_translation",
            "relative_rotation",
            "absolute_rotation",
        ):
            _non_negative(f"odometry.{name}", getattr(self, name))
        scale = _finite("odometry.scale_error", self.scale_error)
        if abs(scale) >= 0.5:
            raise ScenarioError(f"odometry.scale_error must be within (-0.5, 0.5), got {self.scale_error!r}")
        _finite("odometry.heading_drift", self.heading_drift)


@dataclass(frozen=True)
class CameraConfig:
    """A camera rendered from the textured map by ``core.camera.CameraRenderer``.

    The defaults are the renderer's (a 60 degree, 320 x 240 pinhole camera);
    the renderer validates its own fields when the simulator builds it.

    Attributes:
        hfov_deg: horizontal field of view [deg].
        width, height: image size [pixels].
        rate_hz: images per second (rendered at the laser step at or after each frame time).
        lighting_variation: 0..1, strength of the random lighting changes between images.
        texture_seed: seed of the wall textures (the same seed gives the same world).
        encoding: ``mono8`` or ``rgb8``.
        extra: other renderer settings as ``(name, value)`` pairs (e.g. ``camera_height``).
    """

    hfov_deg: float = 60.0
    width: int = 320
    height: int = 240
    rate_hz: float = 5.0
    lighting_variation: float = 0.0
    texture_seed: int = 0
    encoding: str = "mono8"
    extra: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        _positive("camera.hfov_deg", self.hfov_deg)
        for name in ("width", "height", "texture_seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ScenarioError(f"camera.{name} must be an integer, got {value!r}")
        if self.width < 8 or self.height < 8:
            raise ScenarioError(f"camera image must be at least 8 x 8 pixels, got {self.width!r} x {self.height!r}")
        _positive("camera.rate_hz", self.rate_hz)
        _non_negative("camera.lighting_variation", self.lighting_variation)
        if self.encoding not in CAMERA_ENCODINGS:
            raise ScenarioError(f"camera.encoding must be one of {CAMERA_ENCODINGS}, got {self.encoding!r}")

    def renderer_arguments(self) -> dict[str, object]:
        """Keyword arguments of ``CameraRenderer(grid_map, **arguments)``."""
        return {
            "hfov_deg": self.hfov_deg,
            "width": self.width,
            "height": self.height,
            "lighting_variation": self.lighting_variation,
            "texture_seed": self.texture_seed,
            "encoding": self.encoding,
            **dict(self.extra),
        }


# -- world events ---------------------------------------------------------------------
@dataclass(frozen=True)
class Kidnapping:
    """At ``time`` [s] the true pose becomes ``pose``; odometry does not see it.

    ``continue_at``: index of the waypoint the robot heads for after the
    teleport (default: the one it was heading for).
    """

    time: float
    pose: tuple[float, float, float]
    continue_at: int | None = None


@dataclass(frozen=True)
class Person:
    """An unmapped moving person: a circle the laser (and camera) sees.

    Attributes:
        radius: [m].
        speed: walking speed [m/s].
        waypoints: ``(N, 2)`` path corners [m]; a single point stands still.
        loop: walk round the closed polygon instead of back and forth.
    """

    radius: float
    speed: float
    waypoints: tuple[tuple[float, float], ...]
    loop: bool = False

    @cached_property
    def _path(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Corner points of one full cycle and their cumulative arc length."""
        points = np.asarray(self.waypoints, dtype=np.float64)
        if len(points) > 1:
            if self.loop:
                points = np.vstack([points, points[:1]])
            else:
                points = np.vstack([points, points[-2::-1]])
        lengths = np.r_[0.0, np.cumsum(np.hypot(*np.diff(points, axis=0).T))] if len(points) > 1 else np.zeros(1)
        return points, lengths

    def position(self, time: float) -> NDArray[np.float64]:
        """Centre ``(2,)`` [m] at ``time`` [s]."""
        points, lengths = self._path
        if len(points) == 1 or lengths[-1] <= 0.0:
            return points[0].copy()
        s = (self.speed * time) % lengths[-1]
        return np.array([np.interp(s, lengths, points[:, 0]), np.interp(s, lengths, points[:, 1])])


# -- motion -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Waypoint:
    """Drive to ``(x, y)``, then turn to ``yaw`` if given; or stand still for ``wait`` seconds."""

    x: float | None = None
    y: float | None = None
    yaw: float | None = None
    wait: float = 0.0

    @property
    def is_wait(self) -> bool:
        return self.x is None


@dataclass(frozen=True)
class VelocitySegment:
    """Constant linear ``v`` [m/s] and angular ``w`` [rad/s] velocity for ``duration`` [s]."""

    v: float
    w: float
    duration: float


@dataclass(frozen=True)
class MotionPlan:
    """Waypoints followed at ``linear_speed`` / ``angular_speed``, or velocity segments."""

    waypoints: tuple[Waypoint, ...] = ()
    segments: tuple[VelocitySegment, ...] = ()
    linear_speed: float = 0.5
    angular_speed: float = 0.8


@dataclass(frozen=True)
class Trajectory:
    """The true motion sampled at every laser step ``k`` (time ``k / rate_hz``).

    Attributes:
        times: ``(N,)`` [s].
        poses: ``(N, 3)`` true base poses after any kidnapping of that step.
        motion_end: ``(N, 3)`` where the motion of the step ended before a kidnapping
            (equal to ``poses`` when there was none); odometry integrates
            ``poses[k-1] -> motion_end[k]``.
        velocities: ``(N, 2)`` mean true ``(v, w)`` over the step [m/s, rad/s].
        kidnapped: ``(N,)`` whether a kidnapping took effect at that step.
    """

    times: NDArray[np.float64]
    poses: NDArray[np.float64]
    motion_end: NDArray[np.float64]
    velocities: NDArray[np.float64]
    kidnapped: NDArray[np.bool_]


def integrate_unicycle(pose: NDArray[np.float64], v: float, w: float, dt: float) -> NDArray[np.float64]:
    """Exact pose ``(3,)`` after driving the arc ``(v, w)`` for ``dt`` seconds."""
    x, y, theta = pose
    if abs(w) < 1e-9:
        return np.array([x + v * dt * math.cos(theta), y + v * dt * math.sin(theta), theta])
    new_theta = theta + w * dt
    radius = v / w
    return np.array(
        [
            x + radius * (math.sin(new_theta) - math.sin(theta)),
            y - radius * (math.cos(new_theta) - math.cos(theta)),
            float(wrap_angle(new_theta)),
        ]
    )


class _WaypointFollower:
    """Rotate-then-drive state machine; ``advance`` spends exactly ``dt`` seconds."""

    def __init__(self, plan: MotionPlan) -> None:
        self.plan = plan
        self.index = 0
        self.phase = "start"
        self.wait_left = 0.0

    @property
    def done(self) -> bool:
        return self.index >= len(self.plan.waypoints)

    def restart_leg(self, continue_at: int | None = None) -> None:
        """After a teleport, approach the current waypoint (or waypoint ``continue_at``) afresh."""
        if continue_at is not None:
            self.index = continue_at
            self.phase = "start"
        elif not self.done and self.phase != "wait":
            self.phase = "start"

    def advance(self, pose: NDArray[np.float64], dt: float) -> tuple[NDArray[np.float64], float]:
        """Move for ``dt`` seconds; returns the new pose and the distance driven [m]."""
        left = dt
        driven = 0.0
        pose = pose.copy()
        while left > 1e-12 and not self.done:
            waypoint = self.plan.waypoints[self.index]
            if self.phase == "start":
                self.phase = "wait" if waypoint.is_wait else "turn_to_goal"
                self.wait_left = waypoint.wait
                continue
            if self.phase == "wait":
                spent = min(left, self.wait_left)
                self.wait_left -= spent
                left -= spent
                if self.wait_left <= 1e-12:
                    self._next()
                continue
            goal = np.array([waypoint.x, waypoint.y])
            if self.phase == "turn_to_goal":
                offset = goal - pose[:2]
                if np.hypot(*offset) < 1e-6:
                    self.phase = "turn_to_yaw"
                    continue
                target = math.atan2(offset[1], offset[0])
                pose, left = self._turn(pose, target, left)
                if abs(angle_difference(target, pose[2])) < 1e-12:
                    pose[2] = target
                    self.phase = "drive"
                continue
            if self.phase == "drive":
                distance = float(np.hypot(*(goal - pose[:2])))
                step = min(distance, self.plan.linear_speed * left)
                left -= step / self.plan.linear_speed
                if step >= distance - 1e-12:
                    pose[:2] = goal
                    self.phase = "turn_to_yaw"
                else:
                    pose[0] += step * math.cos(pose[2])
                    pose[1] += step * math.sin(pose[2])
                driven += step
                continue
            if self.phase == "turn_to_yaw":
                if waypoint.yaw is None:
                    self._next()
                    continue
                pose, left = self._turn(pose, waypoint.yaw, left)
                if abs(angle_difference(waypoint.yaw, pose[2])) < 1e-12:
                    pose[2] = float(wrap_angle(waypoint.yaw))
                    self._next()
        return pose, driven

    def _turn(self, pose: NDArray[np.float64], target: float, left: float) -> tuple[NDArray[np.float64], float]:
        error = float(angle_difference(target, pose[2]))
        turn = math.copysign(min(abs(error), self.plan.angular_speed * left), error)
        pose[2] = float(wrap_angle(pose[2] + turn))
        if abs(turn) >= abs(error) - 1e-12:
            pose[2] = float(wrap_angle(target))
        return pose, left - abs(turn) / self.plan.angular_speed

    def _next(self) -> None:
        self.index += 1
        self.phase = "start"


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
        object.__setattr__(self, "start", _pose("start", list(self.start)))
        _non_negative("robot_radius", self.robot_radius)
        if self.duration is not None:
            duration = float(self.duration)
            if math.isnan(duration) or duration <= 0.0:
                raise ScenarioError(f"duration must be > 0, got {self.duration!r}")
        if self.motion is not None:
            self._check_motion(self.motion)
        self.check_pose(self.start, "start pose")
        for index, kidnap in enumerate(self.kidnappings):
            time = _non_negative(f"kidnappings[{index}].time", kidnap.time)
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
    def clearance(self, xy: Sequence[float]) -> float:
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
            raise ScenarioError(f"{what} {_fmt_pose(pose)} is off the map (x {x0:.2f}..{x1:.2f}, y {y0:.2f}..{y1:.2f})")
        clearance = self.clearance(pose)
        if clearance < 0.0:
            raise ScenarioError(f"{what} {_fmt_pose(pose)} lies in an obstacle or unknown cell of the map")
        if clearance < self.robot_radius:
            raise ScenarioError(
                f"{what} {_fmt_pose(pose)} is {clearance:.3f} m from an obstacle, "
                f"closer than robot_radius {self.robot_radius!r} m"
            )

    def _check_motion(self, motion: MotionPlan) -> None:
        if bool(motion.waypoints) == bool(motion.segments):
            raise ScenarioError("motion needs either waypoints or segments (exactly one of them)")
        _positive("motion.linear_speed", motion.linear_speed)
        _positive("motion.angular_speed", motion.angular_speed)
        x0, x1, y0, y1 = self.grid_map.extent
        for index, waypoint in enumerate(motion.waypoints):
            if waypoint.is_wait:
                _non_negative(f"motion.waypoints[{index}].wait", waypoint.wait)
                continue
            if not (x0 <= waypoint.x < x1 and y0 <= waypoint.y < y1):
                raise ScenarioError(
                    f"motion.waypoints[{index}] [{waypoint.x}, {waypoint.y}] is off the map "
                    f"(x {x0:.2f}..{x1:.2f}, y {y0:.2f}..{y1:.2f})"
                )
        for index, segment in enumerate(motion.segments):
            _finite(f"motion.segments[{index}].v", segment.v)
            _finite(f"motion.segments[{index}].w", segment.w)
            _positive(f"motion.segments[{index}].duration", segment.duration)

    def _check_person(self, index: int, person: Person) -> None:
        _positive(f"people[{index}].radius", person.radius)
        _positive(f"people[{index}].speed", person.speed)
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
                f"the robot path reaches {_fmt_pose(poses[k])} at t = {times[k]:.2f} s, "
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
    def _integrate(self) -> tuple[NDArray[np.float64], ...]:
        """Integrate the motion at sub-steps until it ends (or the duration passes).

        Returns ``(dense_times, dense_poses, step_poses, step_motion_end, step_velocity, step_kidnapped)``.
        """
        cache_key = "_integrated"
        cached = self.__dict__.get(cache_key)
        if cached is not None:
            return cached
        assert self.motion is not None
        dt = self.period
        substeps = max(1, math.ceil(dt / _MAX_SUBSTEP - 1e-9))
        h = dt / substeps
        limit = float(self.duration) if self.duration is not None else math.inf
        kidnaps = sorted(self.kidnappings, key=lambda k: k.time)
        follower = _WaypointFollower(self.motion) if self.motion.waypoints else None
        segment_ends = np.cumsum([s.duration for s in self.motion.segments])
        pose = np.array(self.start, dtype=np.float64)
        dense_times, dense_poses = [0.0], [pose.copy()]
        step_poses, step_end, step_vel, step_kidnapped = [pose.copy()], [pose.copy()], [np.zeros(2)], [False]
        next_kidnap = 0
        k = 0
        while True:
            t0 = k * dt
            motion_over = follower.done if follower is not None else t0 >= segment_ends[-1] - 1e-9
            pending_kidnap = next_kidnap < len(kidnaps)
            if t0 >= limit - 1e-9 or (math.isinf(limit) and motion_over and not pending_kidnap):
                break
            driven, turned = 0.0, 0.0
            for j in range(substeps):
                before = pose.copy()
                if follower is not None:
                    pose, step = follower.advance(pose, h)
                    driven += step
                else:
                    t_mid = t0 + (j + 0.5) * h
                    index = int(np.searchsorted(segment_ends, t_mid))
                    if index < len(self.motion.segments):
                        segment = self.motion.segments[index]
                        pose = integrate_unicycle(pose, segment.v, segment.w, h)
                        driven += segment.v * h
                turned += float(angle_difference(pose[2], before[2]))
                dense_times.append(t0 + (j + 1) * h)
                dense_poses.append(pose.copy())
            k += 1
            motion_end = pose.copy()
            kidnapped = False
            while next_kidnap < len(kidnaps) and kidnaps[next_kidnap].time <= k * dt + 1e-9:
                pose = np.array(kidnaps[next_kidnap].pose, dtype=np.float64)
                if follower is not None:
                    follower.restart_leg(kidnaps[next_kidnap].continue_at)
                next_kidnap += 1
                kidnapped = True
            if kidnapped:
                dense_times.append(k * dt)
                dense_poses.append(pose.copy())
            step_poses.append(pose.copy())
            step_end.append(motion_end)
            step_vel.append(np.array([driven / dt, turned / dt]))
            step_kidnapped.append(kidnapped)
        result = (
            np.asarray(dense_times),
            np.asarray(dense_poses),
            np.asarray(step_poses),
            np.asarray(step_end),
            np.asarray(step_vel),
            np.asarray(step_kidnapped, dtype=bool),
        )
        self.__dict__[cache_key] = result
        return result

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


# -- YAML loading -------------------------------------------------------------------------
_TOP_KEYS = {
    "name",
    "map",
    "seed",
    "duration",
    "robot_radius",
    "start",
    "motion",
    "kidnappings",
    "people",
    "laser",
    "odometry",
    "camera",
    "description",
}


def _mapping(name: str, value: Any, allowed: set[str]) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ScenarioError(f"{name} must be a mapping, got {value!r}")
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise ScenarioError(f"{name} has unknown key(s) {unknown} (allowed: {sorted(allowed)})")
    return dict(value)


def _list(name: str, value: Any) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, list):
        raise ScenarioError(f"{name} must be a list, got {value!r}")
    return value


def _integer(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ScenarioError(f"{name} must be an integer, got {value!r}")
    return value


def _dataclass_fields(cls: type, name: str, raw: dict[str, Any], integers: Sequence[str] = ()) -> dict[str, Any]:
    """Fields of a config dataclass from YAML, numbers as float (``integers`` as int)."""
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key in integers:
            out[key] = _integer(f"{name}.{key}", value)
        elif isinstance(value, str):
            out[key] = value
        elif key == "mount":
            out[key] = _pose(f"{name}.mount", value)
        else:
            out[key] = _finite(f"{name}.{key}", value)
    return out


def _parse_waypoint(index: int, raw: Any) -> Waypoint:
    name = f"motion.waypoints[{index}]"
    if isinstance(raw, Mapping):
        data = _mapping(name, raw, {"wait"})
        if "wait" not in data:
            raise ScenarioError(f"{name} must be [x, y], [x, y, yaw] or {{wait: seconds}}, got {raw!r}")
        return Waypoint(wait=_non_negative(f"{name}.wait", data["wait"]))
    if not isinstance(raw, (list, tuple)) or len(raw) not in (2, 3):
        raise ScenarioError(f"{name} must be [x, y], [x, y, yaw] or {{wait: seconds}}, got {raw!r}")
    values = [_finite(name, v) for v in raw]
    return Waypoint(values[0], values[1], values[2] if len(values) == 3 else None)


def scenario_from_dict(data: Mapping[str, Any], base_dir: str | os.PathLike[str] = ".") -> Scenario:
    """Build a :class:`Scenario` from parsed YAML; the map path is relative to ``base_dir``."""
    data = _mapping("scenario", data, _TOP_KEYS)
    if "map" not in data:
        raise ScenarioError("scenario has no 'map' (path of a nav2 map_server YAML)")
    if "start" not in data:
        raise ScenarioError("scenario has no 'start' pose [x, y, yaw]")
    map_path = (Path(base_dir) / str(data["map"])).resolve()
    try:
        grid_map = load_map_yaml(map_path)
    except MapError as exc:
        raise ScenarioError(f"scenario map {str(data['map'])!r}: {exc}") from exc

    motion = None
    if data.get("motion") is not None:
        raw = _mapping("motion", data["motion"], {"linear_speed", "angular_speed", "waypoints", "segments"})
        waypoints = tuple(_parse_waypoint(i, w) for i, w in enumerate(_list("motion.waypoints", raw.get("waypoints"))))
        segments = []
        for index, item in enumerate(_list("motion.segments", raw.get("segments"))):
            seg = _mapping(f"motion.segments[{index}]", item, {"v", "w", "duration"})
            for key in ("v", "w", "duration"):
                if key not in seg:
                    raise ScenarioError(f"motion.segments[{index}] has no {key!r}")
            segments.append(
                VelocitySegment(
                    _finite(f"motion.segments[{index}].v", seg["v"]),
                    _finite(f"motion.segments[{index}].w", seg["w"]),
                    _positive(f"motion.segments[{index}].duration", seg["duration"]),
                )
            )
        motion = MotionPlan(
            waypoints=waypoints,
            segments=tuple(segments),
            linear_speed=_finite("motion.linear_speed", raw.get("linear_speed", 0.5)),
            angular_speed=_finite("motion.angular_speed", raw.get("angular_speed", 0.8)),
        )

    kidnappings = []
    for index, item in enumerate(_list("kidnappings", data.get("kidnappings"))):
        raw = _mapping(f"kidnappings[{index}]", item, {"time", "pose", "continue_at"})
        if "time" not in raw or "pose" not in raw:
            raise ScenarioError(f"kidnappings[{index}] needs 'time' and 'pose', got {item!r}")
        continue_at = raw.get("continue_at")
        kidnappings.append(
            Kidnapping(
                _non_negative(f"kidnappings[{index}].time", raw["time"]),
                _pose(f"kidnappings[{index}].pose", raw["pose"]),
                None if continue_at is None else _integer(f"kidnappings[{index}].continue_at", continue_at),
            )
        )

    people = []
    for index, item in enumerate(_list("people", data.get("people"))):
        raw = _mapping(f"people[{index}]", item, {"radius", "speed", "waypoints", "loop"})
        points = tuple(
            _point(f"people[{index}].waypoints", p) for p in _list(f"people[{index}].waypoints", raw.get("waypoints"))
        )
        people.append(
            Person(
                radius=_finite(f"people[{index}].radius", raw.get("radius", 0.25)),
                speed=_finite(f"people[{index}].speed", raw.get("speed", 0.8)),
                waypoints=points,
                loop=bool(raw.get("loop", False)),
            )
        )

    laser_raw = _mapping("laser", data.get("laser"), set(LaserConfig.__dataclass_fields__))
    odom_raw = _mapping("odometry", data.get("odometry"), set(OdometryConfig.__dataclass_fields__))
    laser = LaserConfig(**_dataclass_fields(LaserConfig, "laser", laser_raw, integers=("beams",)))
    odometry = OdometryConfig(**_dataclass_fields(OdometryConfig, "odometry", odom_raw))
    camera = None
    if data.get("camera") is not None:
        if not isinstance(data["camera"], Mapping):
            raise ScenarioError(f"camera must be a mapping, got {data['camera']!r}")
        known = set(CameraConfig.__dataclass_fields__) - {"extra"}
        camera_raw = {k: v for k, v in data["camera"].items() if k in known}
        extra = tuple((str(k), _finite(f"camera.{k}", v)) for k, v in sorted(data["camera"].items()) if k not in known)
        camera = CameraConfig(
            **_dataclass_fields(CameraConfig, "camera", camera_raw, integers=("width", "height", "texture_seed")),
            extra=extra,
        )
    duration = data.get("duration")
    return Scenario(
        grid_map=grid_map,
        start=_pose("start", data["start"]),
        motion=motion,
        kidnappings=tuple(kidnappings),
        people=tuple(people),
        laser=laser,
        odometry=odometry,
        camera=camera,
        duration=None if duration is None else _positive("duration", duration),
        robot_radius=_non_negative("robot_radius", data.get("robot_radius", 0.2)),
        seed=_integer("seed", data.get("seed", 0)),
        name=str(data.get("name", "scenario")),
        map_path=map_path,
    )


def load_scenario(path: str | os.PathLike[str]) -> Scenario:
    """Load and validate a scenario YAML file.

    Raises:
        ScenarioError: naming the file, the field and the bad value.
    """
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"scenario file {str(path)!r} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"scenario file {str(path)!r} is not valid YAML: {exc}") from exc
    if not isinstance(data, Mapping):
        raise ScenarioError(f"scenario file {str(path)!r} must hold a mapping, got {type(data).__name__}")
    data = dict(data)
    data.setdefault("name", path.stem)
    try:
        return scenario_from_dict(data, path.parent)
    except ScenarioError as exc:
        raise ScenarioError(f"scenario {str(path)!r}: {exc}") from exc
