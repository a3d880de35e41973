"""The true motion of a scenario: exact unicycle arcs, the rotate-then-drive waypoint follower, kidnappings.

:func:`integrate_motion` integrates a motion plan once, at sub-steps of at most 10 ms, and samples it at
every laser step; it does not depend on any noise. Notes: docs/simulator.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..se2 import angle_difference, wrap_angle
from .config import Kidnapping, MotionPlan

__all__ = ["Trajectory", "IntegratedMotion", "integrate_unicycle", "integrate_motion"]

# Longest integration sub-step of the true motion [s].
_MAX_SUBSTEP = 0.01

# What integrate_motion returns: dense times, dense poses, step poses, step motion end, step velocity
# (all float64) and step kidnapped (bool).
_F64 = NDArray[np.float64]
IntegratedMotion = tuple[_F64, _F64, _F64, _F64, _F64, NDArray[np.bool_]]


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
                if abs(float(angle_difference(target, pose[2]))) < 1e-12:
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
                if abs(float(angle_difference(waypoint.yaw, pose[2]))) < 1e-12:
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


def integrate_motion(
    motion: MotionPlan,
    start: tuple[float, float, float],
    kidnappings: Sequence[Kidnapping],
    period: float,
    duration: float | None,
    *,
    max_time: float = math.inf,
) -> IntegratedMotion:
    """Integrate the motion at sub-steps until it ends (or the duration or ``max_time`` [s] passes).

    Returns ``(dense_times, dense_poses, step_poses, step_motion_end, step_velocity, step_kidnapped)``.
    """
    dt = period
    substeps = max(1, math.ceil(dt / _MAX_SUBSTEP - 1e-9))
    h = dt / substeps
    limit = float(duration) if duration is not None else math.inf
    kidnaps = sorted(kidnappings, key=lambda k: k.time)
    follower = _WaypointFollower(motion) if motion.waypoints else None
    segment_ends = np.cumsum([s.duration for s in motion.segments])
    pose = np.array(start, dtype=np.float64)
    dense_times, dense_poses = [0.0], [pose.copy()]
    step_vel: list[NDArray[np.float64]] = [np.zeros(2)]
    step_poses, step_end, step_kidnapped = [pose.copy()], [pose.copy()], [False]
    next_kidnap = 0
    k = 0
    while True:
        t0 = k * dt
        motion_over = follower.done if follower is not None else t0 >= segment_ends[-1] - 1e-9
        pending_kidnap = next_kidnap < len(kidnaps)
        if t0 >= min(limit, max_time) - 1e-9 or (math.isinf(limit) and motion_over and not pending_kidnap):
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
                if index < len(motion.segments):
                    segment = motion.segments[index]
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
    result: IntegratedMotion = (
        np.asarray(dense_times),
        np.asarray(dense_poses),
        np.asarray(step_poses),
        np.asarray(step_end),
        np.asarray(step_vel),
        np.asarray(step_kidnapped, dtype=bool),
    )
    return result
