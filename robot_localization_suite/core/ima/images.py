"""Camera images for IMA: grey conversion, CLAHE (thesis 2.2.2), the working scale, equal-angle columns, zoom (2.4).

``cylindrical`` warps a pinhole image to equal angle per column, so that panorama columns and image
columns share one angular scale (beyond the thesis). Notes: docs/ima.md.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .settings import ImaSettings

__all__ = ["to_grey", "apply_clahe", "preprocess", "plain_working_image", "zoom_image", "zoom_panorama"]


# -- images --------------------------------------------------------------------------
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
    return np.asarray(clahe.apply(grey), dtype=np.uint8)  # uint8 in, uint8 out: no copy


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
    # cv2 keeps the uint8 depth; the asarray calls only state it for the type checker (no copy).
    small = np.asarray(cv2.resize(grey, (width, height), interpolation=cv2.INTER_AREA), dtype=np.uint8)
    if not cylindrical:
        return small
    map_x, map_y = _cylindrical_maps(width, height, float(hfov_deg))
    return np.asarray(cv2.remap(small, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), dtype=np.uint8)


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
