"""The camera as one more cue of the hybrid: IMA place recognition breaks the laser's ties between look-alike places.

Each image is matched by IMA (thesis 003, 2.2-2.4, with zoom 4.1.5) against every panorama of a
topological map. As in the thesis' activity update (eq. 3.21), ``MATCH(d)`` is taken as the image's
likelihood at place ``d``. A pose's camera log-likelihood is that of the place nearest it (within
``place_radius``), provided the heading IMA finds at that place agrees with the pose's within
``heading_tolerance``; otherwise the image counts as unlike the place (the image's least match). It is
taken relative to the mean over places, times ``weight``, and is 0 for a pose that no place covers. So
a pose far from any place is neither helped nor hurt. Notes: docs/hybrid.md, "Camera".
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..ima.places import PanoramaBank
from ..ima.settings import ImaSettings
from ..ima.topomap import TopologicalMap
from ..se2 import angle_difference

__all__ = ["CameraCue", "SeenImage"]

_LEAST_MATCH = 1e-3  # a non-positive NCC is as unlike as it gets: log of this


@dataclass(frozen=True)
class SeenImage:
    """One image's IMA against every place: its stamp, ``MATCH`` ``(P,)`` and the heading found at each [rad]."""

    stamp: float
    log_match: NDArray[np.float64]
    heading: NDArray[np.float64]


class CameraCue:
    """Camera log-likelihoods of poses from the last images.

    Args:
        topomap: the places and their panoramas (``build_topomap``).
        ima: IMA's matching parameters.
        weight: exponent of ``MATCH`` (1: the thesis' likelihood).
        place_radius: a pose is covered by its nearest place within this [m]; 0: the median spacing of the places.
        heading_tolerance: largest disagreement of the heading IMA finds with the pose's [rad].
        window_s: how far back images count for :meth:`window` [s].
    """

    def __init__(self, topomap: TopologicalMap, ima: ImaSettings, *, weight: float, place_radius: float,
                 heading_tolerance: float, window_s: float) -> None:
        self.bank = PanoramaBank(topomap.panoramas, topomap.hfov_deg, topomap.heading_refs, ima)
        self.places = np.asarray(topomap.positions, dtype=np.float64).reshape(-1, 2)
        self.weight = float(weight)
        self.radius = float(place_radius) if place_radius > 0.0 else topomap.spacing
        self.heading_tolerance = float(heading_tolerance)
        self.window_s = float(window_s)
        self.recent: deque[SeenImage] = deque()
        self._unused: list[SeenImage] = []

    def forget(self) -> None:
        """Drop every image (a new map, a reset)."""
        self.recent.clear()
        self._unused = []

    def match(self, stamp: float, image: ArrayLike) -> SeenImage:
        """IMA of ``image`` against every place (reads only the panoramas: safe in a worker thread).

        Raises:
            ValueError: the image cannot be read.
        """
        found = self.bank.match(image)
        return SeenImage(float(stamp), np.log(np.maximum(found.match, _LEAST_MATCH)), found.heading)

    def add(self, seen: SeenImage) -> None:
        """Keep a matched image; images older than ``window_s`` before it are dropped (taken or not)."""
        self.recent.append(seen)
        while self.recent and self.recent[0].stamp < seen.stamp - self.window_s:
            self.recent.popleft()
        self._unused = [old for old in self._unused if old.stamp >= seen.stamp - self.window_s] + [seen]

    def on_image(self, stamp: float, image: ArrayLike) -> SeenImage:
        """:meth:`match` then :meth:`add`."""
        seen = self.match(stamp, image)
        self.add(seen)
        return seen

    def window(self, stamp: float) -> list[SeenImage]:
        """The images of the ``window_s`` before ``stamp`` (none after it)."""
        return [seen for seen in self.recent if stamp - self.window_s <= seen.stamp <= stamp]

    def take_new(self, stamp: float) -> list[SeenImage]:
        """The images of the ``window_s`` before ``stamp`` not taken before (each counts once in a running sum)."""
        new, self._unused = self._unused, []
        return [seen for seen in new if seen.stamp >= stamp - self.window_s]

    def log_likelihood(self, poses: ArrayLike, seen: SeenImage) -> NDArray[np.float64]:
        """``(N,)`` camera log-likelihood of each pose ``(N, 3)`` (the camera's, at the image's time) for ``seen``."""
        pose_arr = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(pose_arr) == 0 or len(self.places) == 0:
            return np.zeros(len(pose_arr))
        distance = np.hypot(pose_arr[:, None, 0] - self.places[None, :, 0], pose_arr[:, None, 1] - self.places[None, :, 1])
        nearest = np.argmin(distance, axis=1)
        covered = distance[np.arange(len(pose_arr)), nearest] <= self.radius
        agrees = np.abs(angle_difference(seen.heading[nearest], pose_arr[:, 2])) <= self.heading_tolerance
        value = np.where(agrees, seen.log_match[nearest], seen.log_match.min())
        return np.asarray(np.where(covered, self.weight * (value - seen.log_match.mean()), 0.0), dtype=np.float64)

