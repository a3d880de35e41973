"""IAL's boxes as an integrity monitor of the hybrid's estimate (Guyonneau et al. 2014, issue 16 item 3).

Under its bounded-error assumptions (every reading within ``range_error`` of the map but at most
``max_outliers`` of them, odometry within its bounds) interval analysis keeps the true pose inside
its boxes. The monitor runs :class:`~..ial.localizer.IntervalLocalizer` in a worker thread of its
own (one scan at a time, the latest; the odometry in between is fed to it in order, so that its
prediction stays sound) and judges an estimate against the last boxes: outside every box (with
a margin for the estimate's own error), or boxes at several places (unless IAL stopped bisecting
at its limits: then the boxes are coarse, not several places), and the estimate cannot be LOCALIZED. It switches itself off, and says why, where the assumptions cannot hold: a map with
unknown space a beam can reach (beams ending there break the range bound: the SLAM maps of the
real logs), or no box left (more outliers than declared, or a kidnapping the bounds exclude).
Notes: docs/hybrid.md.
"""

from __future__ import annotations

import math
import threading
from concurrent import futures
from concurrent.futures import Future
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..grid_map import GridMap
from ..ial.localizer import IntervalLocalizer
from ..ial.settings import IALSettings
from ..scan import Scan
from ..se2 import angle_difference
from .proposals import Worker

__all__ = ["IntegrityMonitor"]

WAITING = "no box yet"  # on, where its assumptions can hold, but IAL has not answered since the map came


class IntegrityMonitor:
    """IAL tracking in a worker thread; :meth:`judge` says whether an estimate may be LOCALIZED.

    Args:
        settings: IAL's settings (its declared bounds).
        margin_xy, margin_yaw: how far outside a box an estimate may lie (its own error) [m, rad].
        spread: boxes farther apart than this are at several places [m].
    """

    def __init__(self, settings: IALSettings, margin_xy: float, margin_yaw: float, spread: float) -> None:
        self.ial = IntervalLocalizer(settings)
        self.margin_xy, self.margin_yaw, self.spread = margin_xy, margin_yaw, spread
        self._lock = threading.Lock()
        self._odometry: list[tuple[float, NDArray[np.float64]]] = []
        self._worker = Worker("rls-hybrid-ial")
        self._update_done: Future[None] | None = None
        self._generation = 0
        self.boxes: NDArray[np.float64] | None = None  # (K, 3, 2) of the last IAL update
        self.limited = False  # the last update stopped bisecting at IAL's limits: boxes coarse, spread unknown
        self._initial: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self.boxes_stamp = math.nan
        self.off_reason = "no map yet"  # or WAITING, or why it is off; "" while it judges
        self.updates = 0

    def set_map(self, grid_map: GridMap) -> None:
        """Use ``grid_map``; off when a beam could end in unknown space (the range bound cannot hold there)."""
        with self._lock:
            self._generation += 1
            self._odometry = []
            self.boxes = None
            open_unknown, off_map = grid_map.open_unknown()
            if open_unknown.any() or off_map:
                self.off_reason = "the map has unknown space a beam can reach: IAL's range bound cannot hold"
                return
            self.ial.set_map(grid_map)
            self.off_reason = WAITING

    @property
    def active(self) -> bool:
        return self.off_reason == ""

    def on_odometry(self, stamp: float, pose: NDArray[np.float64]) -> None:
        with self._lock:
            self._odometry.append((float(stamp), np.asarray(pose, dtype=np.float64).copy()))

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """IAL starts from the box of ``pose`` (``ial.initial_pose_sigmas`` of ``covariance``) at its next update."""
        with self._lock:
            self._initial = (np.asarray(pose, dtype=np.float64).copy(), np.asarray(covariance, dtype=np.float64).copy())

    def submit(self, scan: Scan) -> None:
        """IAL's update with ``scan`` in the worker, unless it is busy (that scan is then skipped)."""
        if self.off_reason.startswith("the map") or (self._update_done is not None and not self._update_done.done()):
            return
        generation = self._generation
        self._update_done = self._worker.submit(lambda: self._update(scan, generation))

    def wait(self, timeout: float | None = None) -> None:
        """Until the worker's update has ended, or ``timeout`` seconds have passed."""
        if self._update_done is not None:
            futures.wait([self._update_done], timeout)

    def close(self) -> None:
        """End the worker (an update running ends first; its boxes are still taken)."""
        self._worker.close()

    def _update(self, scan: Scan, generation: int) -> None:
        with self._lock:
            odometry = [item for item in self._odometry if item[0] <= scan.stamp]
            self._odometry = self._odometry[len(odometry):]
            initial, self._initial = self._initial, None
        for stamp, pose in odometry:
            self.ial.on_odometry(stamp, pose)
        if initial is not None:
            self.ial.set_initial_pose(*initial)
        estimate = self.ial.on_scan(scan)
        if estimate is None or generation != self._generation:
            return
        boxes = estimate.boxes
        with self._lock:
            self.updates += 1
            if boxes is None or len(boxes) == 0 or estimate.details.get("restarted"):
                self.boxes, self.off_reason = None, "IAL found no box (more outliers than declared, or a kidnapping)"
                return
            self.boxes, self.boxes_stamp, self.off_reason = np.array(boxes, dtype=np.float64), scan.stamp, ""
            self.limited = bool(estimate.details.get("limited"))

    def judge(self, pose: NDArray[np.float64]) -> tuple[bool, dict[str, Any]]:
        """Whether ``pose`` (at :attr:`boxes_stamp`) may be LOCALIZED, and details for ``/diagnostics``.

        Not before IAL's first boxes on a map where the monitor applies: it has not vouched for anything yet."""
        with self._lock:
            boxes, reason, limited = self.boxes, self.off_reason, self.limited
        if reason == WAITING:
            return False, {"integrity": "waiting", "integrity_off_reason": ""}
        if reason or boxes is None:
            return True, {"integrity": "off", "integrity_off_reason": reason}
        lo, hi = boxes[:, :, 0], boxes[:, :, 1]
        inside_xy = np.all((pose[:2] >= lo[:, :2] - self.margin_xy) & (pose[:2] <= hi[:, :2] + self.margin_xy), axis=1)
        centre = 0.5 * (lo[:, 2] + hi[:, 2])
        half = 0.5 * (hi[:, 2] - lo[:, 2]) + self.margin_yaw
        inside = inside_xy & ((half >= math.pi) | (np.abs(angle_difference(pose[2], centre)) <= half))
        centres = 0.5 * (lo[:, :2] + hi[:, :2])
        span = float(np.hypot(*(centres.max(axis=0) - centres.min(axis=0))))
        details: dict[str, Any] = {"integrity": "on", "integrity_boxes": int(len(boxes)),
                                   "integrity_span_m": round(span, 3), "integrity_limited": limited}
        if not inside.any():
            details["integrity"] = "outside_every_box"
            return False, details
        if span > self.spread and not limited:
            details["integrity"] = "boxes_at_several_places"
            return False, details
        return True, details
