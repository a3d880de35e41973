"""The simulated robot: true motion, noisy odometry, laser scans and camera images.

:class:`Simulator` steps a :class:`~robot_localization_suite.core.sim.scenario.Scenario`
at the laser rate. Step ``k`` is at time ``k / rate_hz`` (step 0 is the start
pose, before any motion) and returns the true pose, the odometry pose, a
laser scan (the shared ray caster plus analytic ray-circle hits on people,
then range noise, outliers, dropouts and REP 117 limits), the people, and a
camera image from :mod:`.camera` when one is due. Odometry integrates the true
motion (a kidnapping's jump is not seen) perturbed by the scenario's
:class:`~robot_localization_suite.core.sim.config.OdometryConfig`, from
``(0, 0, 0)`` in ``odom``. One seed is split into independent streams for the
laser, the odometry and the camera; the same seed gives bit-identical output.
Without a motion plan, velocity commands drive the robot, which stops at walls.

Notes (the noise order, people, randomness, commands): docs/simulator.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ScenarioError
from ..grid_map import GridMap
from ..motion import OdometryMotionModel, apply_delta, odometry_delta
from ..raycast import RayCaster
from ..scan import Scan
from ..se2 import angle_difference, compose, wrap_angle
from .config import OdometryConfig
from .scenario import Scenario
from .trajectory import integrate_unicycle

__all__ = ["Simulator", "SimulationStep", "ray_circle_ranges", "apply_range_noise", "OdometrySimulator"]


@dataclass(frozen=True, eq=False)
class SimulationStep:
    """Everything the simulated robot and world give at one laser step.

    Attributes:
        index: step number (0 at the start).
        time: scenario time [s].
        true_pose: ``(3,)`` true base pose in ``map`` [m, m, rad].
        odom_pose: ``(3,)`` base pose in ``odom`` as the wheel odometry reports it.
        laser_pose: ``(3,)`` true laser pose in ``map``.
        ranges: ``(beams,)`` float32 readings [m]: ``+inf`` no return, ``-inf`` too close.
        true_velocity: ``(v, w)`` mean true velocity over the step [m/s, rad/s].
        odom_velocity: ``(v, w)`` as odometry reports it.
        people: ``(K, 3)`` people ``x, y, radius`` [m].
        kidnapped: a kidnapping took effect at this step.
        blocked: a velocity command was cut short by an obstacle.
        image: camera image (``(H, W)`` mono8 or ``(H, W, 3)`` rgb8) when one is due, else ``None``.
        new_map: the map the world changed to at this step (sensed from this step on), else ``None``.
        reinitialize: the simulated operator asks for global localization at this step.
    """

    index: int
    time: float
    true_pose: NDArray[np.float64]
    odom_pose: NDArray[np.float64]
    laser_pose: NDArray[np.float64]
    ranges: NDArray[np.float32]
    true_velocity: tuple[float, float]
    odom_velocity: tuple[float, float]
    people: NDArray[np.float64]
    kidnapped: bool = False
    blocked: bool = False
    image: NDArray[np.uint8] | None = None
    new_map: GridMap | None = None
    reinitialize: bool = False


def ray_circle_ranges(origin: ArrayLike, directions: ArrayLike, circles: ArrayLike) -> NDArray[np.float64]:
    """Distance along each ray to the nearest circle, ``inf`` where none is hit.

    Args:
        origin: ``(2,)`` ray origin [m].
        directions: ``(B,)`` ray angles in the world [rad].
        circles: ``(K, 3)`` circles ``x, y, radius`` [m]. Circles that contain the
            origin are ignored.

    Returns:
        ``(B,)`` ranges [m].
    """
    origin = np.asarray(origin, dtype=np.float64)
    angles = np.asarray(directions, dtype=np.float64)
    circles = np.asarray(circles, dtype=np.float64).reshape(-1, 3)
    out = np.full(angles.shape, np.inf)
    if circles.shape[0] == 0:
        return out
    offset = circles[:, :2] - origin  # (K, 2)
    radius_sq = circles[:, 2] ** 2
    outside = np.einsum("kd,kd->k", offset, offset) > radius_sq
    if not outside.any():
        return out
    offset, radius_sq = offset[outside], radius_sq[outside]
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # (B, 2)
    along = unit @ offset.T  # (B, K): distance to the closest approach
    miss_sq = np.einsum("kd,kd->k", offset, offset)[None, :] - along**2
    half_chord_sq = radius_sq[None, :] - miss_sq
    hit = (half_chord_sq >= 0.0) & (along > 0.0)
    entry = np.where(hit, along - np.sqrt(np.maximum(half_chord_sq, 0.0)), np.inf)
    return entry.min(axis=1)


def apply_range_noise(
    ranges: ArrayLike,
    *,
    range_min: float,
    range_max: float,
    noise_model: str,
    noise_std: float,
    noise_bound: float,
    outlier_prob: float,
    dropout_prob: float,
    rng: np.random.Generator,
) -> NDArray[np.float32]:
    """Turn exact ranges (``inf`` = nothing within ``range_max``) into sensor readings (REP 117).

    The random draws are made for every beam whatever its value, so that the
    stream of random numbers, and hence the noise, does not depend on the scene.
    """
    exact = np.asarray(ranges, dtype=np.float64)
    count = exact.shape[0]
    if noise_model == "gaussian":
        noise = rng.normal(0.0, 1.0, count) * noise_std
    elif noise_model == "uniform":
        noise = rng.uniform(-noise_bound, noise_bound, count)
    else:
        raise ScenarioError(f"range noise model must be 'gaussian' or 'uniform', got {noise_model!r}")
    outlier_draw = rng.random(count)
    outlier_value = rng.uniform(range_min, range_max, count)
    dropout_draw = rng.random(count)
    measured = exact + noise  # inf stays inf
    measured = np.where(outlier_draw < outlier_prob, outlier_value, measured)
    measured = np.where(dropout_draw < dropout_prob, np.inf, measured)
    measured = np.where(measured >= range_max, np.inf, measured)
    measured = np.where(measured < range_min, -np.inf, measured)
    return measured.astype(np.float32)


class OdometrySimulator:
    """Noisy wheel odometry: integrates true steps with random error and drift.

    Args:
        config: the scenario's odometry model.
        rng: random stream of the odometry.
    """

    def __init__(self, config: OdometryConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self.pose: NDArray[np.float64] = np.zeros(3)  # [m, m, rad]
        self._model = OdometryMotionModel(config.alpha1, config.alpha2, config.alpha3, config.alpha4)

    def step(self, true_previous: NDArray[np.float64], true_current: NDArray[np.float64]) -> NDArray[np.float64]:
        """Advance by the true motion ``true_previous -> true_current`` and return the new odometry pose."""
        delta = odometry_delta(true_previous, true_current)
        config = self.config
        if delta.trans == 0.0 and delta.rot1 == 0.0 and delta.rot2 == 0.0:
            return self.pose.copy()  # wheels that do not turn report nothing
        # Systematic drift: wrong wheel diameter (scale) and wheel base (heading per metre).
        trans = delta.trans * (1.0 + config.scale_error)
        rot2 = delta.rot2 + config.heading_drift * delta.trans
        rel: NDArray[np.float64]
        if config.model == "alphas":
            origin = np.zeros(3)
            drifted = apply_delta(origin, delta.rot1, trans, rot2)
            # Noise scaled by the (drifted) step, exactly as OdometryMotionModel.sample does for a filter.
            rel = self._model.sample(origin[None, :], origin, drifted, self.rng)[0]
        else:
            bounds = OdometryMotionModel.bounds(
                true_previous,
                true_current,
                relative_translation=config.relative_translation,
                absolute_translation=config.absolute_translation,
                relative_rotation=config.relative_rotation,
                absolute_rotation=config.absolute_rotation,
            )
            values = []
            for (low, high), biased in ((bounds.rot1, delta.rot1), (bounds.trans, trans), (bounds.rot2, rot2)):
                half = 0.5 * (high - low)
                drawn = biased + self.rng.uniform(-half, half)
                values.append(float(np.clip(drawn, low, high)))
            rel = apply_delta(np.zeros(3), values[0], max(values[1], 0.0), values[2])
        self.pose = compose(self.pose, rel)
        return self.pose.copy()


class Simulator:
    """Step a scenario at the laser rate.

    Args:
        scenario: the validated scenario.
        seed: noise seed; default: the scenario's ``seed``.

    Iterate with :meth:`run` (the scenario's steps, then stop) or call
    :meth:`step` (past the end the robot stands still; without a motion plan
    ``command=(v, w)`` drives it).
    """

    def __init__(self, scenario: Scenario, *, seed: int | None = None) -> None:
        self.scenario = scenario
        self.seed = int(scenario.seed if seed is None else seed)
        laser = scenario.laser
        self.angles = laser.angles
        # the beams' directions from a level laser at the mount's pose (an upside-down one turns the other way)
        self._directions = -self.angles if laser.upside_down else self.angles
        self._grid_map = scenario.grid_map
        self._raycaster = RayCaster(scenario.grid_map, max_range=laser.range_max)
        self._map_changes_done = 0
        self._reinitializations_done = 0
        streams = np.random.SeedSequence(self.seed).spawn(3)
        self._laser_rng = np.random.default_rng(streams[0])
        self._odometry = OdometrySimulator(scenario.odometry, np.random.default_rng(streams[1]))
        self._camera_rng = np.random.default_rng(streams[2])
        self._camera = self._make_camera()
        self._next_image_index = 0
        self._trajectory = scenario.trajectory if scenario.motion is not None else None
        self.index = -1
        self.true_pose: NDArray[np.float64] = np.array(scenario.start, dtype=np.float64)
        self._last_odom = self._odometry.pose.copy()

    # -- properties ---------------------------------------------------------------------------
    @property
    def period(self) -> float:
        """Time between steps [s]."""
        return self.scenario.period

    @property
    def time(self) -> float:
        """Time of the last step [s] (``-period`` before the first)."""
        return self.index * self.period

    @property
    def step_count(self) -> int:
        """Steps of the scenario, including step 0."""
        return self.scenario.step_count

    @property
    def finished(self) -> bool:
        """Whether the last step of the scenario has been returned (never, for an endless one)."""
        end = self.scenario.end_time
        return math.isfinite(end) and self.index >= int(round(end / self.period))

    @property
    def grid_map(self) -> GridMap:
        """The map the robot senses now (the scenario's, or the last map change's)."""
        return self._grid_map

    def _make_camera(self):
        config = self.scenario.camera
        if config is None:
            return None
        try:
            from .camera import CameraRenderer  # imported only when a camera exists
        except ImportError as exc:
            raise ScenarioError(f"the scenario has a camera but the camera renderer cannot be loaded: {exc}") from exc
        try:
            return CameraRenderer(self._grid_map, **config.renderer_arguments(), **dict(config.extra))
        except (TypeError, ValueError) as exc:
            raise ScenarioError(f"camera: {exc}") from exc

    # -- stepping ------------------------------------------------------------------------------
    def run(self) -> Iterator[SimulationStep]:
        """Yield every step of the scenario, from step 0 to its end."""
        while not self.finished:
            yield self.step()

    def step(self, command: tuple[float, float] | None = None) -> SimulationStep:
        """Advance one laser period and sense.

        Args:
            command: ``(v, w)`` [m/s, rad/s] for a scenario without motion plan; ignored otherwise.
        """
        self.index += 1
        new_map, reinitialize = self._world_events()
        previous = self.true_pose
        kidnapped = blocked = False
        if self.index == 0:
            motion_end = previous
            velocity = (0.0, 0.0)
        elif self._trajectory is not None:
            k = min(self.index, len(self._trajectory.times) - 1)
            if self.index < len(self._trajectory.times):
                motion_end = self._trajectory.motion_end[k]
                self.true_pose = self._trajectory.poses[k].copy()
                kidnapped = bool(self._trajectory.kidnapped[k])
                row = self._trajectory.velocities[k]
                velocity = (float(row[0]), float(row[1]))
            else:  # past the end: stand still
                motion_end = previous
                velocity = (0.0, 0.0)
        else:
            v, w = (0.0, 0.0) if command is None else (float(command[0]), float(command[1]))
            motion_end, velocity, blocked = self._drive(previous, v, w)
            self.true_pose = motion_end.copy()
        odom_pose = self._odometry.step(previous, motion_end) if self.index > 0 else self._odometry.pose.copy()
        odom_velocity = self._odom_velocity(self._last_odom, odom_pose)
        self._last_odom = odom_pose
        time = self.time
        people = self.scenario.people_at(time)
        laser_pose = compose(self.true_pose, np.asarray(self.scenario.laser.mount))
        ranges = self.sense(laser_pose, people)
        image = self._render(time, people)
        return SimulationStep(
            index=self.index,
            time=time,
            true_pose=self.true_pose.copy(),
            odom_pose=odom_pose,
            laser_pose=laser_pose,
            ranges=ranges,
            true_velocity=velocity,
            odom_velocity=odom_velocity,
            people=people,
            kidnapped=kidnapped,
            blocked=blocked,
            image=image,
            new_map=new_map,
            reinitialize=reinitialize,
        )

    def _world_events(self) -> tuple[GridMap | None, bool]:
        """Apply the map changes due at this step (the newest wins); whether a reinitialization is due."""
        scenario = self.scenario
        new_map = None
        changes = scenario.map_changes
        while (self._map_changes_done < len(changes)
               and scenario.event_step(changes[self._map_changes_done].time) <= self.index):
            new_map = changes[self._map_changes_done].grid_map
            self._map_changes_done += 1
        if new_map is not None:
            self._grid_map = new_map
            self._raycaster = RayCaster(new_map, max_range=scenario.laser.range_max)
            if self._camera is not None:
                self._camera = self._make_camera()
        requests = scenario.reinitializations
        reinitialize = False
        while (self._reinitializations_done < len(requests)
               and scenario.event_step(requests[self._reinitializations_done].time) <= self.index):
            self._reinitializations_done += 1
            reinitialize = True
        return new_map, reinitialize

    def _odom_velocity(self, previous: NDArray[np.float64], current: NDArray[np.float64]) -> tuple[float, float]:
        if self.index == 0:
            return (0.0, 0.0)
        delta = odometry_delta(previous, current)
        forward = math.cos(delta.rot1) * delta.trans
        return (forward / self.period, float(angle_difference(current[2], previous[2])) / self.period)

    def _drive(
        self, pose: NDArray[np.float64], v: float, w: float
    ) -> tuple[NDArray[np.float64], tuple[float, float], bool]:
        """Integrate a velocity command for one period; stop translating at obstacles."""
        if not (math.isfinite(v) and math.isfinite(w)):
            raise ScenarioError(f"velocity command must be finite, got v={v!r}, w={w!r}")
        moved = integrate_unicycle(pose, v, w, self.period)
        if v != 0.0 and self.scenario.clearance(moved, self._grid_map) < self.scenario.robot_radius:
            turned = pose.copy()
            turned[2] = float(wrap_angle(pose[2] + w * self.period))
            return turned, (0.0, w), True
        return moved, (v, w), False

    def sense(self, laser_pose: ArrayLike, people: ArrayLike) -> NDArray[np.float32]:
        """One noisy scan ``(beams,)`` from ``laser_pose`` with ``people`` ``(K, 3)`` in the world."""
        laser = self.scenario.laser
        pose = np.asarray(laser_pose, dtype=np.float64)
        circles = np.asarray(people, dtype=np.float64)  # no copy for the (K, 3) float64 of people_at
        exact = self._raycaster.cast(pose, self._directions).astype(np.float64)
        if len(circles):
            exact = np.minimum(exact, ray_circle_ranges(pose[:2], pose[2] + self._directions, circles))
        return apply_range_noise(
            exact,
            range_min=laser.range_min,
            range_max=laser.range_max,
            noise_model=laser.range_noise_model,
            noise_std=laser.range_noise_std,
            noise_bound=laser.range_noise_bound,
            outlier_prob=laser.outlier_prob,
            dropout_prob=laser.dropout_prob,
            rng=self._laser_rng,
        )

    def _render(self, time: float, people: NDArray[np.float64]) -> NDArray[np.uint8] | None:
        config = self.scenario.camera
        if self._camera is None or config is None:
            return None
        if time + 1e-9 < self._next_image_index / config.rate_hz:
            return None
        self._next_image_index = int(math.floor(time * config.rate_hz + 1e-9)) + 1
        image = np.asarray(self._camera.render(self.true_pose, people, self._camera_rng), dtype=np.uint8)
        if config.encoding == "mono8" and image.ndim == 3:
            image = np.asarray(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), dtype=np.uint8)  # uint8 stays uint8: no copy
        elif config.encoding == "rgb8" and image.ndim == 2:
            image = np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2RGB), dtype=np.uint8)
        return image

    # -- conversions ------------------------------------------------------------------------------
    def to_scan(self, step: SimulationStep) -> Scan:
        """The step's readings as a core :class:`Scan` (laser frame)."""
        laser = self.scenario.laser
        return Scan(step.time, self.angles.copy(), step.ranges.astype(np.float64), laser.range_min, laser.range_max)
