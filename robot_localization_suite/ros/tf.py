"""TF for a planar robot: transforms as SE(2) poses, a small buffer of the frames a localizer needs.

A localizer reads two things from TF, as nav2_amcl does: odometry (``odom -> base``, through
any chain of frames between them) and the laser's mount (``base -> laser``, on ``/tf_static``),
and writes one: ``map -> odom``. Transforms are projected on the plane (x, y, yaw of the child's x
axis), keeping one more bit: whether the child's z axis points down (a laser mounted upside down,
whose angles then turn the other way; static links only). One with a non-finite value or a
quaternion whose norm is off by more than tf2's tolerance is refused, as is one stamped more than
``transform_tolerance`` behind its frame's newest.
``tf2_msgs`` may be missing (a PyPI install without ``make``'s interfaces): :data:`TFMessage`
is then None and the callers say so.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from geometry_msgs.msg import TransformStamped
from numpy.typing import NDArray

from ..core.filter.odometry_gate import TIME_JUMP_RESET_S, OdometryGate
from ..core.grid_map import MAX_COORDINATE_M
from ..core.se2 import compose, inverse, quaternion_to_yaw, yaw_to_quaternion
from .conversions import seconds_to_stamp, stamp_to_seconds

try:
    from tf2_msgs.msg import TFMessage
except ImportError:  # no tf2_msgs: neither a ROS 2 install nor make's interfaces/
    TFMessage = None

__all__ = ["TFMessage", "TransformError", "PlanarTransform", "TransformBuffer", "transform_from_msg",
           "transform_to_msg", "tf_message", "frame_name", "map_to_odom"]

# tf2 refuses a quaternion whose norm differs from 1 by more than this (TF_DENORMALIZED_QUATERNION).
QUATERNION_TOLERANCE = 0.01


class TransformError(ValueError):
    """A transform that cannot be used (non-finite, a quaternion that is not a rotation)."""


def frame_name(frame_id: str) -> str:
    """A frame id as tf2 compares them: without a leading slash."""
    return frame_id.lstrip("/")


@dataclass(frozen=True)
class PlanarTransform:
    """``parent -> child`` at ``stamp`` [s]: the child frame's pose ``(x, y, yaw)`` in the parent, and whether
    the child is ``upside_down`` in it (its z axis points down: an angle ``a`` in the child is ``yaw - a``)."""

    parent: str
    child: str
    stamp: float
    pose: NDArray[np.float64]
    upside_down: bool = False


def transform_from_msg(msg: Any) -> PlanarTransform:
    """``geometry_msgs/TransformStamped`` -> :class:`PlanarTransform` (z dropped; roll and pitch kept only as
    whether the child's z axis points down).

    Raises:
        TransformError: a non-finite value, a translation beyond ``MAX_COORDINATE_M``, or a quaternion that is
            not a unit one, naming the frames.
    """
    t, q = msg.transform.translation, msg.transform.rotation
    parent, child = frame_name(msg.header.frame_id), frame_name(msg.child_frame_id)
    values = [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
    if not all(math.isfinite(v) for v in values):
        raise TransformError(f"transform {parent} -> {child} has a non-finite value: {values!r}")
    if max(abs(t.x), abs(t.y)) > MAX_COORDINATE_M:
        raise TransformError(f"transform {parent} -> {child} moves more than {MAX_COORDINATE_M:g} m: "
                             f"({t.x!r}, {t.y!r})")
    norm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise TransformError(f"transform {parent} -> {child} has a quaternion of norm {norm:.4g}, not a rotation")
    yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)  # the heading of the child's x axis
    z_axis_up = (1.0 - 2.0 * (q.x * q.x + q.y * q.y)) / (norm * norm)  # z of the child's z axis in the parent
    return PlanarTransform(parent, child, stamp_to_seconds(msg.header.stamp), np.array([t.x, t.y, yaw]),
                           upside_down=bool(z_axis_up < 0.0))


def transform_to_msg(stamp: float, parent: str, child: str, pose: NDArray[np.float64], *,
                     upside_down: bool = False) -> TransformStamped:
    """A planar pose as ``geometry_msgs/TransformStamped`` ``parent -> child`` at ``stamp`` [s]
    (``upside_down``: the child also rolled by pi about its x axis)."""
    msg = TransformStamped()
    msg.header.stamp = seconds_to_stamp(stamp)
    msg.header.frame_id = parent
    msg.child_frame_id = child
    msg.transform.translation.x, msg.transform.translation.y = float(pose[0]), float(pose[1])
    r = msg.transform.rotation
    x, y, z, w = yaw_to_quaternion(float(pose[2]))
    # yaw then a roll of pi: (w, z) of the yaw move to (x, y)
    r.x, r.y, r.z, r.w = (w, z, 0.0, 0.0) if upside_down else (x, y, z, w)
    return msg


def _in_upside_down(pose: NDArray[np.float64]) -> NDArray[np.float64]:
    """A pose given in an upside-down frame, in the level frame with the same x axis (y and yaw turn over)."""
    return np.array([pose[0], -pose[1], -pose[2]])


def tf_message(transforms: Iterable[TransformStamped]) -> Any:
    """A ``tf2_msgs/TFMessage`` holding ``transforms``.

    Raises:
        RuntimeError: tf2_msgs is not installed.
    """
    if TFMessage is None:
        raise RuntimeError("tf2_msgs is not installed (a ROS 2 install has it; a PyPI one gets it from `make`)")
    return TFMessage(transforms=list(transforms))


class TransformBuffer:
    """The transforms of a tree of frames: the static ones, and a bounded history of each dynamic one.

    Args:
        log: ``log(level, key, text)``, throttled by the caller (the adapter's ``ThrottledLog``).
        tolerance_s: a dynamic transform stamped more than this behind its frame's newest is dropped.
        time_jump_reset_s: one stamped more than this behind starts a new timeline for its frame.
        ignore: ``(parent, child)`` pairs not stored (the node's own ``map -> odom``).
    """

    def __init__(
        self,
        log: Callable[[str, str, str], None],
        *,
        tolerance_s: float = 1.0,
        time_jump_reset_s: float = TIME_JUMP_RESET_S,
        ignore: Iterable[tuple[str, str]] = (),
    ) -> None:
        self.log = log
        self.tolerance_s = float(tolerance_s)
        self.time_jump_reset_s = float(time_jump_reset_s)
        self.ignore = set(ignore)
        self._parent: dict[str, str] = {}
        self._static: dict[str, tuple[NDArray[np.float64], bool]] = {}  # child: (pose, upside down)
        self._dynamic: dict[str, OdometryGate] = {}
        self._newest: dict[str, float] = {}

    def add_message(self, msg: Any, *, static: bool) -> list[PlanarTransform]:
        """Store the usable transforms of a ``tf2_msgs/TFMessage``; returns the dynamic ones stored."""
        stored = []
        for item in msg.transforms:
            try:
                transform = transform_from_msg(item)
            except TransformError as exc:
                self.log("warn", "tf_bad", f"ignoring /tf{'_static' if static else ''} input: {exc}")
                continue
            if (transform.parent, transform.child) in self.ignore:
                continue
            if self.add(transform, static=static):
                stored.append(transform)
        return [t for t in stored if not static]

    def add_odometry(self, msg: Any, odom_frame: str, base_frame: str) -> list[tuple[float, NDArray[np.float64]]]:
        """Store a ``/tf`` message; the odometry it gives, as nav2 reads it: ``odom_frame -> base_frame`` at the
        stamp of each transform stored on the chain between them, ``(stamp, pose)`` in their order."""
        stored = self.add_message(msg, static=False)
        on_the_way = self.chain(odom_frame, base_frame) if stored else None
        if on_the_way is None:
            return []
        odometry = []
        for transform in stored:
            if transform.child in on_the_way:
                pose = self.lookup(odom_frame, base_frame, transform.stamp)
                if pose is not None:
                    odometry.append((transform.stamp, pose))
        return odometry

    def add(self, transform: PlanarTransform, *, static: bool) -> bool:
        """Store one transform; False when it is dropped (too old, or older than its frame's last)."""
        child = transform.child
        if static:
            self._parent[child] = transform.parent
            self._static[child] = (transform.pose, transform.upside_down)
            self._dynamic.pop(child, None)
            return True
        if transform.upside_down:
            self.log("warn", "tf_dynamic_upside_down", f"ignoring transform {transform.parent} -> {child} on /tf: its z axis "
                     "points down, which only a static transform (an upside-down laser on /tf_static) may do")
            return False
        history = self._dynamic.setdefault(child, OdometryGate(time_jump_s=self.time_jump_reset_s))
        newest = self._newest.get(child)
        if newest is not None and newest - self.time_jump_reset_s <= transform.stamp < newest - self.tolerance_s:
            self.log("warn", "tf_old", f"ignoring transform {transform.parent} -> {child} stamped {transform.stamp:.3f} s: "
                     f"older than transform_tolerance ({self.tolerance_s:g} s) behind its newest ({newest:.3f} s)")
            return False
        if not history.add(transform.stamp, transform.pose):
            return False
        self._parent[child] = transform.parent  # only a stored transform says who the parent is
        self._static.pop(child, None)
        self._newest[child] = transform.stamp
        return True

    def knows(self, frame: str) -> bool:
        """Whether a stored transform names ``frame`` (as parent or child)."""
        return frame in self._parent or frame in self._parent.values()

    def frames(self) -> set[str]:
        """Every frame a stored transform names."""
        return set(self._parent) | set(self._parent.values())

    def chain(self, parent: str, child: str) -> list[str] | None:
        """The frames from ``child`` up to ``parent`` (both included), or None when not connected."""
        frames = [child, *self.above(child)]
        return frames[: frames.index(parent) + 1] if parent in frames else None

    def above(self, frame: str) -> list[str]:
        """The frames above ``frame``, its parent first (up to the root, or to a loop)."""
        frames = [frame]
        while (up := self._parent.get(frames[-1])) is not None and up not in frames:
            frames.append(up)
        return frames[1:]

    def lookup(self, parent: str, child: str, stamp: float | None = None, *, static_only: bool = False) -> NDArray[np.float64] | None:
        """The pose of ``child`` in ``parent`` at ``stamp`` (dynamic links interpolated; None: the newest).

        None when the frames are not connected, (``static_only``) a link on the way is dynamic, or ``child``
        is upside down in ``parent`` (:meth:`lookup_mount` takes that one).
        """
        found = self.lookup_mount(parent, child, stamp, static_only=static_only)
        if found is None:
            return None
        pose, upside_down = found
        if upside_down:
            self.log("warn", "tf_upside_down", f"{child} is upside down in {parent} (its z axis points down): "
                     "not usable as a planar pose")
            return None
        return pose

    def lookup_mount(self, parent: str, child: str, stamp: float | None = None, *,
                     static_only: bool = False) -> tuple[NDArray[np.float64], bool] | None:
        """As :meth:`lookup`, with whether ``child`` is upside down in ``parent`` (a laser's mount).

        ``child`` below ``parent``, or both below a common frame, as tf2 resolves a tree (the laser as the
        base's parent, or its sibling under ``base_link``); not through an upside-down frame on ``parent``'s side.
        """
        frames = self.chain(parent, child)
        if frames is not None:
            return self._up(frames, stamp, static_only)
        up_child, up_parent = [child, *self.above(child)], [parent, *self.above(parent)]
        common = next((frame for frame in up_child if frame in up_parent), None)
        if common is None:
            return None
        child_in = self._up(up_child[: up_child.index(common) + 1], stamp, static_only)
        parent_in = self._up(up_parent[: up_parent.index(common) + 1], stamp, static_only)
        if child_in is None or parent_in is None or parent_in[1]:
            return None
        return compose(inverse(parent_in[0]), child_in[0]), child_in[1]

    def _up(self, frames: list[str], stamp: float | None,
            static_only: bool) -> tuple[NDArray[np.float64], bool] | None:
        """The pose of ``frames[0]`` in ``frames[-1]`` along the chain, and whether it is upside down there."""
        pose: NDArray[np.float64] = np.zeros(3)
        upside_down = False
        for frame in frames[:-1]:  # from the child up: each link is the pose of ``frame`` in its parent
            static = self._static.get(frame)
            if static is None:
                if static_only:
                    return None
                history = self._dynamic.get(frame)
                if history is None:
                    return None
                link = history.latest if stamp is None else history.at(stamp)
                if link is None:
                    return None
                flipped = False
            else:
                link, flipped = static
            pose = compose(link, _in_upside_down(pose) if flipped else pose)
            upside_down ^= flipped
        return pose, upside_down


def map_to_odom(map_to_base: NDArray[np.float64], odom_to_base: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ``map -> odom`` transform that puts the base at ``map_to_base`` given odometry ``odom_to_base``."""
    return compose(map_to_base, inverse(odom_to_base))
