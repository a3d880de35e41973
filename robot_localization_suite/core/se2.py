"""SE(2) helpers: the one angle wrap and the pose algebra every module shares.

Poses are arrays ``(..., 3)`` holding ``x`` [m], ``y`` [m], ``theta`` [rad]
(REP 103: counter-clockwise positive). All functions broadcast over leading
axes so that a particle cloud is handled like a single pose.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "wrap_angle",
    "compose",
    "inverse",
    "relative",
    "transform_points",
    "angle_difference",
    "yaw_to_quaternion",
    "quaternion_to_yaw",
]


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to ``[-pi, pi)`` [rad]."""
    wrapped = np.mod(np.asarray(angle, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def angle_difference(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64] | float:
    """Signed smallest difference ``a - b`` wrapped to ``[-pi, pi)``."""
    return wrap_angle(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))


def compose(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """``a (+) b``: pose ``b`` expressed in frame ``a``, returned in ``a``'s parent frame."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.float64)
    out[..., 0] = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    out[..., 1] = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    out[..., 2] = wrap_angle(a[..., 2] + b[..., 2])
    return out


def inverse(a: ArrayLike) -> NDArray[np.float64]:
    """``(-) a``: the inverse transform."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty_like(a)
    out[..., 0] = -c * a[..., 0] - s * a[..., 1]
    out[..., 1] = s * a[..., 0] - c * a[..., 1]
    out[..., 2] = wrap_angle(-a[..., 2])
    return out


def relative(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """``(-) a (+) b``: pose ``b`` seen from pose ``a``."""
    return compose(inverse(a), b)


def transform_points(pose: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Map points ``(..., 2)`` from the frame at ``pose`` (shape ``(3,)``) to its parent frame."""
    pose = np.asarray(pose, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    out = np.empty_like(points)
    out[..., 0] = pose[0] + c * points[..., 0] - s * points[..., 1]
    out[..., 1] = pose[1] + s * points[..., 0] + c * points[..., 1]
    return out


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(x, y, z, w)`` of a rotation by ``yaw`` about z."""
    return 0.0, 0.0, float(np.sin(yaw / 2.0)), float(np.cos(yaw / 2.0))


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Yaw [rad] of a quaternion (roll and pitch ignored, as for a planar robot)."""
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))
