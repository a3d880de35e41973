"""Tiny hand-made CARMEN logs: a straight corridor driven end to end, written as FLASER (and ODOM) lines."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

HALF_WIDTH = 1.025  # walls at y = +-1.025 m: the centres of 5 cm cells, so end points land mid-cell
LENGTH = 30.0  # end walls at x = 0 and x = 30 m
SENSOR_RANGE = 4.0  # farther walls give the no-return code [m]
NO_RETURN = 81.91  # what the Intel and FR101 scanners write for "nothing within range" [m]
BEAMS = 181  # 1 degree apart from -90 to +90 degrees
SPEED = 0.45  # metres between scans along the corridor


def corridor_poses(count: int, *, y: float = 0.0, start_x: float = 0.5) -> np.ndarray:
    """Laser poses ``(count, 3)`` driving along +x down the corridor's middle, ``SPEED`` m apart."""
    x = start_x + SPEED * np.arange(count)
    return np.stack([x, np.full(count, y), np.zeros(count)], axis=1)


def corridor_ranges(pose: np.ndarray, *, y_offset: float = 0.0) -> np.ndarray:
    """The ``BEAMS`` readings at ``pose`` in the corridor (shifted sideways by ``y_offset``)."""
    heading = pose[2] + np.deg2rad(np.arange(BEAMS) - 90.0)
    c, s = np.cos(heading), np.sin(heading)
    py = pose[1] - y_offset
    with np.errstate(divide="ignore", invalid="ignore"):
        candidates = np.stack([
            np.where(s > 1e-9, (HALF_WIDTH - py) / s, np.inf),
            np.where(s < -1e-9, (-HALF_WIDTH - py) / s, np.inf),
            np.where(c < -1e-9, (0.0 - pose[0]) / c, np.inf),
            np.where(c > 1e-9, (LENGTH - pose[0]) / c, np.inf),
        ])
    ranges = candidates.min(axis=0)
    return np.where(ranges > SENSOR_RANGE, NO_RETURN, ranges)


def flaser_line(ranges: Sequence[float], pose: Sequence[float], stamp: float, logger: float | None = None) -> str:
    """One FLASER line: ranges, the corrected pose twice, ipc_timestamp, host, logger_timestamp."""
    logger = stamp if logger is None else logger
    values = " ".join(f"{r:.4f}" for r in ranges)
    x, y, theta = pose
    return f"FLASER {len(ranges)} {values} {x:.6f} {y:.6f} {theta:.6f} {x:.6f} {y:.6f} {theta:.6f} {stamp!r} host {logger!r}\n"


def robotlaser_line(
    ranges: Sequence[float],
    pose: Sequence[float],
    stamp: float,
    *,
    start_angle: float = -np.pi / 2,
    fov: float = np.pi,
    resolution: float = np.pi / 180,
    remissions: Sequence[float] = (),
) -> str:
    """One ROBOTLASER1 line (CARMEN laser-new): geometry, ranges, remissions, laser and robot pose, stamps."""
    values = " ".join(f"{r:.4f}" for r in ranges)
    x, y, theta = pose
    echo = " ".join([str(len(remissions)), *(f"{e:.1f}" for e in remissions)])
    return (f"ROBOTLASER1 0 {start_angle!r} {fov!r} {resolution!r} 81.9 0.01 0 {len(ranges)} {values} {echo} "
            f"{x:.6f} {y:.6f} {theta:.6f} {x:.6f} {y:.6f} {theta:.6f} 0.3 0.0 0.55 0.375 1000000.0 "
            f"{stamp!r} host {stamp!r}\n")


def odom_line(pose: Sequence[float], stamp: float) -> str:
    x, y, theta = pose
    return f"ODOM {x:.6f} {y:.6f} {theta:.6f} 0 0 0 {stamp!r} host {stamp!r}\n"


def write_log(
    path: Path,
    poses: np.ndarray,
    *,
    stamps: Sequence[float] | None = None,
    logger_stamps: Sequence[float] | None = None,
    odom_stamps: Sequence[float] | None = None,
    ranges: Sequence[np.ndarray] | None = None,
) -> Path:
    """Write a CARMEN log of ``poses`` (stamps 10 + i / 4 s unless given); an ODOM line before each scan if asked."""
    count = len(poses)
    stamps = list(10.0 + 0.25 * np.arange(count)) if stamps is None else list(stamps)
    lines = ["# a hand-made corridor log\n"]
    for i, pose in enumerate(poses):
        if odom_stamps is not None:
            lines.append(odom_line(pose, float(odom_stamps[i])))
        readings = corridor_ranges(pose) if ranges is None else ranges[i]
        lines.append(flaser_line(readings, pose, float(stamps[i]),
                                 None if logger_stamps is None else float(logger_stamps[i])))
    path.write_text("".join(lines))
    return path
