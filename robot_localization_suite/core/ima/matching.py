"""The image matching algorithm IMA (thesis 003, chapter 2 and appendix A).

A grey image is cut into ``Ns`` column slots; each slot slides along a stored panorama with the
normalized correlation coefficient (NCC, mapped to [0, 1] by equation A.4), and the best placement
keeps the slots in the right order and spacing: :func:`slot_values` (A.4), :func:`match_slots`
(Code 2.1), :func:`best_matching` (Code 2.2 and the panorama variant Code 2.3), :func:`ima`.
Beyond the thesis: the NCC of all slots and panoramas as one matrix product (``ncc_backend="gemm"``).
Notes: docs/ima.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .settings import NCC_BACKENDS

__all__ = ["FLAT_STD", "ImaResult", "ncc_to_unit", "slot_values", "match_slots", "best_matching", "ima",
           "PanoramaStrip"]

# Below this standard deviation [grey levels] a template or window is flat: NCC 0 (0.5 after A.4).
FLAT_STD = 1e-3


@dataclass(frozen=True)
class ImaResult:
    """Output of IMA on one panorama: ``MAX`` in [0, 1] and ``COL`` (0-based left column)."""

    match: float
    col: int


def ncc_to_unit(ncc: ArrayLike) -> NDArray[np.float64] | float:
    """Appendix A, equation A.4: NCC in [-1, 1] -> [0, 1]."""
    return (np.asarray(ncc) + 1.0) / 2.0


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


class PanoramaStrip:
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
