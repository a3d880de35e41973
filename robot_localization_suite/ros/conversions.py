"""Message <-> array conversions: one small function per message type.

Readers accept any object with the message's fields (rclpy messages and
rosbags' deserialised dataclasses alike); builders return rclpy messages.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Pose, PoseArray, PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from numpy.typing import NDArray
from sensor_msgs.msg import Image, LaserScan
from std_msgs.msg import Header

from ..core.errors import ScanError
from ..core.grid_map import GridMap
from ..core.localizer import Estimate, LocalizerStatus
from ..core.scan import Scan
from ..core.se2 import quaternion_to_yaw, yaw_to_quaternion

__all__ = [
    "stamp_to_seconds",
    "seconds_to_stamp",
    "scan_from_msg",
    "scan_to_msg",
    "pose_from_pose_msg",
    "pose_to_pose_msg",
    "odometry_from_msg",
    "odometry_to_msg",
    "grid_map_from_msg",
    "grid_map_to_msg",
    "initial_pose_from_msg",
    "initial_pose_to_msg",
    "estimate_to_pose_msg",
    "estimate_to_pose_array",
    "estimate_to_diagnostics",
    "image_from_msg",
    "image_to_msg",
]


def stamp_to_seconds(stamp: Any) -> float:
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def seconds_to_stamp(seconds: float) -> Time:
    nanoseconds = int(round(seconds * 1e9))
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def _header(seconds: float, frame_id: str) -> Header:
    return Header(stamp=seconds_to_stamp(seconds), frame_id=frame_id)


# -- LaserScan ------------------------------------------------------------------
def scan_from_msg(msg: Any) -> Scan:
    """``sensor_msgs/LaserScan`` -> :class:`Scan`. Raises :class:`ScanError` on unusable geometry."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    if ranges.size == 0:
        raise ScanError("LaserScan has no ranges")
    angle_min, increment, angle_max = float(msg.angle_min), float(msg.angle_increment), float(msg.angle_max)
    expected = angle_min + (ranges.size - 1) * increment
    # One increment of slack: some drivers report the end of the last beam's sector.
    if math.isfinite(angle_max) and math.isfinite(expected) and abs(angle_max - expected) > abs(increment) + 1e-4:
        raise ScanError(
            f"LaserScan angle_max {angle_max!r} disagrees with angle_min {angle_min!r} + ({ranges.size} - 1) x "
            f"angle_increment {increment!r} = {expected!r}"
        )
    return Scan.from_laser_fields(
        stamp=stamp_to_seconds(msg.header.stamp),
        angle_min=float(msg.angle_min),
        angle_increment=float(msg.angle_increment),
        ranges=ranges,
        range_min=float(msg.range_min),
        range_max=float(msg.range_max),
    )


def scan_to_msg(
    seconds: float,
    frame_id: str,
    *,
    angle_min: float,
    angle_increment: float,
    ranges: NDArray[np.floating],
    range_min: float,
    range_max: float,
    scan_time: float = 0.0,
) -> LaserScan:
    msg = LaserScan()
    msg.header = _header(seconds, frame_id)
    msg.angle_min = float(angle_min)
    msg.angle_increment = float(angle_increment)
    msg.angle_max = float(angle_min + angle_increment * (len(ranges) - 1))
    msg.time_increment = 0.0
    msg.scan_time = float(scan_time)
    msg.range_min = float(range_min)
    msg.range_max = float(range_max)
    msg.ranges = np.asarray(ranges, dtype=np.float32).tolist()
    return msg


# -- Pose, Odometry -------------------------------------------------------------
def pose_from_pose_msg(pose: Any) -> NDArray[np.float64]:
    q = pose.orientation
    return np.array([pose.position.x, pose.position.y, quaternion_to_yaw(q.x, q.y, q.z, q.w)])


def pose_to_pose_msg(pose: NDArray[np.float64]) -> Pose:
    msg = Pose()
    msg.position.x, msg.position.y = float(pose[0]), float(pose[1])
    qx, qy, qz, qw = yaw_to_quaternion(float(pose[2]))
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = qx, qy, qz, qw
    return msg


def odometry_from_msg(msg: Any) -> tuple[float, NDArray[np.float64]]:
    """``nav_msgs/Odometry`` -> ``(stamp [s], pose (3,))``; also ``geometry_msgs/PoseWithCovarianceStamped`` and
    ``PoseStamped`` (a ground truth from motion capture or from another localizer)."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    return stamp_to_seconds(msg.header.stamp), pose_from_pose_msg(pose)


def odometry_to_msg(
    seconds: float,
    pose: NDArray[np.float64],
    *,
    frame_id: str,
    child_frame_id: str = "base_link",
    velocity: tuple[float, float] = (0.0, 0.0),
) -> Odometry:
    msg = Odometry()
    msg.header = _header(seconds, frame_id)
    msg.child_frame_id = child_frame_id
    msg.pose.pose = pose_to_pose_msg(pose)
    msg.twist.twist.linear.x = float(velocity[0])
    msg.twist.twist.angular.z = float(velocity[1])
    return msg


def _covariance_6x6(cov3: NDArray[np.float64]) -> list[float]:
    """A 3x3 (x, y, yaw) covariance in the 6x6 row-major layout of ROS messages."""
    full = np.zeros((6, 6))
    index = [0, 1, 5]
    full[np.ix_(index, index)] = cov3
    return full.reshape(-1).tolist()


def _covariance_3x3(cov6: Any) -> NDArray[np.float64]:
    full = np.asarray(cov6, dtype=np.float64).reshape(6, 6)
    index = [0, 1, 5]
    return full[np.ix_(index, index)]


def initial_pose_from_msg(msg: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``geometry_msgs/PoseWithCovarianceStamped`` -> ``(pose (3,), covariance (3, 3))``."""
    return pose_from_pose_msg(msg.pose.pose), _covariance_3x3(msg.pose.covariance)


def initial_pose_to_msg(
    seconds: float, pose: NDArray[np.float64], covariance: NDArray[np.float64], frame_id: str = "map"
) -> PoseWithCovarianceStamped:
    """``(pose (3,), covariance (3, 3))`` -> ``geometry_msgs/PoseWithCovarianceStamped``."""
    msg = PoseWithCovarianceStamped()
    msg.header = _header(seconds, frame_id)
    msg.pose.pose = pose_to_pose_msg(pose)
    msg.pose.covariance = _covariance_6x6(np.asarray(covariance, dtype=np.float64))
    return msg


# -- OccupancyGrid --------------------------------------------------------------
def grid_map_from_msg(msg: Any) -> GridMap:
    """``nav_msgs/OccupancyGrid`` -> :class:`GridMap` (raises ``MapError`` on inconsistent fields)."""
    q = msg.info.origin.orientation
    return GridMap.from_occupancy_grid(
        width=int(msg.info.width),
        height=int(msg.info.height),
        resolution=float(msg.info.resolution),
        origin_x=float(msg.info.origin.position.x),
        origin_y=float(msg.info.origin.position.y),
        origin_yaw=quaternion_to_yaw(q.x, q.y, q.z, q.w),
        data=np.asarray(msg.data, dtype=np.int8),
    )


def grid_map_to_msg(grid_map: GridMap, seconds: float) -> OccupancyGrid:
    msg = OccupancyGrid()
    msg.header = _header(seconds, "map")
    msg.info.map_load_time = seconds_to_stamp(seconds)
    msg.info.resolution = float(grid_map.resolution)
    msg.info.width, msg.info.height = grid_map.width, grid_map.height
    msg.info.origin.position.x, msg.info.origin.position.y = grid_map.origin
    msg.info.origin.orientation.w = 1.0
    msg.data = grid_map.data.reshape(-1).astype(np.int8).tolist()
    return msg


# -- Image ----------------------------------------------------------------------
_ENCODINGS = {"mono8": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}


def image_from_msg(msg: Any) -> NDArray[np.uint8]:
    """``sensor_msgs/Image`` -> grey ``(H, W)`` uint8. Raises ``ValueError`` naming a bad encoding or size."""
    encoding = str(msg.encoding).lower()
    if encoding not in _ENCODINGS:
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (supported: {sorted(_ENCODINGS)})")
    channels = _ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if height <= 0 or width <= 0 or step < width * channels or raw.size < height * step:
        raise ValueError(f"image of {width!r} x {height!r} ({encoding}, step {step!r}) carries {raw.size} bytes")
    pixels = raw[: height * step].reshape(height, step)[:, : width * channels].reshape(height, width, channels)
    if channels == 1:
        return pixels[:, :, 0].copy()
    rgb = pixels[:, :, :3].astype(np.float32)
    if encoding.startswith("bgr"):
        rgb = rgb[:, :, ::-1]
    grey = rgb @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def image_to_msg(seconds: float, frame_id: str, pixels: NDArray[np.uint8]) -> Image:
    """A ``(H, W)`` grey (mono8) or ``(H, W, 3)`` (rgb8) array as ``sensor_msgs/Image``."""
    pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
    msg = Image()
    msg.header = _header(seconds, frame_id)
    msg.height, msg.width = int(pixels.shape[0]), int(pixels.shape[1])
    channels = 1 if pixels.ndim == 2 else int(pixels.shape[2])
    msg.encoding = "mono8" if channels == 1 else "rgb8"
    msg.is_bigendian = 0
    msg.step = msg.width * channels
    msg.data = pixels.tobytes()
    return msg


# -- Localizer outputs ----------------------------------------------------------
def estimate_to_pose_msg(estimate: Estimate, frame_id: str = "map") -> PoseWithCovarianceStamped:
    return initial_pose_to_msg(estimate.stamp, estimate.pose, estimate.covariance, frame_id)


def estimate_to_pose_array(estimate: Estimate, frame_id: str = "map", max_poses: int = 5000) -> PoseArray:
    msg = PoseArray()
    msg.header = _header(estimate.stamp, frame_id)
    msg.poses = [pose_to_pose_msg(p) for p in estimate.candidates[:max_poses]]
    return msg


_LEVELS = {
    LocalizerStatus.LOCALIZED: DiagnosticStatus.OK,
    LocalizerStatus.INITIALIZING: DiagnosticStatus.WARN,
    LocalizerStatus.AMBIGUOUS: DiagnosticStatus.WARN,
    LocalizerStatus.LOST: DiagnosticStatus.ERROR,
}


def estimate_to_diagnostics(estimate: Estimate, node_name: str, update_ms: float) -> DiagnosticArray:
    status = DiagnosticStatus()
    status.level = _LEVELS[estimate.status]
    status.name = f"{node_name}: localization"
    status.message = estimate.status.value
    status.hardware_id = node_name
    values = {"candidates": len(estimate.candidates), "update_ms": f"{update_ms:.2f}"}
    for key, value in estimate.details.items():
        if isinstance(value, (int, float, str, bool, np.integer, np.floating)):
            values[key] = value
    status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    msg = DiagnosticArray()
    msg.header = _header(estimate.stamp, "")
    msg.status = [status]
    return msg


def progress_diagnostics(seconds: float, node_name: str, what: str, percent: float | None) -> DiagnosticArray:
    """INITIALIZING diagnostics while a node precomputes: what it does and the percent done."""
    status = DiagnosticStatus()
    status.level = _LEVELS[LocalizerStatus.INITIALIZING]
    status.name = f"{node_name}: localization"
    status.message = LocalizerStatus.INITIALIZING.value
    status.hardware_id = node_name
    values = {"preparing": what, "progress_percent": "" if percent is None else f"{percent:.1f}"}
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    msg = DiagnosticArray()
    msg.header = _header(seconds, "")
    msg.status = [status]
    return msg
