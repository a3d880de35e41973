"""Panoramas for IMA (thesis 2.2, equation 2.1) and the heading from a matched column (2.3, equation 2.2).

:func:`build_panorama` stitches snapshots taken at imprecise turning steps (the IMA variant of
Code 2.3). Notes: docs/ima.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..se2 import wrap_angle
from .blas import single_thread_blas
from .images import plain_working_image, preprocess
from .matching import best_matching, match_slots, slot_values
from .settings import ImaSettings

__all__ = ["panorama_width", "heading_from_col", "PanoramaBuild", "build_panorama"]


def panorama_width(image_width: int, hfov_deg: float) -> int:
    """Equation 2.1: ``Wref = Wnew 2 pi / theta`` [px], rounded."""
    if not 0.0 < hfov_deg < 360.0:
        raise ValueError(f"hfov_deg must be within (0, 360), got {hfov_deg!r}")
    return int(round(image_width * 360.0 / hfov_deg))


def heading_from_col(
    col: ArrayLike,
    panorama_width_px: ArrayLike,
    image_width: int,
    slots: int,
    hfov_deg: float,
    heading_ref: ArrayLike = 0.0,
) -> NDArray[np.float64] | float:
    """Camera heading [rad, map frame, CCW] of an image whose slots matched at ``COL`` (0-based).

    Equation 2.2 gives ``alpha = 2 pi COL / Wref`` clockwise from the
    panorama's column 0 (the left edge of the first snapshot, which looked
    at ``heading_ref``). The heading of the image centre is
    ``heading_ref + theta/2 - 2 pi (COL + Wnew/2 - left) / Wpano`` with
    ``left`` the first column the slots use; for an unzoomed panorama and
    ``left = 0`` this is ``heading_ref - alpha``.
    """
    left = (image_width - (image_width // slots) * slots) // 2
    centre = np.asarray(col, dtype=np.float64) + 0.5 * image_width - left
    half_fov = 0.5 * math.radians(hfov_deg)
    heading = np.asarray(heading_ref, dtype=np.float64) + half_fov - 2.0 * np.pi * centre / np.asarray(panorama_width_px)
    return wrap_angle(heading)


@dataclass(frozen=True)
class PanoramaBuild:
    """A panorama rebuilt from snapshots (section 2.2).

    Attributes:
        panorama: ``(height, Wref)`` grey uint8 mosaic of the raw (non-CLAHE) snapshots.
        columns: ``(S,)`` 0-based column where each snapshot's left edge was inserted.
        matches: ``(S,)`` Code 2.3 ``MAX`` of each insertion (the first is 0.5 on the black panorama).
    """

    panorama: NDArray[np.uint8]
    columns: NDArray[np.int64]
    matches: NDArray[np.float64]


def build_panorama(
    snapshots: Sequence[ArrayLike],
    hfov_deg: float,
    settings: ImaSettings,
) -> PanoramaBuild:
    """Rebuild a 360 degree panorama from snapshots taken turning clockwise on the spot (section 2.2).

    The panorama starts black, ``Wref = Wnew 2 pi / theta`` wide (2.1). Each
    snapshot, in the order taken, is compared with the current panorama by
    IMA with the Code 2.3 variant and inserted (overwriting) at the returned
    ``COL``, modulo ``Wref``; the first lands on column 0 because a black
    panorama gives every column the same score. A slot window that reaches
    even partly into the still black part counts as compared with a black
    zone (value exactly 0.5): a half-black window is no comparison with the
    scene, and letting its NCC count rewarded placements that barely overlap
    the mosaic (measured: 3 of 15 panoramas misplaced a snapshot by 3-10 %
    of the width without this rule, none with it). Alignment uses the
    preprocessed (CLAHE if on) images; the stored mosaic is the plain grey
    snapshots at the working scale, so CLAHE can be chosen at localization.

    Args:
        snapshots: images in the order taken, each turned clockwise by about
            the step angle from the previous one (any size; resized).
        hfov_deg: the camera's horizontal field of view [deg].
        settings: working scale, slots (the thesis used 15 for panoramas), CLAHE.
    """
    if len(snapshots) < 2:
        raise ValueError(f"a panorama needs at least 2 snapshots, got {len(snapshots)}")
    width_ref = panorama_width(settings.width, hfov_deg)
    slot_width = settings.slot_width
    left, _used = settings.used_columns
    aligned = np.zeros((settings.height, width_ref), dtype=np.float32)
    filled = np.zeros(width_ref, dtype=bool)
    mosaic: NDArray[np.uint8] = np.zeros((settings.height, width_ref), dtype=np.uint8)
    columns, matches = [], []
    for snapshot in snapshots:
        processed = preprocess(snapshot, settings, hfov_deg)
        plain = plain_working_image(snapshot, settings, hfov_deg)
        with single_thread_blas():
            values = slot_values(processed, aligned, settings.slots, backend=settings.ncc_backend)
        # A window reaching into the still black part is compared with a black zone: exactly 0.5.
        unfilled = np.concatenate([~filled, ~filled[: slot_width - 1]]).astype(np.int64)
        touches_black = np.convolve(unfilled, np.ones(slot_width, dtype=np.int64), mode="valid")[:width_ref] > 0
        values[:, touches_black] = 0.5
        match_slot, match_val = match_slots(values)
        best, col = best_matching(match_slot, match_val, settings.slots, slot_width, panorama_variant=True)
        target = (int(col) - left + np.arange(settings.width)) % width_ref
        aligned[:, target] = processed
        filled[target] = True
        mosaic[:, target] = plain
        columns.append(int(col))
        matches.append(float(best))
    # Column 0 must be the left edge of the first snapshot (heading convention of heading_from_col).
    mosaic = np.roll(mosaic, left, axis=1)
    return PanoramaBuild(mosaic, np.asarray(columns, dtype=np.int64), np.asarray(matches))
