"""The optional ``prepare(scan)`` hook (``core/localizer.py`` ``Preparer``) in the benchmark.

A localizer that has it is given the bag's first scan right after ``set_map``, and both
count in ``map_setup_s``: precomputation a method would otherwise do inside its first update.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ...core.errors import LocalizationSuiteError
from .reference import SCAN_TOPIC, BagReference

if TYPE_CHECKING:
    from ...core.scan import LaserMount, Scan

__all__ = ["prepare_scan", "prepare_localizer"]


def prepare_scan(localizer: Any, reference: BagReference, mount: LaserMount, *,
                 uses_camera: bool = False) -> Scan | None:
    """The bag's first scan that converts (levelled at ``mount``, as the adapter gives scans), if ``localizer``
    has ``prepare``; else None (nothing to do).

    Read before the ``map_setup_s`` timing starts: reading a bag is not precomputation.
    """
    from ...ros import conversions
    from ...ros.bag import read_bag

    if uses_camera or not reference.has_scan or not callable(getattr(localizer, "prepare", None)):
        return None
    for item in read_bag(reference.path, [SCAN_TOPIC], remap=reference.remap):
        try:
            return mount.level(conversions.scan_from_msg(item.msg))
        except LocalizationSuiteError:
            continue
    return None


def prepare_localizer(localizer: Any, scan: Scan | None) -> None:
    """``localizer.prepare(scan)`` when :func:`prepare_scan` found a scan for it."""
    if scan is not None:
        localizer.prepare(scan)
