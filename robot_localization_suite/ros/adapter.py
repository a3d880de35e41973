"""Messages in, core localizer, messages out: what a localizer node and the replay share.

The adapter owns everything between a ROS message and a core call:
conversion, the laser mounting offset, rejection of bad or out-of-order input
with throttled log messages, update timing, and building the output messages.
A node wires it to subscriptions and publishers; ``rls_bench`` calls it
directly with the messages of a bag, so both exercise the same code.

Mounting offset: core localizers estimate the pose of the *laser*. The adapter
gives them laser odometry (``odom (+) mount``) and laser initial poses, and
turns their laser pose back into the base pose (``laser (+) mount^-1``), which
is exact for a rigid mount and keeps every core method free of the offset. An
upside-down laser's scans are given to them as a level laser there would read
them (``LaserMount.level``). A
node that learns the mount from ``/tf_static`` only with the first scan defers
it (``defer_mount``): odometry is held until :meth:`LocalizerAdapter.set_mount`.

Odometry reaches the localizer in step with the sensor: before a scan (image) stamped ``t``, the
odometry stamped up to ``t`` is handed on and newer odometry waits for a later input. A live scan
arrives after odometry newer than its stamp (a laser driver stamps the start of its sweep and
publishes it a period later); given that odometry first, a method would move its estimate to a
later instant than the scan it then weighs (IAL's bounded-error boxes lose the true pose in turns).
A replayed bag, in log order, gives the same sequence.

Each output also carries ``map -> odom`` as nav2_amcl computes it: the estimate
composed with the inverse of the odometry at the estimate's stamp.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..core.errors import LocalizationSuiteError, MapError, ScanError
from ..core.filter.odometry_gate import TIME_JUMP_RESET_S, OdometryGate
from ..core.grid_map import MAX_COORDINATE_M
from ..core.localizer import CameraLocalizer, Estimate, Localizer, LocalizerStatus, Preparer, prepared_for
from ..core.scan import LaserMount, Scan
from ..core.se2 import compose, inverse, relative
from . import conversions
from .tf import map_to_odom

__all__ = ["AdapterOutput", "InputClock", "LocalizerAdapter", "ThrottledLog"]


class ThrottledLog:
    """Log through ``sink(level, text)`` at most once per ``period_s`` for each key."""

    def __init__(self, sink: Callable[[str, str], None], period_s: float = 5.0) -> None:
        self._sink = sink
        self._period = period_s
        self._last: dict[str, float] = {}
        self.counts: dict[str, int] = {}

    def __call__(self, level: str, key: str, text: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1
        now = time.monotonic()
        if now - self._last.get(key, -np.inf) >= self._period:
            self._last[key] = now
            repeats = self.counts[key]
            suffix = f" ({repeats} times so far)" if repeats > 1 else ""
            self._sink(level, text + suffix)


class AdapterOutput:
    """What one update produced: the core estimate, its update time, and the messages to publish.

    The messages are built on first access: a benchmark that reads only the
    estimate does not pay for turning 50,000 particles into a PoseArray.

    Attributes:
        has_pose: whether there is a pose to publish: the estimate is neither LOST (nothing worth using:
            diagnostics and candidates only) nor INITIALIZING (no fix yet), and its pose and covariance are finite.
        map_to_odom: ``(3,)`` the ``map -> odom`` transform this estimate implies (None without odometry or
            without a pose).
        odometry_lag: how far [s] the estimate's stamp lies after the newest odometry used for it.
    """

    def __init__(
        self,
        estimate: Estimate,
        update_ms: float,
        node_name: str,
        max_candidates: int,
        extras_builder: Callable[[Estimate], dict[str, Any]] | None,
        *,
        frame_id: str = "map",
        map_to_odom: NDArray[np.float64] | None = None,
        odometry_lag: float = math.inf,
    ) -> None:
        self.estimate = estimate
        self.has_pose = _publishes_pose(estimate)
        self.update_ms = update_ms
        self.frame_id = frame_id
        self.map_to_odom = map_to_odom
        self.odometry_lag = odometry_lag
        self._node_name = node_name
        self._max_candidates = max_candidates
        self._extras_builder = extras_builder

    @cached_property
    def pose(self) -> Any:
        """The pose message; None without a pose (:attr:`has_pose`): nothing is published on ``~/pose``."""
        return conversions.estimate_to_pose_msg(self.estimate, self.frame_id) if self.has_pose else None

    @cached_property
    def candidates(self) -> Any:
        return conversions.estimate_to_pose_array(self.estimate, self.frame_id, max_poses=self._max_candidates)

    @cached_property
    def diagnostics(self) -> Any:
        return conversions.estimate_to_diagnostics(self.estimate, self._node_name, self.update_ms)

    @cached_property
    def extras(self) -> dict[str, Any]:
        return self._extras_builder(self.estimate) if self._extras_builder else {}


def _finite_estimate(estimate: Estimate) -> bool:
    return bool(np.all(np.isfinite(estimate.pose)) and np.all(np.isfinite(estimate.covariance)))


_NO_POSE_STATES = (LocalizerStatus.LOST, LocalizerStatus.INITIALIZING)


def _publishes_pose(estimate: Estimate) -> bool:
    """LOST (nothing worth using) and INITIALIZING (no fix yet: IAL's whole-map box, MCL's uniform cloud) publish no
    pose; neither does a non-finite estimate."""
    return estimate.status not in _NO_POSE_STATES and _finite_estimate(estimate)


def _same_map(a: Any, b: Any) -> bool:
    """Same cells, resolution and origin; OccupancyGrid stores the resolution as float32, hence the tolerance."""
    return (
        a.data.shape == b.data.shape
        and abs(a.resolution - b.resolution) < 1e-6
        and np.allclose(a.origin, b.origin, atol=1e-6)
        and np.array_equal(a.data, b.data)
    )


# Spread of an initial pose whose covariance cannot be used: ROS 1 amcl's (0.5 m, 0.5 m, pi/12 rad).
DEFAULT_INITIAL_STD = np.array([0.5, 0.5, math.pi / 12.0])
# Odometry poses held at most for a later sensor input (a few minutes of a fast odometry source):
# beyond, the oldest go to the localizer (or are dropped while the mount is not known).
_MAX_HELD_ODOMETRY = 20_000
# An initial pose stamped this much [s] before the oldest odometry cannot be moved on to now in full: warned.
_INITIAL_POSE_GAP_S = 0.2


def _covariance_problem(covariance: NDArray[np.float64]) -> str | None:
    """Why a ``(3, 3)`` covariance cannot be used (not finite, symmetric and positive definite, or too wide), or None."""
    if not np.all(np.isfinite(covariance)) or not np.allclose(covariance, covariance.T, atol=1e-9):
        return "not positive definite"
    if np.any(np.diag(covariance)[:2] > MAX_COORDINATE_M**2):
        return f"wider than {MAX_COORDINATE_M:g} m"
    return None if np.linalg.eigvalsh(covariance).min() > 0.0 else "not positive definite"


# A quaternion whose squared norm is farther than this from 1 is no rotation (tf2's TF_DENORMALIZED_QUATERNION).
_QUATERNION_TOLERANCE = 0.01


def _not_a_rotation(orientation: Any) -> str | None:
    """Why a ``geometry_msgs/Quaternion`` is no rotation (not finite, or not of unit norm, as tf2 refuses), or None."""
    q = np.array([orientation.x, orientation.y, orientation.z, orientation.w], dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        norm2 = float(np.dot(q, q))
    if math.isfinite(norm2) and abs(norm2 - 1.0) <= _QUATERNION_TOLERANCE:
        return None
    return f"its quaternion (x, y, z, w) {q.tolist()!r} is not a rotation (squared norm {norm2!r}, not 1)"


def _far(pose: NDArray[np.float64]) -> bool:
    return bool(np.any(np.abs(pose[:2]) > MAX_COORDINATE_M))


class InputClock:
    """The node's time as its inputs tell it, guarded against stamps that jump.

    With a ``clock`` (the node's ROS clock, or the log time of a replayed bag), a stamp more than
    ``max_future_s`` ahead of it is refused and does not move the node's time: one message stamped
    in 2038 must not make every later real message look old. A stamp more than
    ``time_jump_reset_s`` behind its own stream's last one starts a new timeline (a bag looped, a
    simulator restarted, or a future stamp got through without a clock), as ROS' time-jump handling
    does; a smaller step back is refused. Verdicts: ``ok``, ``future``, ``older``, ``reset``.
    """

    def __init__(
        self,
        max_future_s: float = 1.0,
        time_jump_reset_s: float = TIME_JUMP_RESET_S,
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.max_future_s = float(max_future_s)
        self.time_jump_reset_s = float(time_jump_reset_s)
        self.clock = clock
        self.newest: float | None = None
        self._last: dict[str, float] = {}

    def admit(self, stream: str, stamp: float) -> str:
        """The verdict on ``stamp`` [s] of ``stream``; ``ok`` and ``reset`` accept it."""
        if not math.isfinite(stamp):
            return "future"
        if self.clock is not None and stamp > self.clock() + self.max_future_s:
            return "future"
        last = self._last.get(stream)
        if last is not None and stamp < last - self.time_jump_reset_s:
            self._last = {stream: stamp}
            self.newest = stamp
            return "reset"
        if last is not None and stamp < last:
            return "older"
        self._last[stream] = stamp
        self.newest = stamp if self.newest is None else max(self.newest, stamp)
        return "ok"


class LocalizerAdapter:
    """Bridge between ROS messages and one core localizer.

    Args:
        localizer: a :class:`Localizer` or :class:`CameraLocalizer`.
        node_name: used in diagnostics.
        log: ``log(level, text)`` with level in ``debug|info|warn|error``.
        mount: laser pose in the base frame.
        extras_builder: turns an estimate into method-specific messages, keyed by
            topic suffix (e.g. ``{"boxes": MarkerArray}``).
        max_candidates: cap on the poses put in the candidates message.
        max_future_s, time_jump_reset_s, clock: the :class:`InputClock`'s limits [s] and "now" [s].
        global_frame: frame of the outputs; initial poses in another frame are refused.
        defer_mount: hold odometry until :meth:`set_mount` gives the mount (a node reading /tf_static).
    """

    def __init__(
        self,
        localizer: Localizer | CameraLocalizer,
        *,
        node_name: str,
        log: Callable[[str, str], None],
        mount: LaserMount | None = None,
        extras_builder: Callable[[Estimate], dict[str, Any]] | None = None,
        max_candidates: int = 2000,
        max_future_s: float = 1.0,
        time_jump_reset_s: float = TIME_JUMP_RESET_S,
        clock: Callable[[], float] | None = None,
        global_frame: str = "map",
        defer_mount: bool = False,
    ) -> None:
        self.localizer = localizer
        # The sensor side, told apart once by the runtime-checkable protocols: scans go to the one, images to the other.
        self._laser: Localizer | None = localizer if isinstance(localizer, Localizer) else None
        self._prepared_key: tuple[Any, ...] | None = None  # the scanner and map prepare() last ran for
        self._keys_prepared_before: set[tuple[Any, ...]] = set()  # earlier scanner layouts on this map
        self._camera: CameraLocalizer | None = localizer if isinstance(localizer, CameraLocalizer) else None
        self.max_candidates = max_candidates
        self.node_name = node_name
        self.log = ThrottledLog(log)
        self._info = log
        self.global_frame = global_frame
        self.mount = LaserMount()
        self._mount_inv: NDArray[np.float64] = np.zeros(3)
        # The base's odometry not yet given to the localizer: newer than the last sensor input, or
        # (defer_mount) waiting for the mount.
        self._held_odometry: list[tuple[float, NDArray[np.float64]]] = []
        self._mount_known = False
        self._extras_builder = extras_builder
        self.clock = InputClock(max_future_s, time_jump_reset_s, clock)
        # The base's odometry (before the mount), for map -> odom at an estimate's stamp.
        self.odometry = OdometryGate(time_jump_s=time_jump_reset_s)
        self._last_odometry_stamp = -math.inf
        self._last_beam_count: int | None = None
        self.has_map = False
        self._current_map: Any = None
        if not defer_mount:
            self.set_mount(mount or LaserMount())

    @property
    def current_map(self) -> Any:
        """The map in use (a ``GridMap``), or None."""
        return self._current_map

    @property
    def last_odometry_stamp(self) -> float:
        """Stamp [s] of the newest odometry used (-inf before any)."""
        return self._last_odometry_stamp

    @property
    def mount_known(self) -> bool:
        return self._mount_known

    def set_mount(self, mount: LaserMount) -> None:
        """Use ``mount`` from now on; held odometry goes to the localizer with the next sensor input."""
        self.mount = mount
        self._mount_inv = inverse(mount.pose)
        self._mount_known = True
        if hasattr(self.localizer, "set_laser_mount"):
            # One source of the mount: a method whose model needs it (IAL's base-motion bounds) gets it here.
            self.localizer.set_laser_mount(mount)

    def _release_odometry(self, until: float = math.inf) -> None:
        """Give the localizer the held odometry stamped up to ``until`` [s] (all of it by default)."""
        if not self._mount_known:
            return
        count = 0
        for stamp, pose in self._held_odometry:
            if stamp > until:
                break
            self.localizer.on_odometry(stamp, compose(pose, self.mount.pose))
            count += 1
        del self._held_odometry[:count]

    # -- inputs -------------------------------------------------------------------
    def on_map_msg(self, msg: Any) -> bool:
        """Use the map of ``msg``; False (logged) when it or the method refuses it."""
        grid_map = self.map_from_msg(msg)
        if grid_map is None:
            return False
        try:
            self.set_map(grid_map)
        except MapError as exc:
            self.log("error", "map", f"ignoring map message: {exc}")
            return False
        return True

    def map_from_msg(self, msg: Any) -> Any:
        """The ``GridMap`` of an OccupancyGrid, or None (logged) when it is unusable."""
        try:
            return conversions.grid_map_from_msg(msg)
        except MapError as exc:
            self.log("error", "map", f"ignoring map message: {exc}")
            return None

    def is_current_map(self, grid_map: Any) -> bool:
        """Whether ``grid_map`` is the map in use already (``set_map`` would keep it)."""
        return self._current_map is not None and _same_map(self._current_map, grid_map)

    def set_map(self, grid_map: Any) -> None:
        """Give the method ``grid_map``. Raises MapError when the method refuses it; it then has no map."""
        if not hasattr(self.localizer, "set_map"):
            return
        if self.is_current_map(grid_map):
            # map_yaml and the map topic often carry the same map; relearning it is wasted work.
            self._info("debug", "map unchanged: keeping the current one")
            return
        self._info("info", f"map {grid_map.width} x {grid_map.height} cells at {grid_map.resolution} m received")
        try:
            self.localizer.set_map(grid_map)
        except MapError:
            # The method may hold part of this map now: no map until the next one, whichever it is.
            self._current_map, self.has_map = None, False
            raise
        self._current_map = grid_map
        self.has_map = True

    def on_odom_msg(self, msg: Any) -> None:
        problem = _not_a_rotation(msg.pose.pose.orientation)
        if problem is not None:
            self.log("warn", "odom_quaternion", f"ignoring odometry: {problem}")
            return
        self.on_odometry(*conversions.odometry_from_msg(msg))

    def on_odometry(self, stamp: float, pose: NDArray[np.float64]) -> None:
        """The base's odometry pose ``(3,)`` in the odom frame at ``stamp`` [s] (from the odom topic or /tf)."""
        if not np.all(np.isfinite(pose)):
            self.log("warn", "odom_nan", f"ignoring odometry with non-finite pose {pose.tolist()!r}")
            return
        if _far(pose):
            self.log("warn", "odom_far", f"ignoring odometry at ({pose[0]!r}, {pose[1]!r}) m: more than "
                     f"{MAX_COORDINATE_M:g} m from the odometry origin")
            return
        if not self._admit("odometry", stamp):
            return
        self.odometry.add(stamp, pose)  # a stamp far in the past starts its new timeline, as the clock did
        self._last_odometry_stamp = stamp
        self._held_odometry.append((stamp, pose))
        if len(self._held_odometry) > _MAX_HELD_ODOMETRY:
            # No sensor input for a long while: the oldest go on now (or are dropped without a mount).
            excess = len(self._held_odometry) - _MAX_HELD_ODOMETRY
            self._release_odometry(self._held_odometry[excess - 1][0])
            del self._held_odometry[:-_MAX_HELD_ODOMETRY]

    def on_initial_pose_msg(self, msg: Any) -> bool:
        """An initial pose (RViz "2D Pose Estimate"); False when refused (another frame, no rotation, non-finite, far)."""
        frame = msg.header.frame_id.lstrip("/")
        if frame != self.global_frame:
            self.log("warn", "initialpose_frame", f"ignoring initial pose in frame {frame!r}: initial poses must be in "
                     f"the global frame {self.global_frame!r} (global_frame_id)")
            return False
        problem = _not_a_rotation(msg.pose.pose.orientation)
        if problem is not None:
            self.log("warn", "initialpose", f"ignoring initial pose: {problem}")
            return False
        pose, covariance = conversions.initial_pose_from_msg(msg)
        if not np.all(np.isfinite(pose)):
            self.log("warn", "initialpose", f"ignoring initial pose with non-finite values {pose.tolist()!r}")
            return False
        if _far(pose):
            self.log("warn", "initialpose", f"ignoring initial pose at ({float(pose[0])!r}, {float(pose[1])!r}) m: more than "
                     f"{MAX_COORDINATE_M:g} m from the origin of {frame!r}")
            return False
        stamp = conversions.stamp_to_seconds(msg.header.stamp)
        then, now = self.odometry.at(stamp), self.odometry.latest
        if stamp > 0.0 and then is not None and now is not None:
            # A pose of the past (RViz stamps it when clicked): moved on by the odometry since, as nav2_amcl does.
            pose = compose(pose, relative(then, now))
            oldest = self.odometry.oldest_stamp
            if oldest is not None and stamp < oldest - _INITIAL_POSE_GAP_S:
                self.log("warn", "initialpose_old", f"initial pose stamped {oldest - stamp:.2f} s before the oldest "
                         "odometry kept (odometry counts from activation): moved on by the odometry since then only")
        problem = _covariance_problem(covariance)
        if problem is not None:
            shown = [[float(f"{value:.6g}") for value in row] for row in covariance.tolist()]  # np.round overflows
            self.log("warn", "initialpose_covariance",
                     f"initial pose covariance (x, y, yaw) {shown!r} is {problem}: "
                     f"using the default spread (std {DEFAULT_INITIAL_STD[0]:g} m, {DEFAULT_INITIAL_STD[1]:g} m, "
                     f"{math.degrees(DEFAULT_INITIAL_STD[2]):g} deg)")
            self.set_initial_pose(pose)
        else:
            self.set_initial_pose(pose, covariance)
        return True

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64] | None = None) -> None:
        """Restart around the base pose ``(3,)`` in the global frame; no covariance: the default spread."""
        if covariance is None:
            covariance = np.diag(np.square(DEFAULT_INITIAL_STD))
        self._info("info", f"initial pose x={pose[0]:.2f} y={pose[1]:.2f} yaw={pose[2]:.2f}")
        grid_map = self._current_map
        if grid_map is not None and not bool(grid_map.in_bounds(grid_map.world_to_cell(pose[None, :2]))[0]):
            x0, x1, y0, y1 = grid_map.extent
            # Accepted, as nav2_amcl does (a robot may start beyond the map and drive into it), but said: a pose
            # far off the map is more often a frame or a unit mixed up.
            self.log("warn", "initialpose_off_map", f"initial pose at ({float(pose[0]):g}, {float(pose[1]):g}) m is "
                     f"outside the map (x {x0:g} to {x1:g} m, y {y0:g} to {y1:g} m): no scan can confirm it there "
                     "until the robot is on the map")
        self._release_odometry()  # the pose is where the robot is now: at the newest odometry
        self.localizer.set_initial_pose(compose(pose, self.mount.pose), covariance)

    def reinitialize(self) -> None:
        self._info("info", "global localization requested")
        self.localizer.reinitialize()

    def request_nomotion_update(self) -> None:
        if hasattr(self.localizer, "request_nomotion_update"):
            self.localizer.request_nomotion_update()

    def on_scan_msg(self, msg: Any) -> AdapterOutput | None:
        if not self.has_map and hasattr(self.localizer, "set_map"):
            self.log("warn", "no_map", "scan received before any map: waiting for /map or map_yaml")
            return None
        try:
            scan = self.scan_from_msg(msg)
        except ScanError as exc:
            self.log("warn", "bad_scan", f"skipping scan: {exc}")
            return None
        if not scan.hit_mask.any() and not scan.no_return_mask.any():
            self.log("warn", "no_valid_beam", f"skipping scan at {scan.stamp:.3f} s: no valid beam")
            return None
        if self._last_beam_count is not None and scan.beam_count != self._last_beam_count:
            self.log("info", "beam_count", f"beam count changed from {self._last_beam_count} to {scan.beam_count}")
        if not self._admit("scan", scan.stamp):
            return None
        self._last_beam_count = scan.beam_count
        laser = self._laser
        if laser is None:
            raise TypeError(f"{type(self.localizer).__name__} is not a laser Localizer: it cannot take scans")
        self._release_odometry(scan.stamp)
        return self._run(lambda: laser.on_scan(scan))

    def preparation_due(self, msg: Any) -> bool:
        """Whether the localizer would precompute for this scan's scanner (``Preparer``) and has not yet.

        A scan laid out as the last prepared one is not; one laid out otherwise is asked of the method
        (``prepared_for``): a beam more or less, or an ``angle_min`` a hair off, usually need nothing new.
        """
        if not (self.has_map and isinstance(self.localizer, Preparer)):
            return False
        key = self._preparation_key(msg)
        if key == self._prepared_key:
            return False
        try:
            scan = self.scan_from_msg(msg)
        except ScanError:
            return False  # on_scan_msg says why, throttled
        if not scan.hit_mask.any():
            return False  # a scan with no hit is skipped, not prepared for
        if self._prepared_key is not None and key[0] == self._prepared_key[0] and prepared_for(self.localizer, scan):
            self._prepared_key = key
            return False
        if key in self._keys_prepared_before:
            self.log("warn", "scanner_alternates",
                     f"precomputing again for a scanner layout prepared before ({key[1]} beams from "
                     f"{key[2]:.4f} rad by {key[3]:.6f} rad): are two scanners publishing on one topic? "
                     "Each change drops the scan that brings it")
        return True

    def prepare(self, msg: Any) -> None:
        """Run the localizer's precomputation for this scan's scanner (in a worker thread, by the node).

        Raises:
            ScanError: the scan cannot be read (the next one is tried).
        """
        key = self._preparation_key(msg)
        if isinstance(self.localizer, Preparer):
            self.localizer.prepare(self.scan_from_msg(msg))
        if self._prepared_key is not None and self._prepared_key[0] == key[0]:
            if len(self._keys_prepared_before) >= 16:
                self._keys_prepared_before.clear()
            self._keys_prepared_before.add(self._prepared_key)
        else:
            self._keys_prepared_before.clear()  # another map: what was prepared before is gone
        self._prepared_key = key

    def scan_from_msg(self, msg: Any) -> Scan:
        """A ``LaserScan`` as the methods get it: converted, and levelled at the mount (``LaserMount.level``).

        Raises:
            ScanError: the scan cannot be read.
        """
        return self.mount.level(conversions.scan_from_msg(msg))

    def _preparation_key(self, msg: Any) -> tuple[Any, ...]:
        return (id(self._current_map), len(msg.ranges), float(msg.angle_min), float(msg.angle_increment),
                float(msg.range_min), float(msg.range_max), self.mount.upside_down)

    def on_image_msg(self, msg: Any) -> AdapterOutput | None:
        try:
            image = conversions.image_from_msg(msg)
        except ValueError as exc:
            self.log("warn", "bad_image", f"skipping image: {exc}")
            return None
        stamp = conversions.stamp_to_seconds(msg.header.stamp)
        if not self._admit("image", stamp):
            return None
        camera = self._camera
        if camera is None:
            raise TypeError(f"{type(self.localizer).__name__} is not a CameraLocalizer: it cannot take images")
        self._release_odometry(stamp)
        return self._run(lambda: camera.on_image(stamp, image))

    def _admit(self, stream: str, stamp: float) -> bool:
        """Whether an input stamped ``stamp`` is used (InputClock), with a throttled reason when not."""
        verdict = self.clock.admit(stream, stamp)
        if verdict == "future":
            now = self.clock.clock() if self.clock.clock is not None else math.nan
            hint = (": the clock has not started (use_sim_time with no /clock yet? `ros2 bag play --clock`)"
                    if now == 0.0 else "")
            self.log("warn", f"{stream}_future", f"ignoring {stream} stamped {stamp:.3f} s: more than "
                     f"{self.clock.max_future_s:g} s ahead of the node's clock ({now:.3f} s){hint}")
        elif verdict == "older":
            self.log("warn", f"{stream}_time", f"ignoring {stream} stamped {stamp:.3f} s, older than the last one")
        elif verdict == "reset":
            self._held_odometry.clear()  # odometry of the old timeline
            self.log("info", "time_jump", f"time jumped back to {stamp:.3f} s (more than {self.clock.time_jump_reset_s:g} s): "
                       "starting a new timeline (a bag looped or a simulator restarted?)")
        return verdict in ("ok", "reset")

    # -- outputs ------------------------------------------------------------------
    def _run(self, update: Callable[[], Estimate | None]) -> AdapterOutput | None:
        start = time.perf_counter()
        try:
            estimate = update()
        except LocalizationSuiteError as exc:
            self.log("warn", type(exc).__name__, f"update skipped: {exc}")
            return None
        update_ms = (time.perf_counter() - start) * 1e3
        if estimate is None:
            return None
        return self.build_output(estimate, update_ms)

    def to_base(self, laser_poses: NDArray[np.float64]) -> NDArray[np.float64]:
        return compose(laser_poses, self._mount_inv)

    def to_base_estimate(self, estimate: Estimate) -> Estimate:
        """The core's estimate of the laser, as a new estimate of the base (the core's own is left as it is)."""
        if not self.mount.pose.any():
            return estimate
        boxes = estimate.boxes
        if boxes is not None and len(boxes):
            from ..core.interval import compose_boxes  # numba: only for localizers that publish boxes

            boxes = compose_boxes(boxes.reshape(-1, 6), self._mount_inv).reshape(-1, 3, 2)
        return replace(
            estimate,
            pose=self.to_base(estimate.pose),
            candidates=self.to_base(estimate.candidates) if len(estimate.candidates) else estimate.candidates,
            boxes=boxes,
        )

    def build_output(self, estimate: Estimate, update_ms: float) -> AdapterOutput:
        """The output of an estimate; a LOST or INITIALIZING one, or one whose pose or covariance is not finite, gets
        no pose and no ``map -> odom``."""
        base = self.to_base_estimate(estimate)
        odom = self.odometry.at(base.stamp)
        has_pose = _publishes_pose(base)
        if not has_pose and base.status not in _NO_POSE_STATES:
            self.log("warn", "estimate_nan", f"{base.status.value} estimate at {base.stamp:.3f} s has a non-finite pose "
                     f"{base.pose.tolist()!r} or covariance: no pose published")
        return AdapterOutput(
            base, update_ms, self.node_name, self.max_candidates, self._extras_builder, frame_id=self.global_frame,
            map_to_odom=None if odom is None or not has_pose else map_to_odom(base.pose, odom),
            odometry_lag=base.stamp - self._last_odometry_stamp,
        )
