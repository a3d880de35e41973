"""Interval Analysis Localization (IAL): guaranteed global localization with boxes.

Guyonneau, Lagrange, Hardouin & Lucidarme, "Guaranteed interval analysis
localization for mobile robots", *Advanced Robotics* 28(16), 2014
(``../shared/seeds/004_0d88fe8e59c0c187.txt``). Under stated bounds (range
error ``+- range_error``, bounded odometry, at most ``max_outliers`` readings
breaking the range bound) the true laser pose lies inside the union of the
returned boxes, every time; an empty list means kidnapping and restarts from
the whole map (section 3.2).

Algorithm 1, per scan: interval prediction of each box by the bounded
odometry step, forward-backward contraction of each box by every beam against
the map (:mod:`.kernels`) with a relaxed (q-)intersection, and bisection down
to ``min_box_width_*``. Additions, all sound: the laser stands in a free cell,
no certain obstacle before a beam's shortest range, boxes merged into hulls
before prediction.

Notes (choices where the paper is silent, status, why numba not codac,
measured figures): docs/ial.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import MapError
from ..filter.odometry_gate import MotionMeasure, OdometryGate
from ..grid_map import GridMap
from ..interval import (
    MAX_COORDINATE,
    OUTWARD,
    angle_hull,
    compose_boxes,
    interval_cos,
    interval_mul,
    interval_sin,
    normalize_angle_intervals,
)
from ..localizer import Estimate, LocalizerStatus
from ..metrics import scan_explained
from ..motion import _MIN_TRANSLATION_FOR_HEADING
from ..scan import LaserMount, Scan
from ..se2 import angle_difference, compose, inverse, wrap_angle
from .kernels import merge_boxes, pave, summed_area_table
from .settings import IALSettings

__all__ = [
    "IALSettings",
    "IntervalLocalizer",
    "ObstacleGrid",
    "IterationResult",
    "boxes_hull",
    "odometry_step_bounds",
    "beam_intervals",
]

# Relative float32 rounding of a LaserScan range: half an ulp is 2^-24, one ulp 2^-23.
_FLOAT32_RELATIVE = 2.0**-23


class ObstacleGrid:
    """The obstacle set of a map for IAL: occupied or unknown cells, with a summed-area table.

    Raises:
        MapError: the map is too large for the arithmetic error budget.
    """

    def __init__(
        self,
        grid_map: GridMap,
        *,
        margin: float = 0.0,
        laser_in_free_cells: bool = True,
        unknown_is_obstacle: bool = True,
        laser_cell_constraint: bool = True,
    ) -> None:
        x_min, x_max, y_min, y_max = grid_map.extent
        if max(abs(x_min), abs(x_max), abs(y_min), abs(y_max)) > MAX_COORDINATE:
            raise MapError(
                f"map extent {grid_map.extent!r} exceeds +-{MAX_COORDINATE:g} m, beyond IAL's rounding margin"
            )
        self.grid_map = grid_map
        self.origin = (float(grid_map.origin[0]), float(grid_map.origin[1]))
        self.resolution = float(grid_map.resolution)
        # Where a beam may end: occupied cells, and unknown ones unless they count as outliers
        # (sat_any keeps them, for the retry of a scan that leaves no box).
        self.obstacle = grid_map.occupied_mask | grid_map.unknown_mask
        self.sat_any = summed_area_table(self.obstacle)
        if not unknown_is_obstacle:
            self.obstacle = grid_map.occupied_mask
        self.sat = self.sat_any if unknown_is_obstacle else summed_area_table(self.obstacle)
        # Where the laser may stand: free cells, or any cell not marked occupied, or (the paper) any cell.
        if not laser_cell_constraint:
            stand = np.ones(grid_map.occupied_mask.shape, dtype=bool)
        else:
            stand = grid_map.free_mask if laser_in_free_cells else ~grid_map.occupied_mask
        self.free_sat = summed_area_table(stand)
        # Cells surely inside an obstacle: occupied cells eroded by twice the map margin.
        occupied = grid_map.occupied_mask
        erosion = int(math.ceil(2.0 * margin / self.resolution - 1e-9)) if margin > 0.0 else 0
        if erosion > 0:
            # Erosion by a (2e + 1)^2 square, off-map cells not occupied: the window is full of occupied cells.
            window = summed_area_table(np.pad(occupied, erosion))
            side = 2 * erosion + 1
            count = window[side:, side:] - window[:-side, side:] - window[side:, :-side] + window[:-side, :-side]
            occupied = count == side * side
        self.certain_sat = summed_area_table(occupied)
        self.extent = (x_min, x_max, y_min, y_max)

    def whole_map_box(self) -> NDArray[np.float64]:
        """``(1, 6)``: every position of the map, every heading (the paper's ``L_0``)."""
        x_min, x_max, y_min, y_max = self.extent
        return np.array([[x_min, x_max, y_min, y_max, -math.pi, math.pi]])


def beam_intervals(
    scan: Scan, *, range_error: float, max_beams: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(angles, range_lo, range_hi)`` of the valid readings used, at most ``max_beams`` of them.

    Readings outside ``[range_min, range_max)``, NaN and inf are dropped before
    they become intervals; the rest are picked evenly. Each interval is
    ``reading +- (range_error + float32 rounding)``, clipped at 0.
    """
    angles, ranges = scan.hits()
    positive = ranges > 0.0
    angles, ranges = angles[positive], ranges[positive]
    if ranges.size > max_beams:
        index = np.unique(np.round(np.linspace(0, ranges.size - 1, max_beams)).astype(np.int64))
        angles, ranges = angles[index], ranges[index]
    pad = range_error + ranges * _FLOAT32_RELATIVE + OUTWARD
    return (
        np.ascontiguousarray(angles, dtype=np.float64),
        np.maximum(ranges - pad, 0.0),
        ranges + pad,
    )


def boxes_hull(boxes: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(6,)`` hull of boxes ``(K, 6)``; the heading part is the shortest arc covering them all."""
    theta_lo, theta_hi = angle_hull(boxes[:, 4], boxes[:, 5])
    return np.array(
        [boxes[:, 0].min(), boxes[:, 1].max(), boxes[:, 2].min(), boxes[:, 3].max(), theta_lo, theta_hi]
    )


def odometry_step_bounds(
    previous: ArrayLike,
    current: ArrayLike,
    *,
    relative_translation: float,
    absolute_translation: float,
    relative_rotation: float,
    absolute_rotation: float,
    rotation_per_translation: float = 0.0,
    translation_per_rotation: float = 0.0,
) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float], bool]:
    """Bounds of the true ``rot1, trans, rot2`` of one odometry step, and whether its direction is known.

    The stated bound (docs/ial.md, "Odometry"): the odometry realises the true
    decomposition (``rot1 = 0`` below 1 cm, as :func:`odometry_delta`) with errors

    - ``|e_rot_i| <= relative_rotation |rot_i| + rotation_per_translation trans + absolute_rotation``,
    - ``|e_trans| <= relative_translation trans + translation_per_rotation (|rot1| + |rot2|)
      + absolute_translation``.

    The simulator's bounded odometry draws each component so (without the cross
    terms). Thrun's and nav2's Gaussian model scales its noise by the distance of
    a rotation to 0 or pi, never more than ``|rot|``, and its realised translation
    may come out negative (the measured step then points backwards, ``rot1`` and
    ``rot2`` shifted by pi); ``|rot_i| <= |measured_i| + |e_rot_i|`` then bounds the
    noise scale, and ``trans <= measured + |e_trans|`` holds either way. Solving
    the two bounds for the errors gives the intervals below; with the cross terms
    at 0 they are ``m +- (relative |m| + absolute) / (1 - relative)``. The step is
    decomposed without the 1 cm threshold; when the true translation may be
    under 1 cm its direction is reported unknown (the true ``rot1`` is then 0
    whatever the direction of travel; ``rot1 + rot2`` still bounds the heading).
    """
    previous = np.asarray(previous, dtype=np.float64)
    current = np.asarray(current, dtype=np.float64)
    dx, dy = current[0] - previous[0], current[1] - previous[1]
    trans = math.hypot(dx, dy)
    rot1 = float(angle_difference(math.atan2(dy, dx), previous[2])) if trans > 0.0 else 0.0
    rot2 = float(angle_difference(angle_difference(current[2], previous[2]), rot1))
    size1, size2 = abs(rot1), abs(rot2)
    # |e_trans| bound from the linear system of the two stated bounds (settings.validate: denominator > 0).
    rho = 1.0 / (1.0 - relative_rotation)
    trans_error = (
        relative_translation * trans
        + translation_per_rotation * rho * (size1 + size2)
        + 2.0 * translation_per_rotation * rho * (rotation_per_translation * trans + absolute_rotation)
        + absolute_translation
    ) / (1.0 - relative_translation - 2.0 * translation_per_rotation * rho * rotation_per_translation)
    trans_max = trans + trans_error

    def rotation_bounds(value: float, size: float) -> tuple[float, float]:
        half = (relative_rotation * size + rotation_per_translation * trans_max + absolute_rotation) / (
            1.0 - relative_rotation
        ) + OUTWARD
        return value - half, value + half

    trans_bounds = (max(trans - trans_error - OUTWARD, 0.0), trans_max + OUTWARD)
    direction_known = trans_bounds[0] >= _MIN_TRANSLATION_FOR_HEADING
    return rotation_bounds(rot1, size1), trans_bounds, rotation_bounds(rot2, size2), direction_known


@dataclass
class IterationResult:
    """What one run of Algorithm 1 produced (before it becomes an :class:`Estimate`)."""

    boxes: NDArray[np.float64]
    consistent_beams: NDArray[np.int64]
    contractions: int
    limited: bool


class IntervalLocalizer:
    """Guaranteed localization by interval analysis (:class:`Localizer` and :class:`GlobalFixer`).

    Args:
        settings: :class:`IALSettings`.
        grid_map: the map, or None to wait for :meth:`set_map`.
    """

    def __init__(self, settings: IALSettings | None = None, grid_map: GridMap | None = None) -> None:
        self.settings = settings or IALSettings()
        self.mount = LaserMount()
        self.obstacles: ObstacleGrid | None = None
        # None: localize globally (whole map) at the next scan.
        self.boxes: NDArray[np.float64] | None = None
        # Base-frame odometry: the steps since the last scan and the path since the last update.
        self.odometry = OdometryGate(
            self.settings.update_min_d, self.settings.update_min_a, measure=MotionMeasure.PATH, keep_steps=True
        )
        self._updates = 0
        # Updates since the list last emptied (settle_updates); None: not since the start or initialpose.
        self._since_emptied: int | None = None
        if grid_map is not None:
            self.set_map(grid_map)

    # -- Localizer protocol -----------------------------------------------------------
    def set_laser_mount(self, mount: LaserMount) -> None:
        """The laser's pose on the base: the odometry bounds describe the base's motion (paper 5.2)."""
        self.mount = mount

    def set_map(self, grid_map: GridMap) -> None:
        self.obstacles = ObstacleGrid(
            grid_map,
            margin=self.settings.map_margin,
            laser_in_free_cells=self.settings.laser_in_free_cells,
            unknown_is_obstacle=self.settings.unknown_is_obstacle,
            laser_cell_constraint=self.settings.laser_cell_constraint,
        )
        self.reinitialize()

    def on_odometry(self, stamp: float, odom_pose: NDArray[np.float64]) -> None:
        """Record odometry; non-finite or older poses are ignored."""
        pose = np.asarray(odom_pose, dtype=np.float64)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            return
        if self.mount.pose.any():
            pose = compose(pose, inverse(self.mount.pose))  # the bounds describe the base's motion
        self.odometry.add(stamp, pose)

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        s = self.settings
        pose = np.asarray(pose, dtype=np.float64)
        covariance = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
        sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        half = s.initial_pose_sigmas * sigma
        half[:2] = np.maximum(half[:2], s.initial_min_half_width_xy)
        half[2] = min(max(half[2], s.initial_min_half_width_theta), math.pi)
        theta = float(wrap_angle(pose[2]))
        self.boxes = np.array([[pose[0] - half[0], pose[0] + half[0], pose[1] - half[1], pose[1] + half[1],
                                theta - half[2], theta + half[2]]])
        self._since_emptied = None  # a prior the user gives is not a set that just emptied
        self.odometry.take_steps()  # the box is where the robot is now
        self.odometry.request_update()

    def reinitialize(self) -> None:
        self.boxes = None
        self._since_emptied = None
        self.odometry.take_steps()
        self.odometry.request_update()

    def request_nomotion_update(self) -> None:
        self.odometry.request_update()

    def on_scan(self, scan: Scan) -> Estimate | None:
        if self.obstacles is None:
            return None
        s = self.settings
        steps = self.odometry.take_steps()
        previous = self.boxes
        tracking = previous is not None
        if previous is not None and not self.odometry.due():
            self.boxes = self.predict(previous, steps)
            return None
        self.odometry.mark_updated(self.odometry.latest)
        self._updates += 1
        angles, range_lo, range_hi = beam_intervals(scan, range_error=s.range_error, max_beams=s.max_beams)
        details: dict[str, Any] = {"valid_beams": int(angles.size), "restarted": False}

        if previous is not None:
            boxes = previous
            if len(boxes) > 1 and angles.size >= s.max_outliers + 1:
                # Leaves of the last iteration grouped into hulls, before odometry widens them.
                boxes = merge_boxes(boxes, np.array([s.merge_width_xy, s.merge_width_xy, s.merge_width_theta]))
                boxes[:, 4], boxes[:, 5] = normalize_angle_intervals(boxes[:, 4], boxes[:, 5])
            boxes = self.predict(boxes, steps)
        else:
            boxes = self.obstacles.whole_map_box()
        if angles.size < s.max_outliers + 1:
            details["warning"] = (
                f"{angles.size} valid readings, fewer than max_outliers + 1 = {s.max_outliers + 1}: "
                "boxes left uncontracted"
            )
            self.boxes = boxes if tracking else None
            consistent = np.zeros(len(boxes), dtype=np.int64)
            status = LocalizerStatus.LOST if len(boxes) == 0 else None
            return self._estimate(scan.stamp, boxes, consistent, details, status, contracted=False)

        result = self.iterate(boxes, angles, range_lo, range_hi)
        contractions = result.contractions
        status = None
        details["outliers_retried"] = False
        if len(result.boxes) == 0 and tracking and s.max_outliers_retry > s.max_outliers:
            # More outliers than max_outliers in this scan, readings into unknown space, or a kidnapping:
            # the same boxes under the looser bound (and unknown cells as possible ends).
            details["outliers_retried"] = True
            result = self.iterate(boxes, angles, range_lo, range_hi, max_outliers=s.max_outliers_retry,
                                  unknown_is_obstacle=True)
            contractions += result.contractions
        if len(result.boxes) == 0 and tracking:
            # Section 3.2: an empty list means kidnapping (or lost): restart over the whole map.
            details["restarted"] = True
            result = self.iterate(self.obstacles.whole_map_box(), angles, range_lo, range_hi)
            contractions += result.contractions
            status = LocalizerStatus.LOST
        if len(result.boxes) == 0:
            status = LocalizerStatus.LOST
            details["restarted"] = True
        if details["restarted"]:
            self._since_emptied = 0
        elif self._since_emptied is not None:
            self._since_emptied += 1
        settled = self._since_emptied is None or self._since_emptied >= s.settle_updates
        if self._since_emptied is not None:
            details["updates_since_emptied"] = self._since_emptied
        details["contractions"] = contractions
        details["limited"] = result.limited
        self.boxes = result.boxes if len(result.boxes) else None
        return self._assumption_checked(scan, self._estimate(scan.stamp, result.boxes, result.consistent_beams,
                                                             details, status, contracted=True, settled=settled))

    # -- GlobalFixer protocol ---------------------------------------------------------
    def global_fix(self, scan: Scan) -> Estimate:
        """One global iteration from the whole map; the tracking state is left untouched."""
        if self.obstacles is None:
            raise MapError("IAL global_fix needs a map: call set_map first")
        s = self.settings
        angles, range_lo, range_hi = beam_intervals(scan, range_error=s.range_error, max_beams=s.max_beams)
        details: dict[str, Any] = {"valid_beams": int(angles.size), "restarted": False}
        if angles.size < s.max_outliers + 1:
            details["warning"] = (
                f"{angles.size} valid readings, fewer than max_outliers + 1 = {s.max_outliers + 1}: "
                "boxes left uncontracted"
            )
            boxes = self.obstacles.whole_map_box()
            return self._estimate(scan.stamp, boxes, np.zeros(1, dtype=np.int64), details, None,
                                  contracted=False, best_first=True)
        result = self.iterate(self.obstacles.whole_map_box(), angles, range_lo, range_hi)
        details["contractions"] = result.contractions
        details["limited"] = result.limited
        status = LocalizerStatus.LOST if len(result.boxes) == 0 else None
        return self._assumption_checked(scan, self._estimate(scan.stamp, result.boxes, result.consistent_beams,
                                                             details, status, contracted=True, best_first=True))

    def _assumption_checked(self, scan: Scan, estimate: Estimate) -> Estimate:
        """A LOCALIZED ``estimate`` stays LOCALIZED only where the map explains, at its pose, the share of the scan
        the bounds assume (``localized_needs_explained_scan``; docs/ial.md, "The assumption at the estimate")."""
        s = self.settings
        if estimate.status is not LocalizerStatus.LOCALIZED or not s.localized_needs_explained_scan:
            return estimate
        assert self.obstacles is not None
        explained = float(scan_explained(self.obstacles.grid_map, estimate.pose[None, :], scan)[0])
        details = {**estimate.details, "explained": round(explained, 4)}
        status = LocalizerStatus.LOCALIZED if explained >= details["explained_needed"] else LocalizerStatus.AMBIGUOUS
        return replace(estimate, status=status, details=details)

    # -- the algorithm ----------------------------------------------------------------
    def predict(
        self, boxes: NDArray[np.float64], steps: list[tuple[NDArray[np.float64], NDArray[np.float64]]]
    ) -> NDArray[np.float64]:
        """Line 4: move laser-pose boxes ``(K, 6)`` through each base odometry step, by interval evaluation.

        With a laser mount, the boxes are moved to the base frame, predicted with
        the base odometry (which the bounds describe), and moved back, outward.
        """
        s = self.settings
        mount = self.mount.pose
        boxes = compose_boxes(boxes, inverse(mount)) if steps else np.array(boxes, dtype=np.float64, copy=True)
        for previous, current in steps:
            rot1, trans, rot2, direction_known = odometry_step_bounds(
                previous,
                current,
                relative_translation=s.odom_relative_translation,
                absolute_translation=s.odom_absolute_translation,
                relative_rotation=s.odom_relative_rotation,
                absolute_rotation=s.odom_absolute_rotation,
                rotation_per_translation=s.odom_rotation_per_translation,
                translation_per_rotation=s.odom_translation_per_rotation,
            )
            if direction_known:
                travel_lo = boxes[:, 4] + rot1[0] - OUTWARD
                travel_hi = boxes[:, 5] + rot1[1] + OUTWARD
                c_lo, c_hi = interval_cos(travel_lo, travel_hi)
                s_lo, s_hi = interval_sin(travel_lo, travel_hi)
                dx_lo, dx_hi = interval_mul(trans[0], trans[1], c_lo, c_hi)
                dy_lo, dy_hi = interval_mul(trans[0], trans[1], s_lo, s_hi)
            else:
                # Any direction of travel, at most the largest possible translation.
                dx_lo = dy_lo = np.full(len(boxes), -trans[1])
                dx_hi = dy_hi = np.full(len(boxes), trans[1])
            boxes[:, 0] += dx_lo - OUTWARD
            boxes[:, 1] += dx_hi + OUTWARD
            boxes[:, 2] += dy_lo - OUTWARD
            boxes[:, 3] += dy_hi + OUTWARD
            boxes[:, 4], boxes[:, 5] = normalize_angle_intervals(
                boxes[:, 4] + rot1[0] + rot2[0] - 2 * OUTWARD, boxes[:, 5] + rot1[1] + rot2[1] + 2 * OUTWARD
            )
        if steps:
            boxes = compose_boxes(boxes, mount)
        if self.obstacles is not None:
            x_min, x_max, y_min, y_max = self.obstacles.extent
            boxes[:, 0] = np.maximum(boxes[:, 0], x_min)
            boxes[:, 1] = np.minimum(boxes[:, 1], x_max)
            boxes[:, 2] = np.maximum(boxes[:, 2], y_min)
            boxes[:, 3] = np.minimum(boxes[:, 3], y_max)
            boxes = boxes[(boxes[:, 0] <= boxes[:, 1]) & (boxes[:, 2] <= boxes[:, 3])]
        return boxes

    def iterate(
        self,
        boxes: NDArray[np.float64],
        angles: NDArray[np.float64],
        range_lo: NDArray[np.float64],
        range_hi: NDArray[np.float64],
        *,
        max_outliers: int | None = None,
        unknown_is_obstacle: bool | None = None,
    ) -> IterationResult:
        """Lines 2-12 of Algorithm 1 on already predicted boxes: contract, bisect, keep non-empty.

        ``max_outliers`` and ``unknown_is_obstacle`` default to the settings' (the retry loosens both).
        """
        if self.obstacles is None:
            raise MapError("IAL needs a map: call set_map first")
        s = self.settings
        grid = self.obstacles
        allowed = s.max_outliers if max_outliers is None else max_outliers
        max_outliers = min(allowed, max(int(angles.size) - 1, 0))
        out, consistent, contractions, limited = pave(
            np.ascontiguousarray(boxes, dtype=np.float64),
            np.ascontiguousarray(angles, dtype=np.float64),
            np.ascontiguousarray(range_lo, dtype=np.float64),
            np.ascontiguousarray(range_hi, dtype=np.float64),
            max_outliers,
            grid.sat_any if unknown_is_obstacle else grid.sat,
            grid.free_sat,
            grid.certain_sat,
            int(s.free_space_samples),
            grid.origin[0],
            grid.origin[1],
            grid.resolution,
            float(s.map_margin),
            np.array([s.min_box_width_xy, s.min_box_width_xy, s.min_box_width_theta]),
            int(s.contraction_passes),
            float(s.min_contraction_gain),
            int(s.max_boxes),
            int(s.max_contractions),
        )
        out[:, 4], out[:, 5] = normalize_angle_intervals(out[:, 4], out[:, 5])
        return IterationResult(out, consistent, int(contractions), bool(limited))

    # -- outputs ----------------------------------------------------------------------
    def _estimate(
        self,
        stamp: float,
        boxes: NDArray[np.float64],
        consistent: NDArray[np.int64],
        details: dict[str, Any],
        status: LocalizerStatus | None,
        *,
        contracted: bool,
        best_first: bool = False,
        settled: bool = True,
    ) -> Estimate:
        s = self.settings
        details["box_count"] = int(len(boxes))
        # The share of a scan its bound assumes the map explains at the true pose (the benchmark splits by it).
        details["explained_needed"] = round(1.0 - s.max_outliers / s.max_beams, 4)
        if len(boxes) == 0:
            details.update(hull_width_x=0.0, hull_width_y=0.0, hull_width_theta=0.0)
            return Estimate(stamp, np.full(3, np.nan), np.full((3, 3), np.nan), LocalizerStatus.LOST,
                            np.zeros((0, 3)), np.zeros(0), boxes=np.zeros((0, 3, 2)), details=details)
        hull = boxes_hull(boxes)
        widths = hull[1::2] - hull[0::2]
        details.update(hull_width_x=float(widths[0]), hull_width_y=float(widths[1]),
                       hull_width_theta=float(widths[2]))
        volume = np.prod(boxes[:, 1::2] - boxes[:, 0::2], axis=1)
        order = np.lexsort((volume, -consistent))
        centres = 0.5 * (boxes[order, 0::2] + boxes[order, 1::2])
        centres[:, 2] = wrap_angle(centres[:, 2])
        weights = consistent[order] / max(int(details.get("valid_beams", 1)), 1)
        if best_first:
            pose = centres[0].copy()
        else:
            pose = 0.5 * (hull[0::2] + hull[1::2])
            pose[2] = wrap_angle(pose[2])
        covariance = np.diag(np.maximum(widths, 1e-9) ** 2 / 12.0)
        if status is None:
            if not contracted:
                status = LocalizerStatus.INITIALIZING if self.boxes is None else LocalizerStatus.AMBIGUOUS
            elif widths[0] <= s.localized_width_xy and widths[1] <= s.localized_width_xy and (
                widths[2] <= s.localized_width_theta
            ) and settled:
                status = LocalizerStatus.LOCALIZED
            else:
                status = LocalizerStatus.AMBIGUOUS
        return Estimate(stamp, pose, covariance, status, centres, weights.astype(np.float64),
                        boxes=boxes[order].reshape(-1, 3, 2), details=details)
