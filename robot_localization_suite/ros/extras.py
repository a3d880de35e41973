"""Method-specific output messages: IAL's boxes as markers, IMA's place name.

An :class:`Extra` names the message type and how to build it from an estimate; the shared
node publishes each on ``~/<key>``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from ..core.localizer import Estimate
from .conversions import seconds_to_stamp

__all__ = ["Extra", "IAL_BOXES", "IMA_PLACE", "boxes_markers", "MAX_DRAWN_BOXES"]

# Boxes drawn on ~/boxes at most (the best ranked first): RViz slows down beyond a few thousand lines.
MAX_DRAWN_BOXES = 2000


@dataclass(frozen=True)
class Extra:
    """One extra output topic: its message type and the builder from an estimate."""

    kind: type
    build: Callable[[Estimate], Any]


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


def boxes_markers(estimate: Estimate, max_boxes: int = MAX_DRAWN_BOXES) -> MarkerArray:
    """Box rectangles, heading ranges (two rays from each centre) and the hull, in the ``map`` frame."""
    boxes = np.zeros((0, 3, 2)) if estimate.boxes is None else np.asarray(estimate.boxes, dtype=np.float64).reshape(-1, 3, 2)
    clear = Marker()
    clear.header.stamp = seconds_to_stamp(estimate.stamp)
    clear.header.frame_id = "map"
    clear.action = Marker.DELETEALL
    markers = [clear]
    if len(boxes):
        outline = _marker(estimate.stamp, "ial_boxes", Marker.LINE_LIST, (0.1, 0.4, 1.0, 0.9), 0.01)
        headings = _marker(estimate.stamp, "ial_headings", Marker.LINE_LIST, (1.0, 0.5, 0.0, 0.9), 0.01)
        ray = 0.3  # length of the heading rays [m]
        for box in boxes[:max_boxes]:
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
    return array


def place_message(estimate: Estimate) -> String:
    """The name of the estimated place."""
    return String(data=estimate.place.name if estimate.place is not None else "")


IAL_BOXES = {"boxes": Extra(MarkerArray, boxes_markers)}
IMA_PLACE = {"place": Extra(String, place_message)}
