"""Place recognition over a set of panoramas (thesis 4.1.5), with digital zoom (2.4) as the best of three comparisons.

Notes: docs/ima.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .blas import single_thread_blas
from .images import apply_clahe, preprocess, to_grey, zoom_image, zoom_panorama
from .matching import PanoramaStrip, best_matching, match_slots
from .panorama import heading_from_col, panorama_width
from .settings import ImaSettings

__all__ = ["PlaceMatch", "PanoramaBank"]


@dataclass(frozen=True)
class PlaceMatch:
    """IMA of one camera image against every panorama.

    Attributes:
        match: ``(P,)`` best ``MAX`` of the comparisons (``MATCH(d)`` of eq. 3.21).
        col: ``(P,)`` ``COL`` of that comparison.
        heading: ``(P,)`` camera heading it implies [rad] (eq. 2.2).
        comparison: ``(P,)`` 0 image->panorama, 1 zoomed image->panorama, 2 image->zoomed panorama.
    """

    match: NDArray[np.float64]
    col: NDArray[np.int64]
    heading: NDArray[np.float64]
    comparison: NDArray[np.int64]


class PanoramaBank:
    """Every node's panorama at the working scale, ready for IMA with zoom (section 4.1.5).

    Args:
        panoramas: grey (or colour) panoramas of any size, each covering 360 degrees
            with column 0 looking at ``heading_refs[p] + hfov/2``.
        hfov_deg: the camera's horizontal field of view [deg] (sets ``Wref``, eq. 2.1).
        heading_refs: ``(P,)`` or scalar map heading of each panorama's first snapshot [rad].
        settings: IMA parameters.
    """

    def __init__(
        self,
        panoramas: Sequence[ArrayLike],
        hfov_deg: float,
        heading_refs: ArrayLike,
        settings: ImaSettings,
    ) -> None:
        if len(panoramas) == 0:
            raise ValueError("a panorama bank needs at least one panorama")
        self.settings = settings
        self.hfov_deg = float(hfov_deg)
        self.width = panorama_width(settings.width, hfov_deg)
        self.heading_refs = np.broadcast_to(np.asarray(heading_refs, dtype=np.float64), (len(panoramas),)).copy()
        tile = (settings.width / settings.clahe_tiles, settings.height / settings.clahe_tiles)
        prepared = []
        for panorama in panoramas:
            grey = to_grey(panorama)
            resized = cv2.resize(grey, (self.width, settings.height), interpolation=cv2.INTER_AREA)
            small = np.asarray(resized, dtype=np.uint8)  # uint8 already: states it for the type checker, no copy
            if settings.clahe:
                small = apply_clahe(small, settings, tile_px=(round(tile[0]), round(tile[1])))
            prepared.append(small.astype(np.float32))
        self.panoramas = prepared
        self._plain = PanoramaStrip(prepared, settings.slot_width)
        self.zoom_on = settings.zoom > 1.0
        if self.zoom_on:
            zoomed = [zoom_panorama(p, settings.zoom) for p in prepared]
            self.zoomed_width = zoomed[0].shape[1]
            self._zoomed = PanoramaStrip(zoomed, settings.slot_width)

    def __len__(self) -> int:
        return len(self.panoramas)

    def _score(self, strip: PanoramaStrip, image: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        s = self.settings
        values = strip.values(image, s.slots, s.ncc_backend)
        match_slot, match_val = match_slots(values)
        return best_matching(match_slot, match_val, s.slots, s.slot_width)

    def match(self, image: ArrayLike) -> PlaceMatch:
        """IMA of a camera image (any size, grey or colour) against every panorama, best of three with zoom."""
        s = self.settings
        processed = preprocess(image, s, self.hfov_deg)
        with single_thread_blas():
            scores = [self._score(self._plain, processed)]
        widths = [self.width]
        if self.zoom_on:
            with single_thread_blas():
                scores.append(self._score(self._plain, zoom_image(image, s, self.hfov_deg)))
            widths.append(self.width)
            with single_thread_blas():
                scores.append(self._score(self._zoomed, processed))
            widths.append(self.zoomed_width)
        best = np.stack([m for m, _ in scores])  # (comparisons, P)
        cols = np.stack([c for _, c in scores])
        which = np.argmax(best, axis=0)
        count = best.shape[1]
        match = best[which, np.arange(count)]
        col = cols[which, np.arange(count)]
        width = np.asarray(widths, dtype=np.float64)[which]
        heading = heading_from_col(col, width, s.width, s.slots, self.hfov_deg, self.heading_refs)
        return PlaceMatch(match.astype(np.float64), col.astype(np.int64), np.asarray(heading), which.astype(np.int64))
