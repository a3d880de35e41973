"""Image-based place recognition with IMA (thesis 003, chapter 2 and appendix A).

The image matching algorithm (IMA) cuts a new grey image into ``Ns`` column
*slots*, slides each slot along a stored panorama with the normalized
correlation coefficient (NCC, mapped to [0, 1] by equation A.4), and looks
for the position where the slots match in the right order and spacing:

* :func:`slot_values` (A.4), :func:`match_slots` (Code 2.1),
  :func:`best_matching` (Code 2.2, and the panorama variant Code 2.3);
* :func:`build_panorama` - section 2.2, equation 2.1, CLAHE option (2.2.2);
* :func:`heading_from_col` - section 2.3, equation 2.2;
* :class:`PanoramaBank` - the place recognition of section 4.1.5, with
  digital zoom (section 2.4) as the best of three comparisons;
* :class:`TopologicalMap` / :func:`load_topomap` - the map file of Figure 4.1.

Beyond the thesis: NCC of all slots and panoramas as one matrix product
(``ncc_backend="gemm"``), and images warped to equal angle per column
(``cylindrical``).

Notes (choices where the thesis is silent, measured figures): docs/ima.md.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from ..errors import MapError
from ..se2 import wrap_angle
from .settings import NCC_BACKENDS, ImaSettings

__all__ = [
    "FLAT_STD",
    "ImaSettings",
    "ImaResult",
    "ncc_to_unit",
    "to_grey",
    "preprocess",
    "zoom_image",
    "zoom_panorama",
    "apply_clahe",
    "plain_working_image",
    "single_thread_blas",
    "slot_values",
    "match_slots",
    "best_matching",
    "ima",
    "panorama_width",
    "heading_from_col",
    "build_panorama",
    "PanoramaBank",
    "PlaceMatch",
    "TopoNode",
    "TopologicalMap",
    "load_topomap",
    "save_topomap",
]

# Below this standard deviation [grey levels] a template or window is flat: NCC 0 (0.5 after A.4).
FLAT_STD = 1e-3


@dataclass(frozen=True)
class ImaResult:
    """Output of IMA on one panorama: ``MAX`` in [0, 1] and ``COL`` (0-based left column)."""

    match: float
    col: int


# -- images --------------------------------------------------------------------------
def ncc_to_unit(ncc: ArrayLike) -> NDArray[np.float64] | float:
    """Appendix A, equation A.4: NCC in [-1, 1] -> [0, 1]."""
    return (np.asarray(ncc) + 1.0) / 2.0


def to_grey(image: ArrayLike) -> NDArray[np.uint8]:
    """A grey uint8 image from grey, RGB (H, W, 3) or RGBA input; refuses other shapes."""
    pixels = np.asarray(image)
    if pixels.ndim == 3 and pixels.shape[2] in (3, 4):
        pixels = pixels[:, :, :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    elif pixels.ndim == 3 and pixels.shape[2] == 1:
        pixels = pixels[:, :, 0]
    if pixels.ndim != 2 or pixels.shape[0] < 2 or pixels.shape[1] < 2:
        raise ValueError(f"expected a grey (H, W) or colour (H, W, 3) image, got shape {np.shape(image)!r}")
    if pixels.dtype != np.uint8:
        pixels = np.asarray(pixels, dtype=np.float64)
        if not np.all(np.isfinite(pixels)):
            raise ValueError("image holds non-finite values")
        if pixels.size and pixels.max() <= 1.0 and pixels.min() >= 0.0 and np.asarray(image).dtype.kind == "f":
            pixels = pixels * 255.0
        pixels = np.clip(np.rint(pixels), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(pixels)


def apply_clahe(grey: NDArray[np.uint8], settings: ImaSettings, *, tile_px: tuple[int, int] | None = None) -> NDArray[np.uint8]:
    """CLAHE (section 2.2.2) with ``settings.clahe_tiles`` tiles per image side, or tiles of ``tile_px`` (w, h)."""
    height, width = grey.shape
    if tile_px is None:
        grid = (settings.clahe_tiles, settings.clahe_tiles)
    else:
        grid = (max(1, round(width / tile_px[0])), max(1, round(height / tile_px[1])))
    clahe = cv2.createCLAHE(clipLimit=settings.clahe_clip_limit, tileGridSize=grid)
    return clahe.apply(grey)


@functools.lru_cache(maxsize=32)
def _cylindrical_maps(width: int, height: int, hfov_deg: float) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """cv2.remap maps from a pinhole image to a cylindrical one of the same size and field of view."""
    half = 0.5 * math.radians(hfov_deg)
    focal = 0.5 * width / math.tan(half)
    angle = (0.5 * width - (np.arange(width) + 0.5)) * (2.0 * half / width)  # left column positive
    source_x = 0.5 * width - focal * np.tan(angle) - 0.5
    rows = np.arange(height) + 0.5 - 0.5 * height
    source_y = 0.5 * height + rows[:, None] / np.cos(angle)[None, :] - 0.5
    map_x = np.broadcast_to(source_x[None, :], (height, width)).astype(np.float32)
    return np.ascontiguousarray(map_x), source_y.astype(np.float32)


def _to_working(grey: NDArray[np.uint8], width: int, height: int, hfov_deg: float, cylindrical: bool) -> NDArray[np.uint8]:
    small = cv2.resize(grey, (width, height), interpolation=cv2.INTER_AREA)
    if not cylindrical:
        return small
    map_x, map_y = _cylindrical_maps(width, height, float(hfov_deg))
    return cv2.remap(small, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def preprocess(image: ArrayLike, settings: ImaSettings, hfov_deg: float) -> NDArray[np.float32]:
    """Grey, resized to the working scale (area averaging), cylindrical if on, CLAHE if on: float32 (height, width)."""
    small = _to_working(to_grey(image), settings.width, settings.height, hfov_deg, settings.cylindrical)
    if settings.clahe:
        small = apply_clahe(small, settings)
    return small.astype(np.float32)


def plain_working_image(image: ArrayLike, settings: ImaSettings, hfov_deg: float) -> NDArray[np.uint8]:
    """Grey at the working scale, cylindrical if on, without CLAHE (what panorama files store)."""
    return _to_working(to_grey(image), settings.width, settings.height, hfov_deg, settings.cylindrical)


def zoom_image(image: ArrayLike, settings: ImaSettings, hfov_deg: float) -> NDArray[np.float32]:
    """The digitally zoomed-in image (2.4): resized by ``rho_in`` from the source, centre crop, CLAHE."""
    zoomed_w = max(settings.width, round(settings.width * settings.zoom))
    zoomed_h = max(settings.height, round(settings.height * settings.zoom))
    big = _to_working(to_grey(image), zoomed_w, zoomed_h, hfov_deg, settings.cylindrical)
    left = (zoomed_w - settings.width) // 2
    top = (zoomed_h - settings.height) // 2
    crop = np.ascontiguousarray(big[top : top + settings.height, left : left + settings.width])
    if settings.clahe:
        crop = apply_clahe(crop, settings)
    return crop.astype(np.float32)


def zoom_panorama(panorama: NDArray[np.float32], zoom: float) -> NDArray[np.float32]:
    """The zoomed-in panorama (4.1.5, the practical zoom-out of the image): wider, centre-cropped in height."""
    height, width = panorama.shape
    zoomed_w = round(width * zoom)
    zoomed_h = max(height, round(height * zoom))
    # Resize a copy with wrapped borders so the seam interpolates across 360 degrees.
    pad = 2
    wrapped = np.concatenate([panorama[:, -pad:], panorama, panorama[:, :pad]], axis=1)
    big = cv2.resize(wrapped, (round((width + 2 * pad) * zoom), zoomed_h), interpolation=cv2.INTER_LINEAR)
    start = round(pad * zoom)
    top = (zoomed_h - height) // 2
    return np.ascontiguousarray(big[top : top + height, start : start + zoomed_w], dtype=np.float32)


# -- BLAS threads ----------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def _openblas_local_setters() -> tuple:
    """``openblas_set_num_threads_local`` of every OpenBLAS loaded in this process (numpy's, scipy's)."""
    try:
        with open("/proc/self/maps") as maps:
            paths = sorted({line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line})
    except OSError:
        return ()
    setters = []
    for path in paths:
        try:
            setter = ctypes.CDLL(path).openblas_set_num_threads_local
        except (OSError, AttributeError):
            continue
        setter.argtypes = [ctypes.c_int]
        setter.restype = ctypes.c_int
        setters.append(setter)
    return tuple(setters)


@contextlib.contextmanager
def single_thread_blas():
    """Run the block's matrix products on the calling thread only.

    The IMA products are small (72 x 58 by 58 x 7000): OpenBLAS' threads cost
    more than they bring, and on a loaded 2-core machine their spin-waiting
    made an update 5-30x slower (measured). Uses OpenBLAS' thread-local
    setting, restored on exit; a no-op where no OpenBLAS is found.
    """
    setters = _openblas_local_setters()
    previous = [setter(1) for setter in setters]
    try:
        yield
    finally:
        for setter, count in zip(setters, previous, strict=True):
            setter(count)


# -- IMA -----------------------------------------------------------------------------
def _window_norms(extended: NDArray[np.float32], slot_width: int) -> NDArray[np.float64]:
    """sqrt of sum of squared deviations of every ``slot_width``-column window, flat windows -> 0."""
    height = extended.shape[0]
    count = height * slot_width
    columns = extended.astype(np.float64)
    first = np.concatenate([[0.0], np.cumsum(columns.sum(axis=0))])
    second = np.concatenate([[0.0], np.cumsum((columns * columns).sum(axis=0))])
    sums = first[slot_width:] - first[:-slot_width]
    squares = second[slot_width:] - second[:-slot_width]
    variance = np.maximum(squares - sums * sums / count, 0.0) / count
    std = np.sqrt(variance)
    return np.where(std < FLAT_STD, 0.0, std * math.sqrt(count))


def _slot_templates(image: NDArray[np.float32], slots: int, slot_width: int) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """Zero-mean slot templates ``(H, Ns, Wslot)`` of the used columns and their norms ``(Ns,)`` (flat -> 0)."""
    height, width = image.shape
    used = slots * slot_width
    left = (width - used) // 2
    templates = image[:, left : left + used].astype(np.float64).reshape(height, slots, slot_width)
    templates = templates - templates.mean(axis=(0, 2), keepdims=True)
    count = height * slot_width
    std = np.sqrt((templates * templates).sum(axis=(0, 2)) / count)
    norms = np.where(std < FLAT_STD, 0.0, std * math.sqrt(count))
    return templates.astype(np.float32), norms


def _extend(panorama: NDArray[np.float32], slot_width: int) -> NDArray[np.float32]:
    """The panorama with its first ``slot_width - 1`` columns appended: windows wrap around 360 degrees."""
    if slot_width <= 1:
        return np.ascontiguousarray(panorama, dtype=np.float32)
    return np.ascontiguousarray(np.concatenate([panorama, panorama[:, : slot_width - 1]], axis=1), dtype=np.float32)


def _correlate_gemm(templates: NDArray[np.float32], extended: NDArray[np.float32]) -> NDArray[np.float32]:
    """Sum over rows and template columns of template x window, for every window start: ``(Ns, X - Wslot + 1)``."""
    height, slots, slot_width = templates.shape
    columns = templates.reshape(height, slots * slot_width).T  # (Ns*Wslot, H)
    products = columns @ extended  # (Ns*Wslot, X): dot of each template column with each panorama column
    starts = extended.shape[1] - slot_width + 1
    numerator = np.zeros((slots, starts), dtype=np.float32)
    for offset in range(slot_width):
        numerator += products[offset::slot_width, offset : offset + starts]
    return numerator


def _ncc_unit(numerator: NDArray, template_norms: NDArray[np.float64], window_norms: NDArray[np.float64]) -> NDArray[np.float32]:
    denominator = template_norms[:, None] * window_norms[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        ncc = np.where(denominator > 0.0, numerator / np.where(denominator > 0.0, denominator, 1.0), 0.0)
    return (0.5 * (np.clip(ncc, -1.0, 1.0) + 1.0)).astype(np.float32)


def _opencv_values(
    image: NDArray[np.float32],
    extended: NDArray[np.float32],
    templates: NDArray[np.float32],
    template_norms: NDArray[np.float64],
    window_norms: NDArray[np.float64],
) -> NDArray[np.float32]:
    """``cv2.matchTemplate(TM_CCOEFF_NORMED)`` of each slot, mapped by A.4, flat slots or windows -> 0.5."""
    slots, slot_width = templates.shape[1], templates.shape[2]
    height, width = image.shape
    left = (width - slots * slot_width) // 2
    out = np.empty((slots, window_norms.shape[0]), dtype=np.float32)
    for n in range(slots):
        slot = np.ascontiguousarray(image[:, left + n * slot_width : left + (n + 1) * slot_width], dtype=np.float32)
        ncc = cv2.matchTemplate(extended, slot, cv2.TM_CCOEFF_NORMED)[0, : window_norms.shape[0]]
        flat = (template_norms[n] <= 0.0) | (window_norms <= 0.0)
        out[n] = np.where(flat, 0.5, 0.5 * (np.clip(ncc, -1.0, 1.0) + 1.0))
    return out


def slot_values(
    image: NDArray[np.float32],
    panorama: NDArray[np.float32],
    slots: int,
    *,
    backend: str = "gemm",
) -> NDArray[np.float32]:
    """``VAL`` of every slot at every panorama column: ``(Ns, Wref)`` in [0, 1] (Figure 2.2, appendix A).

    ``VAL[n, c]`` compares slot ``n`` with the panorama columns ``c .. c + Wslot - 1``
    (modulo ``Wref``: the panorama is circular).
    """
    image = np.asarray(image, dtype=np.float32)
    panorama = np.asarray(panorama, dtype=np.float32)
    if image.ndim != 2 or panorama.ndim != 2 or image.shape[0] != panorama.shape[0]:
        raise ValueError(f"image {image.shape!r} and panorama {panorama.shape!r} must be 2-D with equal heights")
    if backend not in NCC_BACKENDS:
        raise ValueError(f"backend must be one of {NCC_BACKENDS}, got {backend!r}")
    slot_width = image.shape[1] // slots
    if slot_width < 1 or panorama.shape[1] < slot_width:
        raise ValueError(f"{slots!r} slots do not fit image width {image.shape[1]} / panorama width {panorama.shape[1]}")
    extended = _extend(panorama, slot_width)
    templates, template_norms = _slot_templates(image, slots, slot_width)
    window_norms = _window_norms(extended, slot_width)
    width = panorama.shape[1]
    if backend == "opencv":
        return _opencv_values(image, extended, templates, template_norms, window_norms[:width])
    numerator = _correlate_gemm(templates, extended)
    return _ncc_unit(numerator, template_norms, window_norms)[:, :width]


def match_slots(values: NDArray[np.float32]) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """Code 2.1: ``MATCH_SLOT`` (1-based slot index, 0 where no value beat 0) and ``MATCH_VAL`` per column.

    Works on ``(Ns, W)`` or batched ``(Ns, P, W)`` values. The strict ``>`` of
    Code 2.1 keeps the lowest slot index among equal values, as ``argmax`` does.
    """
    best = np.argmax(values, axis=0)
    match_val = np.max(values, axis=0)
    match_slot = np.where(match_val > 0.0, best + 1, 0).astype(np.int64)
    return match_slot, np.where(match_val > 0.0, match_val, 0.0).astype(np.float32)


def _mask_indices(width: int, slots: int, slot_width: int) -> NDArray[np.int64]:
    """``i = c + (n - 1) Wslot`` (0-based, modulo the circular width): ``(Ns, W)``."""
    return (np.arange(width)[None, :] + slot_width * np.arange(slots)[:, None]) % width


def best_matching(
    match_slot: NDArray[np.int64],
    match_val: NDArray[np.float32],
    slots: int,
    slot_width: int,
    *,
    panorama_variant: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Code 2.2 (or Code 2.3 with ``panorama_variant``): ``MAX`` and ``COL`` for ``(W,)`` or batched ``(P, W)`` input.

    The mask ``{1, ..., Ns}`` is placed with its first slot at every column
    ``c``; element ``n`` looks at ``i = c + (n - 1) Wslot`` (modulo ``W``, the
    panorama being circular) and adds ``MATCH_VAL[i]`` when ``MATCH_SLOT[i] = n``.
    Code 2.3 adds, where ``MATCH_VAL[i] = 0.5`` exactly (a black zone), the mean
    of the previous slots ``SUM / (n - 1)`` (0 for ``n = 1``).

    Returns ``MAX`` (divided by ``Ns``) and 0-based ``COL``, of shape ``()`` or
    ``(P,)``. ``COL`` is the first column reaching the maximum (strict ``>``);
    when every sum is 0, ``MAX = 0`` and ``COL = 0`` as initialised.
    """
    if slots < 1 or slot_width < 1:
        raise ValueError(f"slots and slot_width must be >= 1, got {slots!r} and {slot_width!r}")
    single = np.ndim(match_slot) == 1
    match_slot = np.atleast_2d(match_slot)
    match_val = np.atleast_2d(match_val).astype(np.float64)
    width = match_slot.shape[1]
    index = _mask_indices(width, slots, slot_width)  # (Ns, W)
    gathered_slot = match_slot[:, index]  # (P, Ns, W)
    gathered_val = match_val[:, index]
    in_order = gathered_slot == (np.arange(1, slots + 1)[None, :, None])
    if not panorama_variant:
        sums = np.where(in_order, gathered_val, 0.0).sum(axis=1)
    else:
        sums = np.zeros((match_slot.shape[0], width))
        for n in range(slots):
            black = ~in_order[:, n] & (gathered_val[:, n] == 0.5)
            mean_so_far = sums / n if n > 0 else np.zeros_like(sums)
            sums = sums + np.where(in_order[:, n], gathered_val[:, n], np.where(black, mean_so_far, 0.0))
    col = np.argmax(sums, axis=1)
    best = sums[np.arange(sums.shape[0]), col] / slots
    if single:
        return best[0], col[0]
    return best, col


def ima(
    image: NDArray[np.float32],
    panorama: NDArray[np.float32],
    slots: int,
    *,
    panorama_variant: bool = False,
    backend: str = "gemm",
) -> ImaResult:
    """IMA on one panorama: Code 2.1 then Code 2.2 (or 2.3). Images are preprocessed float32 of equal height."""
    values = slot_values(image, panorama, slots, backend=backend)
    match_slot, match_val = match_slots(values)
    best, col = best_matching(match_slot, match_val, slots, image.shape[1] // slots, panorama_variant=panorama_variant)
    return ImaResult(float(best), int(col))


# -- panoramas and heading (2.2, 2.3) -------------------------------------------------
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
    mosaic = np.zeros((settings.height, width_ref), dtype=np.uint8)
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


# -- place recognition over a set of panoramas (4.1.5) --------------------------------
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


class _Strip:
    """Panoramas of equal size side by side, each extended to wrap, for one batched NCC."""

    def __init__(self, panoramas: Sequence[NDArray[np.float32]], slot_width: int) -> None:
        self.count = len(panoramas)
        self.width = panoramas[0].shape[1]
        self.segment = self.width + slot_width - 1
        self.slot_width = slot_width
        self.extended = [_extend(p, slot_width) for p in panoramas]
        self.strip = np.ascontiguousarray(np.concatenate(self.extended, axis=1), dtype=np.float32)
        self.window_norms = _window_norms(self.strip, slot_width)

    def values(self, image: NDArray[np.float32], slots: int, backend: str) -> NDArray[np.float32]:
        """``VAL`` ``(Ns, P, W)`` of every slot on every panorama."""
        templates, norms = _slot_templates(image, slots, self.slot_width)
        if backend == "opencv":
            return np.stack(
                [
                    _opencv_values(image, ext, templates, norms, self.window_norms[p * self.segment :][: self.width])
                    for p, ext in enumerate(self.extended)
                ],
                axis=1,
            )
        unit = _ncc_unit(_correlate_gemm(templates, self.strip), norms, self.window_norms)
        padded = np.pad(unit, ((0, 0), (0, self.count * self.segment - unit.shape[1])))
        return padded.reshape(slots, self.count, self.segment)[:, :, : self.width]


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
            small = cv2.resize(grey, (self.width, settings.height), interpolation=cv2.INTER_AREA)
            if settings.clahe:
                small = apply_clahe(small, settings, tile_px=(round(tile[0]), round(tile[1])))
            prepared.append(small.astype(np.float32))
        self.panoramas = prepared
        self._plain = _Strip(prepared, settings.slot_width)
        self.zoom_on = settings.zoom > 1.0
        if self.zoom_on:
            zoomed = [zoom_panorama(p, settings.zoom) for p in prepared]
            self.zoomed_width = zoomed[0].shape[1]
            self._zoomed = _Strip(zoomed, settings.slot_width)

    def __len__(self) -> int:
        return len(self.panoramas)

    def _score(self, strip: _Strip, image: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
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


# -- the topological map file (4.1.3, Figure 4.1) --------------------------------------
@dataclass(frozen=True)
class TopoNode:
    """One place: its name, position in the map frame [m] and panorama."""

    name: str
    x: float
    y: float
    panorama_file: str
    heading_ref: float = 0.0


@dataclass
class TopologicalMap:
    """The topological map: nodes with panoramas, and the camera field of view they were taken with.

    Attributes:
        nodes: the places.
        hfov_deg: horizontal field of view of the camera that took the snapshots [deg].
        panoramas: ``(H, W)`` grey uint8 panorama of each node.
        source: free-form provenance (scenario, settings) written by ``build_topomap``.
    """

    nodes: list[TopoNode]
    hfov_deg: float
    panoramas: list[NDArray[np.uint8]] = field(default_factory=list, repr=False)
    source: dict[str, object] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [node.name for node in self.nodes]

    @property
    def positions(self) -> NDArray[np.float64]:
        """``(N, 2)`` node positions [m]."""
        return np.array([[node.x, node.y] for node in self.nodes], dtype=np.float64).reshape(-1, 2)

    @property
    def heading_refs(self) -> NDArray[np.float64]:
        return np.array([node.heading_ref for node in self.nodes], dtype=np.float64)


def _topomap_field(meta: dict, name: str, path: Path, where: str = "") -> object:
    if name not in meta:
        raise MapError(f"topological map {str(path)!r}{where} has no field {name!r}")
    return meta[name]


def _finite(value: object, name: str, path: Path, where: str) -> float:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise MapError(f"topological map {str(path)!r}{where}: field {name!r} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise MapError(f"topological map {str(path)!r}{where}: field {name!r} must be finite, got {value!r}")
    return number


def load_topomap(yaml_path: str | os.PathLike[str]) -> TopologicalMap:
    """Read a topological map YAML and its panorama images.

    The file holds ``hfov_deg``, optionally ``panorama_dir`` (the first line of
    the thesis' map file; default the YAML's folder) and ``heading_ref``, and
    ``nodes``: a list of ``{name, x, y, panorama[, heading_ref]}``.

    Raises:
        MapError: naming the file, the field and the bad value; a missing
            panorama file is named with its full path.
    """
    path = Path(yaml_path)
    if not path.is_file():
        raise MapError(f"topological map {str(path)!r} does not exist")
    try:
        meta = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MapError(f"topological map {str(path)!r} is not valid YAML: {exc}") from exc
    if not isinstance(meta, dict):
        raise MapError(f"topological map {str(path)!r} must hold a mapping, got {type(meta).__name__}")
    hfov = _finite(_topomap_field(meta, "hfov_deg", path), "hfov_deg", path, "")
    if not 0.0 < hfov < 360.0:
        raise MapError(f"topological map {str(path)!r}: field 'hfov_deg' must be within (0, 360), got {hfov!r}")
    default_ref = _finite(meta.get("heading_ref", 0.0), "heading_ref", path, "")
    folder = (path.parent / str(meta.get("panorama_dir", "."))).resolve()
    entries = _topomap_field(meta, "nodes", path)
    if not isinstance(entries, list) or not entries:
        raise MapError(f"topological map {str(path)!r}: field 'nodes' must be a non-empty list, got {entries!r}")
    nodes, panoramas, seen = [], [], set()
    for index, entry in enumerate(entries):
        where = f" node {index}"
        if not isinstance(entry, dict):
            raise MapError(f"topological map {str(path)!r}{where} must be a mapping, got {entry!r}")
        name = str(_topomap_field(entry, "name", path, where))
        if name in seen:
            raise MapError(f"topological map {str(path)!r}: node name {name!r} appears twice")
        seen.add(name)
        where = f" node {name!r}"
        x = _finite(_topomap_field(entry, "x", path, where), "x", path, where)
        y = _finite(_topomap_field(entry, "y", path, where), "y", path, where)
        ref = _finite(entry.get("heading_ref", default_ref), "heading_ref", path, where)
        file_name = str(_topomap_field(entry, "panorama", path, where))
        image_path = folder / file_name
        if not image_path.is_file():
            raise MapError(f"topological map {str(path)!r}{where}: panorama file {str(image_path)!r} does not exist")
        pixels = cv2.imread(str(image_path), cv2.IMREAD_GRAYSCALE)
        if pixels is None or pixels.size == 0:
            raise MapError(f"topological map {str(path)!r}{where}: panorama file {str(image_path)!r} is not an image")
        nodes.append(TopoNode(name, x, y, file_name, ref))
        panoramas.append(pixels)
    source = meta.get("source", {})
    return TopologicalMap(nodes, hfov, panoramas, source if isinstance(source, dict) else {})


def save_topomap(topomap: TopologicalMap, yaml_path: str | os.PathLike[str]) -> Path:
    """Write the YAML and one PNG per node (``<panorama_file>``) beside it."""
    path = Path(yaml_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if len(topomap.panoramas) != len(topomap.nodes):
        raise ValueError(f"{len(topomap.nodes)} nodes but {len(topomap.panoramas)} panoramas")
    for node, panorama in zip(topomap.nodes, topomap.panoramas, strict=True):
        target = path.parent / node.panorama_file
        if not cv2.imwrite(str(target), np.asarray(panorama, dtype=np.uint8)):
            raise MapError(f"could not write panorama {str(target)!r}")
    meta = {
        "hfov_deg": float(topomap.hfov_deg),
        "panorama_dir": ".",
        "source": topomap.source,
        "nodes": [
            {
                "name": node.name,
                "x": round(float(node.x), 4),
                "y": round(float(node.y), 4),
                "panorama": node.panorama_file,
                "heading_ref": round(float(node.heading_ref), 6),
            }
            for node in topomap.nodes
        ],
    }
    path.write_text(yaml.safe_dump(meta, sort_keys=False))
    return path
