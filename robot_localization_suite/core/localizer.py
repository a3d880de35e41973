"""The interface every localizer in ``core/`` offers, and what it returns.

Nodes, the deterministic replay and the benchmark talk to localizers only
through :class:`Localizer` (laser methods) or :class:`CameraLocalizer`
(camera methods), so that any method can be dropped into the same harness.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from .grid_map import GridMap
from .scan import Scan

__all__ = [
    "LocalizerStatus",
    "Place",
    "Estimate",
    "Localizer",
    "CameraLocalizer",
    "GlobalFixer",
    "Preparer",
    "prepared_for",
    "Idler",
]


class LocalizerStatus(enum.Enum):
    """What a localizer believes about its own estimate (published on /diagnostics)."""

    INITIALIZING = "INITIALIZING"
    LOCALIZED = "LOCALIZED"
    AMBIGUOUS = "AMBIGUOUS"
    LOST = "LOST"


@dataclass(frozen=True)
class Place:
    """A topological place an estimate names (IMA).

    Attributes:
        name: the place's name in the topological map.
        xy: ``(2,)`` its position in the map [m].
        node_xy: ``(N, 2)`` every place's position, to tell whether the named one is the nearest.
    """

    name: str
    xy: NDArray[np.float64]
    node_xy: NDArray[np.float64]


@dataclass(frozen=True)
class Estimate:
    """One output of a localizer: a value, never changed once made (``dataclasses.replace`` makes another).

    Attributes:
        stamp: the stamp of the input that produced it [s].
        pose: ``(3,)`` best pose in the map [m, m, rad].
        covariance: ``(3, 3)`` covariance of (x, y, theta).
        status: the localizer's own verdict.
        candidates: ``(K, 3)`` particles, candidates or box centres, best first where ranked.
        candidate_weights: ``(K,)`` weights of the candidates, or None.
        boxes: ``(K, 3, 2)`` boxes of poses guaranteed to hold the true one (IAL), in the frame of ``pose``.
        place: the topological place named (IMA), or None.
        heading_corrected: whether the heading was corrected from a match (IMA), None where it does not apply.
        details: scalar diagnostics (``/diagnostics`` key-values: counts, scores, reasons), snake_case keys.
    """

    stamp: float
    pose: NDArray[np.float64]
    covariance: NDArray[np.float64]
    status: LocalizerStatus
    candidates: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    candidate_weights: NDArray[np.float64] | None = None
    boxes: NDArray[np.float64] | None = None
    place: Place | None = None
    heading_corrected: bool | None = None
    details: Mapping[str, Any] = field(default_factory=dict)


@runtime_checkable
class Localizer(Protocol):
    """A laser localizer. Every call returns quickly and never raises on bad readings.

    Optional: ``prepare(scan)`` (:class:`Preparer`), precomputation that needs the scanner's
    geometry as well as the map; callers that have a scan before the first update call it.
    """

    def set_map(self, grid_map: GridMap) -> None:
        """Use this map from now on (may trigger precomputation)."""

    def on_odometry(self, stamp: float, odom_pose: NDArray[np.float64]) -> None:
        """Record the odometry pose ``(3,)`` in the ``odom`` frame at ``stamp``."""

    def on_scan(self, scan: Scan) -> Estimate | None:
        """Process a scan; return an estimate when the method produces one."""

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Restart around ``pose`` with the ``(3, 3)`` covariance (RViz "2D Pose Estimate")."""

    def reinitialize(self) -> None:
        """Forget everything and localize globally (``~/reinitialize_global_localization``)."""

    def request_nomotion_update(self) -> None:
        """Update on the next scan even without motion (``~/request_nomotion_update``)."""


@runtime_checkable
class CameraLocalizer(Protocol):
    """A camera localizer: images instead of scans."""

    def on_odometry(self, stamp: float, odom_pose: NDArray[np.float64]) -> None: ...

    def on_image(self, stamp: float, image: NDArray[np.uint8]) -> Estimate | None: ...

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None: ...

    def reinitialize(self) -> None: ...


@runtime_checkable
class GlobalFixer(Protocol):
    """A method that can localize from a single scan with no prior (``rls_bench --global-fixes``)."""

    def global_fix(self, scan: Scan) -> Estimate:
        """Candidates ranked best first; ``pose`` is the best one."""


@runtime_checkable
class Preparer(Protocol):
    """Optional part of :class:`Localizer`: precompute what the first scan would, from its geometry.

    A method whose precomputation depends on the scanner (beam count, angles, range limits)
    as well as on the map may otherwise do it lazily inside the first ``on_scan``. Given a
    scan of that scanner, ``prepare`` does it at once; only the scan's geometry counts, not
    its readings or stamp. Callers with a scan in hand (``rls_bench``: the bag's first scan,
    right after ``set_map``, timed as ``map_setup_s``) call it when a localizer has it; a
    localizer must work the same when it is never called, and after a later ``set_map``.
    """

    def prepare(self, scan: Scan) -> None:
        """Precompute what the first scan of this geometry would (after ``set_map``)."""


def prepared_for(localizer: Preparer, scan: Scan) -> bool:
    """Whether ``localizer.prepare(scan)`` would have nothing to do, as its optional ``prepared_for(scan)``
    says: what is precomputed serves this scan's geometry (a scanner whose beam count or ``angle_min``
    varies a little from scan to scan needs nothing new). False for a method without it: any other
    layout is prepared for."""
    check = getattr(localizer, "prepared_for", None)
    return bool(check(scan)) if callable(check) else False


@runtime_checkable
class Idler(Protocol):
    """Optional part of :class:`Localizer` for a method with work in background threads (``hybrid_localizer``).

    On a robot that work runs while the node waits for its next input. A replay that feeds the next input at
    once (``rls_bench``) calls ``idle(seconds)`` before each input with the log time since the previous one,
    so that the work gets the time it would have had; a node never calls it (real time passes by itself).
    """

    def idle(self, seconds: float) -> None:
        """Let background work run for at most ``seconds``; return as soon as none is left."""

