"""The robot's position between places: the odometry and the recognised places fused by a Kalman filter (ours).

The thesis localizes to a place; a pose also needs a position. A recognised place is read as a noisy
measurement of the position (its node, with the place's extent as standard deviation), the odometry as
the motion between measurements (its error growing with the distance travelled). A place beyond
``gate_sigmas`` of the fused position is a relocalization (a kidnapping, a wrong earlier place): the
position restarts there (the tracker lets only a place vision names clearly restart it). The places'
errors are not independent (the same view from the same spot errs the same way), so the variance stays
at least ``floor_share`` squared of a place's. Notes and figures: docs/ima.md, "Departure: the pose
within the place".
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["FLOOR_SHARE", "GATE_SIGMAS", "PlacePositionFilter"]

GATE_SIGMAS = 3.0  # a place further than this many standard deviations restarts the position
FLOOR_SHARE = 0.5  # the fused standard deviation stays at least this share of a place's


class PlacePositionFilter:
    """Isotropic 2-D Kalman filter over the robot's position.

    Args:
        drift: standard deviation of the odometry's position error per metre travelled.
        gate_sigmas: a place measured further than this many standard deviations away restarts it.
        floor_share: after a place, the standard deviation is at least this share of the place's.
    """

    def __init__(self, drift: float, gate_sigmas: float = GATE_SIGMAS, floor_share: float = FLOOR_SHARE) -> None:
        self.drift = float(drift)
        self.gate_sigmas = float(gate_sigmas)
        self.floor_share = float(floor_share)
        self.xy: NDArray[np.float64] | None = None
        self.variance = math.inf

    def reset(self) -> None:
        """No position (global localization)."""
        self.xy, self.variance = None, math.inf

    def start(self, xy: ArrayLike, variance: float) -> None:
        """A known position, with its variance per axis [m^2]."""
        self.xy = np.asarray(xy, dtype=np.float64).reshape(2).copy()
        self.variance = float(variance)

    def predict(self, displacement: ArrayLike) -> None:
        """Move by the odometry's ``displacement`` ``(2,)`` [m] in the map frame; the variance grows with it."""
        if self.xy is None:
            return
        moved = np.asarray(displacement, dtype=np.float64).reshape(2)
        self.xy = self.xy + moved
        self.variance += (self.drift * float(np.hypot(moved[0], moved[1]))) ** 2

    def beyond_gate(self, place_xy: ArrayLike, variance: float) -> bool:
        """Whether a place measured at ``place_xy`` with ``variance`` lies beyond the gate (False without a
        position: the first place starts it)."""
        if self.xy is None:
            return False
        offset = np.asarray(place_xy, dtype=np.float64).reshape(2) - self.xy
        return float(offset @ offset) > self.gate_sigmas**2 * (self.variance + variance)

    def correct(self, place_xy: ArrayLike, variance: float) -> bool:
        """Fuse a place measured at ``place_xy`` with ``variance`` per axis; True if it restarted the position."""
        z = np.asarray(place_xy, dtype=np.float64).reshape(2)
        if self.xy is None or self.beyond_gate(z, variance):
            self.start(z, variance)
            return True
        offset = z - self.xy
        gain = self.variance / (self.variance + variance)
        self.xy = self.xy + gain * offset
        self.variance = max((1.0 - gain) * self.variance, self.floor_share**2 * float(variance))
        return False
