"""What a scenario is made of: laser, odometry and camera models, people, kidnappings and the motion plan.

Each is a frozen dataclass validated on construction; a :class:`~..errors.ScenarioError` names the
field and the bad value. Units: metres, radians, seconds. YAML layout: docs/simulator.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, TypedDict

import numpy as np
from numpy.typing import NDArray

from ..errors import ScenarioError
from ..grid_map import GridMap
from ..se2 import wrap_angle

__all__ = [
    "LaserConfig",
    "OdometryConfig",
    "CameraConfig",
    "RendererArguments",
    "Person",
    "Kidnapping",
    "MapChange",
    "Reinitialization",
    "Waypoint",
    "VelocitySegment",
    "MotionPlan",
    "RANGE_NOISE_MODELS",
    "ODOMETRY_MODELS",
    "CAMERA_ENCODINGS",
    "REINITIALIZE_TOPIC",
    "MAX_BEAMS",
    "MAX_RATE_HZ",
    "finite_value",
    "non_negative_value",
    "positive_value",
    "probability_value",
    "pose_value",
    "point_value",
    "format_pose",
]

RANGE_NOISE_MODELS = ("gaussian", "uniform")
ODOMETRY_MODELS = ("alphas", "bounded")
CAMERA_ENCODINGS = ("mono8", "rgb8")
# Where scan_sim publishes (live) and records (bag) a Reinitialization: std_msgs/Header stamped at the request.
REINITIALIZE_TOPIC = "operator/reinitialize_global_localization"
# Most beams a scan and most scans a second: beyond them a scan or the trajectory does not fit in memory.
MAX_BEAMS = 100_000
MAX_RATE_HZ = 1000.0



def finite_value(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise ScenarioError(f"{name} must be a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ScenarioError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ScenarioError(f"{name} must be finite, got {value!r}")
    return number


def non_negative_value(name: str, value: Any) -> float:
    number = finite_value(name, value)
    if number < 0.0:
        raise ScenarioError(f"{name} must be >= 0, got {value!r}")
    return number


def positive_value(name: str, value: Any) -> float:
    number = finite_value(name, value)
    if number <= 0.0:
        raise ScenarioError(f"{name} must be > 0, got {value!r}")
    return number


def probability_value(name: str, value: Any) -> float:
    number = finite_value(name, value)
    if not 0.0 <= number <= 1.0:
        raise ScenarioError(f"{name} must be within [0, 1], got {value!r}")
    return number


def pose_value(name: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ScenarioError(f"{name} must be [x, y, yaw], got {value!r}")
    x, y, yaw = (finite_value(name, v) for v in value)
    return (x, y, float(wrap_angle(yaw)))


def point_value(name: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ScenarioError(f"{name} must be [x, y], got {value!r}")
    return (finite_value(name, value[0]), finite_value(name, value[1]))


def format_pose(pose: Sequence[float]) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in pose) + "]"


# -- sensor and odometry models -------------------------------------------------------
@dataclass(frozen=True)
class LaserConfig:
    """The simulated 2-D laser scanner.

    Defaults describe a 360 degree indoor scanner (e.g. a SICK/Hokuyo pair or an
    RPLIDAR class sensor): 1 degree beams, 12 m range, 10 Hz, 1.5 cm range noise
    (manufacturers quote 1-3 cm), 1.5 % outliers, 0.5 % dropouts.

    Attributes:
        beams: number of beams, 2..``MAX_BEAMS``.
        fov_deg: field of view [deg], 90..360. At 360 the beams are ``2 pi / beams``
            apart starting at ``-pi`` (no duplicate beam); below 360 they span
            ``[-fov/2, +fov/2]`` end to end.
        range_min, range_max: valid interval [m]; readings at or beyond ``range_max``
            are published as ``+inf``, hits closer than ``range_min`` as ``-inf`` (REP 117).
        rate_hz: scans per second, up to ``MAX_RATE_HZ``; the simulator steps at this rate.
        range_noise_std: standard deviation of Gaussian range noise [m].
        range_noise_model: ``gaussian`` or ``uniform`` (bounded: ``+-range_noise_bound``,
            what interval methods assume).
        range_noise_bound: half-width of the uniform noise [m].
        outlier_prob: probability that a beam reads a random range uniform in
            ``[range_min, range_max)`` (Probabilistic Robotics' ``p_rand``).
        dropout_prob: probability that a beam returns nothing (``+inf``).
        mount: laser pose in the robot base frame [m, m, rad].
        upside_down: the laser is mounted upside down (rolled by pi): its beam angle ``a``
            looks along ``mount yaw - a`` in the base frame, and ``/tf_static`` says so.
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
    upside_down: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.upside_down, bool):
            raise ScenarioError(f"laser.upside_down must be true or false, got {self.upside_down!r}")
        if isinstance(self.beams, bool) or not isinstance(self.beams, (int, np.integer)) or not 2 <= self.beams <= MAX_BEAMS:
            raise ScenarioError(f"laser.beams must be an integer within [2, {MAX_BEAMS}], got {self.beams!r}")
        fov = finite_value("laser.fov_deg", self.fov_deg)
        if not 90.0 <= fov <= 360.0:
            raise ScenarioError(f"laser.fov_deg must be within [90, 360], got {self.fov_deg!r}")
        range_min = non_negative_value("laser.range_min", self.range_min)
        range_max = positive_value("laser.range_max", self.range_max)
        if range_min >= range_max:
            raise ScenarioError(f"laser.range_min {self.range_min!r} must be below laser.range_max {self.range_max!r}")
        if positive_value("laser.rate_hz", self.rate_hz) > MAX_RATE_HZ:
            raise ScenarioError(f"laser.rate_hz must be within (0, {MAX_RATE_HZ:g}] Hz, got {self.rate_hz!r}")
        non_negative_value("laser.range_noise_std", self.range_noise_std)
        non_negative_value("laser.range_noise_bound", self.range_noise_bound)
        if self.range_noise_model not in RANGE_NOISE_MODELS:
            raise ScenarioError(
                f"laser.range_noise_model must be one of {RANGE_NOISE_MODELS}, got {self.range_noise_model!r}"
            )
        probability_value("laser.outlier_prob", self.outlier_prob)
        probability_value("laser.dropout_prob", self.dropout_prob)
        object.__setattr__(self, "mount", pose_value("laser.mount", list(self.mount)))

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
            non_negative_value(f"odometry.{name}", getattr(self, name))
        scale = finite_value("odometry.scale_error", self.scale_error)
        if abs(scale) >= 0.5:
            raise ScenarioError(f"odometry.scale_error must be within (-0.5, 0.5), got {self.scale_error!r}")
        finite_value("odometry.heading_drift", self.heading_drift)


class RendererArguments(TypedDict):
    """The named keyword arguments of ``CameraRenderer``; the others come from ``CameraConfig.extra``."""

    hfov_deg: float
    width: int
    height: int
    lighting_variation: float
    texture_seed: int
    encoding: str


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
        positive_value("camera.hfov_deg", self.hfov_deg)
        for name in ("width", "height", "texture_seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ScenarioError(f"camera.{name} must be an integer, got {value!r}")
        if self.width < 8 or self.height < 8:
            raise ScenarioError(f"camera image must be at least 8 x 8 pixels, got {self.width!r} x {self.height!r}")
        positive_value("camera.rate_hz", self.rate_hz)
        non_negative_value("camera.lighting_variation", self.lighting_variation)
        if self.encoding not in CAMERA_ENCODINGS:
            raise ScenarioError(f"camera.encoding must be one of {CAMERA_ENCODINGS}, got {self.encoding!r}")

    def renderer_arguments(self) -> RendererArguments:
        """Named keyword arguments of ``CameraRenderer(grid_map, **arguments, **dict(config.extra))``."""
        return {
            "hfov_deg": self.hfov_deg,
            "width": self.width,
            "height": self.height,
            "lighting_variation": self.lighting_variation,
            "texture_seed": self.texture_seed,
            "encoding": self.encoding,
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


@dataclass(frozen=True, eq=False)
class MapChange:
    """At ``time`` [s] the world becomes ``grid_map`` (doors closed, furniture moved): the laser and
    camera sense it from then on and ``scan_sim`` publishes it on ``map`` (docs/simulator.md).

    ``path``: the map_server YAML it was loaded from, for messages.
    """

    time: float
    grid_map: GridMap
    path: str = ""


@dataclass(frozen=True)
class Reinitialization:
    """At ``time`` [s] the simulated operator asks every localizer to localize globally again
    (``~/reinitialize_global_localization``; docs/simulator.md)."""

    time: float


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
