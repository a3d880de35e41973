"""The odometry gate: when a filter update is due, and the odometry it moves by.

nav2_amcl's ``update_min_d`` / ``update_min_a`` (Thrun et al., *Probabilistic
Robotics*, 8.3.5: update only after enough motion): a bounded buffer of
odometry poses, the pose at a stamp, the reference pose of the last update
and the thresholds that make the next one due. Non-finite and out-of-order
odometry is rejected (counted, never raised).
"""

from __future__ import annotations

import bisect
import math
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..motion import odometry_delta
from ..se2 import angle_difference, wrap_angle

__all__ = ["MotionMeasure", "OdometryGate", "DEFAULT_CAPACITY", "TIME_JUMP_RESET_S"]

#: Odometry poses kept at least (the buffer holds between this and twice this many).
DEFAULT_CAPACITY = 2000
#: A stamp this much older than the last one starts a new timeline [s] (ROS' time-jump handling).
TIME_JUMP_RESET_S = 3.0


class MotionMeasure(Enum):
    """How the motion since the last update is measured against the thresholds."""

    #: Net displacement from the reference pose: distance and absolute heading change (nav2).
    DISPLACEMENT = "displacement"
    #: Path since the last update: summed step translations and ``|rot1| + |rot2|`` of each step.
    PATH = "path"


Pose = NDArray[np.float64]


class OdometryGate:
    """Odometry buffer and update gate shared by the localizers.

    Args:
        min_translation: motion [m] that makes an update due (``update_min_d``).
        min_rotation: rotation [rad] that makes an update due (``update_min_a``).
        measure: net displacement from the reference pose, or path length since the last update.
        capacity: odometry poses kept at least (older ones are dropped in blocks of this size).
        keep_steps: never drop poses whose steps :meth:`take_steps` has not returned yet
            (for a caller that takes them at every scan, as IAL's bounded prediction).

    Either threshold reached makes an update due, so a threshold of 0 does as soon as the motion
    is known. ``forced`` (set by :meth:`request_update` and :meth:`reset`) makes the next update
    due whatever the motion.
    """

    def __init__(
        self,
        min_translation: float = 0.0,
        min_rotation: float = 0.0,
        *,
        measure: MotionMeasure = MotionMeasure.DISPLACEMENT,
        capacity: int = DEFAULT_CAPACITY,
        keep_steps: bool = False,
        time_jump_s: float = TIME_JUMP_RESET_S,
    ) -> None:
        if not (min_translation >= 0.0 and min_rotation >= 0.0):
            raise ValueError(f"gate thresholds must be >= 0, got {min_translation!r} m, {min_rotation!r} rad")
        if capacity < 1:
            raise ValueError(f"gate capacity must be >= 1, got {capacity!r}")
        self.min_translation = float(min_translation)
        self.min_rotation = float(min_rotation)
        self.measure = MotionMeasure(measure)
        self.capacity = int(capacity)
        self.keep_steps = bool(keep_steps)
        self.time_jump_s = float(time_jump_s)
        self.rejected = 0
        self.time_jumps = 0
        self._stamps: list[float] = []
        self._poses: list[Pose] = []
        self._step_start = 0  # index of the pose the next step of take_steps starts from
        self.reference: Pose | None = None
        self.forced = True
        self._path = [0.0, 0.0]

    # -- odometry in ----------------------------------------------------------------------
    def add(self, stamp: float, pose: ArrayLike) -> bool:
        """Record odometry ``pose`` ``(3,)`` [m, m, rad] at ``stamp`` [s]; False (and counted) when rejected.

        A non-finite pose or stamp, or a stamp older than the last one, is rejected; a pose at the
        last stamp replaces the last pose (with ``keep_steps``, it is one more step). A stamp more
        than ``time_jump_s`` older than the last one starts a new timeline (a bag looped, a simulator
        restarted): the buffer and the reference are cleared and the next update is forced, so
        time going back never blocks odometry for good.
        """
        pose_arr = np.array(pose, dtype=np.float64).reshape(-1)
        if pose_arr.size != 3 or not np.all(np.isfinite(pose_arr)) or not math.isfinite(stamp):
            self.rejected += 1
            return False
        stamps, poses = self._stamps, self._poses
        if stamps and stamp < stamps[-1] - self.time_jump_s:
            self.restart()
            self.time_jumps += 1
        elif stamps and stamp < stamps[-1]:
            self.rejected += 1
            return False
        if self.measure is MotionMeasure.PATH and poses:
            delta = odometry_delta(poses[-1], pose_arr)
            self._path[0] += delta.trans
            self._path[1] += abs(delta.rot1) + abs(delta.rot2)
        if stamps and stamp == stamps[-1] and not self.keep_steps:
            poses[-1] = pose_arr
            return True
        stamps.append(float(stamp))
        poses.append(pose_arr)
        if len(stamps) > 2 * self.capacity:
            drop = min(self.capacity, self._step_start) if self.keep_steps else self.capacity
            del stamps[:drop]
            del poses[:drop]
            self._step_start = max(self._step_start - drop, 0)
        return True

    @property
    def oldest_stamp(self) -> float | None:
        """Stamp [s] of the oldest odometry pose kept (None before any)."""
        return self._stamps[0] if self._stamps else None

    @property
    def latest(self) -> Pose | None:
        """The last odometry pose (None before any)."""
        return self._poses[-1] if self._poses else None

    def at(self, stamp: float) -> Pose | None:
        """Odometry pose at ``stamp``, interpolated between the bracketing poses (clamped at the ends)."""
        stamps = self._stamps
        if not stamps:
            return None
        index = bisect.bisect_left(stamps, stamp)
        if index <= 0:
            return self._poses[0]
        if index >= len(stamps):
            return self._poses[-1]
        t0, t1 = stamps[index - 1], stamps[index]
        p0, p1 = self._poses[index - 1], self._poses[index]
        ratio = (stamp - t0) / (t1 - t0)
        out = p0 + ratio * (p1 - p0)
        out[2] = wrap_angle(p0[2] + ratio * float(angle_difference(p1[2], p0[2])))
        return out

    def take_steps(self) -> list[tuple[Pose, Pose]]:
        """The consecutive odometry steps ``(previous, current)`` received since the last call."""
        poses = self._poses
        steps = [(poses[k], poses[k + 1]) for k in range(self._step_start, len(poses) - 1)]
        self._step_start = max(len(poses) - 1, 0)
        return steps

    def clear(self) -> None:
        """Forget the buffered odometry (the reference and the forced flag are kept)."""
        self._stamps.clear()
        self._poses.clear()
        self._step_start = 0

    def restart(self) -> None:
        """A new timeline: no buffered odometry, no reference, the next update forced."""
        self.clear()
        self.reset(force=True)

    # -- the gate -------------------------------------------------------------------------
    def motion(self, pose: ArrayLike | None = None) -> tuple[float, float]:
        """Motion since the last update ``(translation [m], rotation [rad])`` as ``measure`` says.

        For ``DISPLACEMENT`` from the reference to ``pose`` (default: the latest pose);
        ``(nan, nan)`` when either is unknown.
        """
        if self.measure is MotionMeasure.PATH:
            return self._path[0], self._path[1]
        current = self.latest if pose is None else np.asarray(pose, dtype=np.float64)
        if self.reference is None or current is None:
            return math.nan, math.nan
        translation = math.hypot(current[0] - self.reference[0], current[1] - self.reference[1])
        return translation, abs(float(angle_difference(current[2], self.reference[2])))

    def moved(self, pose: ArrayLike | None = None) -> bool:
        """Whether the motion since the last update reaches either threshold (False when unknown)."""
        translation, rotation = self.motion(pose)
        return translation >= self.min_translation or rotation >= self.min_rotation

    def due(self, pose: ArrayLike | None = None) -> bool:
        """Whether an update is due: forced, or :meth:`moved`."""
        return self.forced or self.moved(pose)

    def request_update(self) -> None:
        """Make the next update due whatever the motion (``request_nomotion_update``)."""
        self.forced = True

    def mark_updated(self, pose: ArrayLike | None) -> None:
        """An update happened at odometry ``pose`` (the new reference; None: unknown)."""
        self.reference = None if pose is None else np.array(pose, dtype=np.float64)
        self.forced = False
        self._path = [0.0, 0.0]

    def reset(self, *, force: bool = True) -> None:
        """A fresh filter: no reference pose, no motion since the last update; ``forced`` as given."""
        self.reference = None
        self.forced = force
        self._path = [0.0, 0.0]
