"""``ial_localizer``: guaranteed interval-analysis localization (Guyonneau et al. 2014) as a ROS 2 node.

The node is the shared
:class:`~robot_localization_suite.nodes.localizer_node.LocalizerNode`; this
module lists the parameters, copies them into
:class:`~robot_localization_suite.core.ial.IALSettings` (which documents units,
defaults and their sources) and draws the boxes on ``~/boxes``
(visualization_msgs/MarkerArray): each box's x-y rectangle, its heading range
as two rays from the box centre, and the hull of all boxes.

Outputs besides the common ones: ``~/pose`` is the hull centre with the hull's
covariance, ``~/candidates`` the box centres, ``/diagnostics`` the box count
and hull size (``box_count``, ``hull_width_x``, ``hull_width_y``,
``hull_width_theta``) and LOST when the list empties (a kidnapping: IAL then
restarts over the whole map).
"""

from __future__ import annotations

import math
import sys
from dataclasses import fields
from typing import Any

import numpy as np
from geometry_msgs.msg import Point
from visualization_msgs.msg import Marker, MarkerArray

from ..core.ial.localizer import IALSettings, IntervalLocalizer
from ..core.localizer import Estimate
from ..core.scan import LaserMount
from ..ros.conversions import seconds_to_stamp
from .common import ParamSpec
from .localizer_node import localizer_node_main

__all__ = ["NODE_NAME", "DESCRIPTION", "PARAMS", "EXTRAS", "make_localizer", "build_extras", "main"]

NODE_NAME = "ial_localizer"
DESCRIPTION = (
    "Guaranteed localization by interval analysis (Guyonneau et al., Advanced Robotics 2014): boxes of poses "
    "predicted with bounded odometry, contracted by every beam against the grid map with a relaxed intersection "
    "that tolerates max_outliers readings, bisected down to min_box_width; under the stated bounds the true pose "
    "is inside the published boxes, and an empty list (kidnapping) restarts over the whole map."
)

_D = IALSettings()

PARAMS = (
    ParamSpec("range_error", _D.range_error, "eps_y: bound of a range reading's error [m] (paper: 0.05)", 0.0, 10.0),
    ParamSpec("max_outliers", _D.max_outliers, "n_o: readings allowed to break range_error (paper: 5 of 36)", 0, 100_000),
    ParamSpec("max_beams", _D.max_beams, "valid readings used per scan, evenly spaced (paper: 36)", 1, 100_000),
    ParamSpec("min_box_width_xy", _D.min_box_width_xy, "xi for x and y: bisect while a box is wider [m]", 1e-4, 100.0),
    ParamSpec("min_box_width_theta", _D.min_box_width_theta, "xi for the heading: bisect while wider [rad]", 1e-5, 6.28),
    ParamSpec("map_margin", _D.map_margin,
              "a beam may end this far from an occupied cell [m]: 0 for simulated maps, about a cell for SLAM maps",
              0.0, 10.0),
    ParamSpec("free_space_samples", _D.free_space_samples,
              "points before each beam's end that must not be inside certain obstacles (0: off)", 0, 64),
    ParamSpec("laser_in_free_cells", _D.laser_in_free_cells,
              "the laser stands in a cell the map marks free; false: in any cell not marked occupied"),
    ParamSpec("odom_relative_translation", _D.odom_relative_translation,
              "odometry bound: translation error per step, relative part (paper: 0.1)", 0.0, 0.99),
    ParamSpec("odom_absolute_translation", _D.odom_absolute_translation,
              "odometry bound: translation error per step, absolute part [m]", 0.0, 10.0),
    ParamSpec("odom_relative_rotation", _D.odom_relative_rotation,
              "odometry bound: rotation error per step, relative part", 0.0, 0.99),
    ParamSpec("odom_absolute_rotation", _D.odom_absolute_rotation,
              "odometry bound: rotation error per step, absolute part [rad]", 0.0, 3.14),
    ParamSpec("contraction_passes", _D.contraction_passes, "forward-backward passes per box at most", 1, 100),
    ParamSpec("min_contraction_gain", _D.min_contraction_gain,
              "stop the passes when no width shrank by more than this fraction", 0.0, 0.99),
    ParamSpec("max_boxes", _D.max_boxes, "bisection stops past this many boxes in one scan (coarser, still sound)",
              1, 10_000_000),
    ParamSpec("max_contractions", _D.max_contractions, "bisection stops past this many contractions in one scan",
              1, 1_000_000_000),
    ParamSpec("merge_width_xy", _D.merge_width_xy, "boxes are merged into hulls at most this wide before prediction [m]",
              1e-3, 100.0),
    ParamSpec("merge_width_theta", _D.merge_width_theta, "heading width of those hulls [rad]", 1e-4, 3.14),
    ParamSpec("localized_width_xy", _D.localized_width_xy, "LOCALIZED when the hull is at most this wide [m]", 1e-4, 1e3),
    ParamSpec("localized_width_theta", _D.localized_width_theta, "LOCALIZED needs the hull heading width at most this [rad]",
              1e-5, 6.3),
    ParamSpec("initial_pose_sigmas", _D.initial_pose_sigmas, "initialpose box half-width in standard deviations",
              1e-3, 100.0),
    ParamSpec("initial_min_half_width_xy", _D.initial_min_half_width_xy, "initialpose box half-width at least [m]",
              1e-4, 100.0),
    ParamSpec("initial_min_half_width_theta", _D.initial_min_half_width_theta,
              "initialpose box heading half-width at least [rad]", 1e-5, 3.15),
    ParamSpec("update_min_d", _D.update_min_d, "translation before an update [m] (0: every scan, as the paper)", 0.0, 1e3),
    ParamSpec("update_min_a", _D.update_min_a, "rotation before an update [rad] (0: every scan)", 0.0, 7.0),
)

EXTRAS = {"boxes": MarkerArray}

# SLAM maps of the real logs are mostly unknown space: a 180-degree scan facing it fits
# almost any pose, so the box list saturates (about 1 s an update) and never fixes.
_REAL_LOG = "real 180-degree log with a mostly unknown SLAM map: boxes saturate, no fix (see core/ial.py)"
BENCH_SKIP = {"intel*": _REAL_LOG, "fr101*": _REAL_LOG, "orebro*": _REAL_LOG}

# Boxes drawn on ~/boxes at most (the best ranked first): RViz slows down beyond a few thousand lines.
MAX_DRAWN_BOXES = 2000


def make_localizer(params: dict[str, Any]) -> IntervalLocalizer:
    """Build the core localizer from parameter values (missing ones take the defaults, unknown ones are ignored)."""
    settings_fields = {field.name: field for field in fields(IALSettings)}
    values: dict[str, Any] = {}
    for key, value in params.items():
        if key not in settings_fields or key == "mount":
            continue
        default = settings_fields[key].default
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        values[key] = value
    values["mount"] = LaserMount(
        float(params.get("laser_x", 0.0)), float(params.get("laser_y", 0.0)), float(params.get("laser_yaw", 0.0))
    )
    return IntervalLocalizer(IALSettings(**values))


def _marker(stamp: float, namespace: str, kind: int, rgba: tuple[float, float, float, float], width: float) -> Marker:
    marker = Marker()
    marker.header.stamp = seconds_to_stamp(stamp)
    marker.header.frame_id = "map"
    marker.ns = namespace
    marker.id = 0
    marker.type = kind
    marker.action = Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.scale.x = width
    marker.color.r, marker.color.g, marker.color.b, marker.color.a = rgba
    return marker


def _rectangle_segments(x_lo: float, x_hi: float, y_lo: float, y_hi: float) -> list[Point]:
    corners = [(x_lo, y_lo), (x_hi, y_lo), (x_hi, y_hi), (x_lo, y_hi)]
    points = []
    for k in range(4):
        for x, y in (corners[k], corners[(k + 1) % 4]):
            points.append(Point(x=float(x), y=float(y), z=0.0))
    return points


def build_extras(estimate: Estimate, max_boxes: int | None = None) -> dict[str, MarkerArray]:
    """``{"boxes": MarkerArray}``: box rectangles, heading ranges and the hull, in the ``map`` frame."""
    limit = MAX_DRAWN_BOXES if max_boxes is None else max_boxes
    boxes = np.asarray(estimate.details.get("boxes", np.zeros((0, 3, 2))), dtype=np.float64).reshape(-1, 3, 2)
    clear = Marker()
    clear.header.stamp = seconds_to_stamp(estimate.stamp)
    clear.header.frame_id = "map"
    clear.action = Marker.DELETEALL
    markers = [clear]
    if len(boxes):
        drawn = boxes[:limit]
        outline = _marker(estimate.stamp, "ial_boxes", Marker.LINE_LIST, (0.1, 0.4, 1.0, 0.9), 0.01)
        headings = _marker(estimate.stamp, "ial_headings", Marker.LINE_LIST, (1.0, 0.5, 0.0, 0.9), 0.01)
        ray = 0.3  # length of the heading rays [m]
        for box in drawn:
            outline.points.extend(_rectangle_segments(box[0, 0], box[0, 1], box[1, 0], box[1, 1]))
            cx, cy = 0.5 * (box[0, 0] + box[0, 1]), 0.5 * (box[1, 0] + box[1, 1])
            for theta in (box[2, 0], box[2, 1]):
                headings.points.append(Point(x=float(cx), y=float(cy), z=0.0))
                headings.points.append(
                    Point(x=float(cx + ray * math.cos(theta)), y=float(cy + ray * math.sin(theta)), z=0.0)
                )
        hull = _marker(estimate.stamp, "ial_hull", Marker.LINE_LIST, (0.0, 0.8, 0.2, 1.0), 0.02)
        hull.points.extend(
            _rectangle_segments(boxes[:, 0, 0].min(), boxes[:, 0, 1].max(), boxes[:, 1, 0].min(), boxes[:, 1, 1].max())
        )
        markers.extend([outline, headings, hull])
    array = MarkerArray()
    array.markers = markers
    return {"boxes": array}


def main() -> int:
    return localizer_node_main(sys.modules[__name__])


if __name__ == "__main__":
    sys.exit(main())
