"""Pseudo Image Localization (PIL): Lambert, Jaiem, Lapierre, Crestani, "PIL: A new algorithm
for mobile robot localization", 2020 (hal-02494512).

Off-line (:mod:`.pil_learning`): a simulated robot at the centre of every
valid tile of an ``r``-sized grid, heading 0, records ``N_s`` pseudo-images
``I(L, C, k) = 1 - D_s / R`` (sections 2.2, equations 1-2); orientation-free
level functions ``I_n`` of every tile are computed from them (section 2.3,
:mod:`.pil_levels`).

On-line (this module, :mod:`.pil_matching`): the live scan becomes ``N_s``
sensor intensities (equation 3) and their level functions ``E_n``; tiles with
``AND_n alpha_n |I_n - E_n| < sigma_n`` form the binary candidate image of
equation (4), inside a spatial window around the last estimate that covers the
whole map at start, after a kidnapping and when lost (section 2.7); theta of
every candidate comes from the circular cross-correlation of the live profile
with the learned one (section 2.5); the best candidate is the estimate.

Choices and additions, written down (the paper leaves them open, or DESIGN.md
"Measured here" showed they matter):

* **Candidate selection.** Equation (4) is computed and reported
  (``filter_count``; :attr:`PilLocalizer.candidate_image`). Candidates are the
  tiles that pass it, *ranked* by ``sum_n min((alpha_n |I_n - E_n| / sigma_n)^2, cap)``
  and capped at ``max_candidates``; when fewer than ``min_candidates`` pass,
  the best-ranked others are added (real sensor noise needs a sigma so wide
  that a fixed filter passes most tiles or drops the right one; ranking keeps
  it in the top few hundred). ``min_candidates = 0`` is the paper's pure filter.
* **Match score.** The normalised truncated squared difference of the aligned
  profiles (``0`` perfect, ``1`` every sensor off by more than ``tau``), not a
  raw correlation; theta itself comes from an FFT correlation (see
  :mod:`.pil_matching`).
* **Sub-tile refinement** (optional, ``refine_candidates > 0``): the best few
  candidates are refined against the map's distance field and rescored by
  casting the ``N_s`` sensors from the refined pose; a candidate keeps the
  better of its tile pose and its refined pose.
* **Limited field of view** (beyond the paper): the paper assumes a full-range
  sensor. For a scan covering less than 360 degrees the level functions are
  learned on ``K`` heading sheets (sectors of the full-circle profiles at
  headings ``2 pi j / K``) and a tile is a candidate if any sheet matches; theta
  is found by correlation within the field of view over all headings.
* **Window.** A square of side ``window_size`` centred on the last estimate,
  moved by the odometry received since (``on_odometry``; PIL is otherwise
  odometry-free). If the best score inside the window is above
  ``kidnap_score``, the same update searches the whole map (a kidnapping is
  recovered in one update, section 3.1). A LOST estimate, ``reinitialize()``
  and the start use the whole map. Each windowed update also scores the
  ``global_candidates`` best-ranked tiles outside the window, which replace
  the window's best once their score advantage, accumulated over updates,
  exceeds ``global_switch_margin``: a window
  that settled on the twin of a symmetric place (the corridor of section 3.2)
  is left as soon as the scan tells the twins apart, not never.
* **Outputs.** ``pose`` = best candidate; ``covariance`` = weighted spread of
  the candidates scoring within ``ambiguity_margin`` of the best, plus the
  grid quantisation (``r^2 / 12``, ``Delta^2 / 12``); status ``AMBIGUOUS``
  when a candidate farther than ``ambiguity_distance`` or
  ``ambiguity_angle`` from the best scores within ``ambiguity_margin`` of it
  (the corridor of section 3.2), ``LOST`` when the best score exceeds
  ``lost_score``.
* **A scan the learning does not fit.** A field of view other than the learned
  one (beyond one beam step), or a ``range_max`` below the learned ``R``,
  triggers a warning (logger and ``details["warning"]``) and a relearning for
  the scan's geometry (from the cache when it was learned before) rather than
  wrong answers. The laser pose is estimated; the adapter handles the mount.
* **Bad readings.** NaN / -inf / below ``range_min`` readings are invalid and
  carry zero weight; ``inf`` and readings at or beyond ``range_max`` (and
  beyond ``R``) read ``R`` (I = 0, as in the learning); a changed beam count
  rebuilds the beam-to-sensor mapping; fewer than ``min_valid_fraction`` valid
  sensors raise :class:`~robot_localization_suite.core.errors.ScanError`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import MapError, ScanError
from ..filter.odometry_gate import OdometryGate
from ..filter.refinement import DistanceField, refine_poses
from ..grid_map import GridMap
from ..localizer import Estimate, LocalizerStatus
from ..raycast import RayCaster
from ..scan import Scan
from ..se2 import angle_difference, compose, relative, wrap_angle
from .learning import PilLearning, learn_pseudo_images
from .levels import (
    LEVEL_FUNCTION_NAMES,
    LevelFunction,
    energy,
    fill_invalid_circular,
    harmonic_magnitude,
    pq_fraction,
    profile_quantile,
)
from .matching import (
    BEAM_MAPPINGS,
    BeamMapping,
    LiveProfile,
    SensorLayout,
    check_live_profile,
    correlate_profiles,
    feature_distances,
    sheet_features,
    sheet_sectors,
    truncated_scores,
)

__all__ = ["PilSettings", "PilLocalizer", "make_level_functions"]

_logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PilSettings:
    """Settings of PIL; units in brackets, sources in comments.

    Learning (section 2.2):
        tile_size: ``r`` [m] (paper: 20 cm).
        sensor_count: ``N_s`` sensors evenly spaced over the field of view (paper: 57).
        max_range: ``R`` [m] (paper figure 1: 6 m; 10 m suits the 30 m x 11 m floor).
        field_of_view: angle the learned sensors cover [rad] (paper: 2 pi; a scan with another
            field of view triggers a relearning).
        angular_upsampling: learned directions per sensor step (DESIGN.md: 4x finer profiles).
        reference_headings: ``K`` heading sheets for a limited field of view (DESIGN.md: 8 as good as 16 or 36).
        unknown_blocks: whether unknown map cells stop the learning rays.
        beam_mapping: ``"nearest"`` or ``"sector_min"`` (see :mod:`.pil_matching`).

    Level functions (section 2.3): ``<name>_enabled``, ``<name>_alpha`` (``alpha_n``),
    ``<name>_sigma`` (``sigma_n``, intensity units). The paper uses alpha 1 and sigma 0.05 for
    Energy and pq%; the defaults here are measured: about 2.5 x the robust spread (1.48 MAD) of
    ``I_n - E_n`` at the true tile over the Intel log (180 degrees, K = 8, R = 10 m), so that
    equation (4) keeps the true tile for most real scans and the ranking weighs each function by
    its reliability.
        pq_low, pq_high: ``p`` and ``q`` of pq% (paper figure 2: 0.25 and 0.75).
        low_quantile_level, high_quantile_level: the quantiles of the sorted profile.

    Candidates (sections 2.4, 2.7):
        min_candidates: add best-ranked tiles until this many (0: the paper's pure filter). 600:
            on the real logs the true tile's rank is below 300 in 70-80 % of scans, below 1000 in
            80-91 % (measured); 600 keeps an update near 10 ms.
        max_candidates: keep at most this many passing tiles, best-ranked first.
        rank_term_cap: cap of each function's ``(alpha_n |I_n - E_n| / sigma_n)^2`` in the ranking
            (9: three sigma). Measured on floor_kidnap (people walking by): the true tile ranks in
            the top 300 for 94 % of scans instead of 91 % uncapped.
        window_size: side of the square search window [m] (paper section 4.2: 4 m); <= 0: whole map.
        global_candidates: best-ranked tiles outside the window scored with every windowed update
            (0: the paper's hard window). Without them a window that settled on the twin of a
            symmetric place never lets go (measured on corridor_kidnap).
        global_switch_margin: a place outside the window replaces the window's best once its
            accumulated score advantage exceeds this (normalised score; see ``_prefer_window``).

    Theta and scoring (section 2.5):
        score_truncation: ``tau`` of the truncated squared difference [intensity units].
        shift_hypotheses: local correlation optima rescored per candidate.
        refine_candidates: best candidates refined below the tile size (0: off).
        refine_iterations: Gauss-Newton iterations of the refinement.
        refine_beams: live hits used by the refinement at most.
        refine_truncation: endpoints farther from an obstacle are ignored [m].

    Status:
        lost_score: best normalised score above which the estimate is LOST.
        kidnap_score: best score inside the window above which the whole map is searched. Measured
            on the real logs (global fixes, tau 0.1): correct fixes score 0.03-0.07 (median) and
            0.1-0.2 (90th percentile), wrong ones 0.19-0.35 (median).
        ambiguity_margin: score margin of AMBIGUOUS and of the covariance's near-best set.
        ambiguity_distance: [m] and ambiguity_angle: [rad] what counts as a separate candidate.
        min_valid_fraction: sensors that must receive a valid beam.

    Cache:
        cache_dir: directory ("" -> ``$RLS_CACHE_DIR`` or ``~/.cache/robot_localization_suite``).
        use_cache: read and write the cache.
        show_progress: tqdm bar while learning.
    """

    tile_size: float = 0.2
    sensor_count: int = 57
    max_range: float = 10.0
    field_of_view: float = 2.0 * math.pi
    angular_upsampling: int = 4
    reference_headings: int = 8
    unknown_blocks: bool = False
    beam_mapping: str = "nearest"

    energy_enabled: bool = True
    energy_alpha: float = 1.0
    energy_sigma: float = 0.03
    pq_enabled: bool = True
    pq_low: float = 0.25
    pq_high: float = 0.75
    pq_alpha: float = 1.0
    pq_sigma: float = 0.08
    harmonic1_enabled: bool = True
    harmonic1_alpha: float = 1.0
    harmonic1_sigma: float = 0.025
    harmonic2_enabled: bool = True
    harmonic2_alpha: float = 1.0
    harmonic2_sigma: float = 0.02
    low_quantile_enabled: bool = True
    low_quantile_level: float = 0.1
    low_quantile_alpha: float = 1.0
    low_quantile_sigma: float = 0.06
    high_quantile_enabled: bool = True
    high_quantile_level: float = 0.9
    high_quantile_alpha: float = 1.0
    high_quantile_sigma: float = 0.02

    min_candidates: int = 600
    max_candidates: int = 1000
    rank_term_cap: float = 9.0
    window_size: float = 4.0
    global_candidates: int = 50
    global_switch_margin: float = 0.05

    score_truncation: float = 0.1
    shift_hypotheses: int = 3
    refine_candidates: int = 20
    refine_iterations: int = 10
    refine_beams: int = 180
    refine_truncation: float = 0.3

    lost_score: float = 0.5
    kidnap_score: float = 0.2
    ambiguity_margin: float = 0.03
    ambiguity_distance: float = 1.0
    ambiguity_angle: float = 0.5
    min_valid_fraction: float = 0.3

    cache_dir: str = ""
    use_cache: bool = True
    show_progress: bool = True

    def __post_init__(self) -> None:
        def positive(name: str) -> None:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"PilSettings.{name} must be positive, got {value!r}")

        for name in ("tile_size", "max_range", "score_truncation", "refine_truncation", "ambiguity_distance", "rank_term_cap"):
            positive(name)
        for name in LEVEL_FUNCTION_NAMES:
            positive(f"{name}_alpha")
            positive(f"{name}_sigma")
        if self.max_range > 65.0:
            raise ValueError(f"PilSettings.max_range must be at most 65 m, got {self.max_range!r}")
        if not 0.0 < self.field_of_view <= 2.0 * math.pi + 1e-9:
            raise ValueError(f"PilSettings.field_of_view must be in (0, 2 pi] rad, got {self.field_of_view!r}")
        if self.sensor_count < 4:
            raise ValueError(f"PilSettings.sensor_count must be at least 4, got {self.sensor_count!r}")
        if self.angular_upsampling < 1:
            raise ValueError(f"PilSettings.angular_upsampling must be at least 1, got {self.angular_upsampling!r}")
        if self.reference_headings < 1:
            raise ValueError(f"PilSettings.reference_headings must be at least 1, got {self.reference_headings!r}")
        if self.beam_mapping not in BEAM_MAPPINGS:
            raise ValueError(f"PilSettings.beam_mapping must be one of {BEAM_MAPPINGS}, got {self.beam_mapping!r}")
        if not 0.0 <= self.pq_low < self.pq_high <= 1.0:
            raise ValueError(f"PilSettings needs 0 <= pq_low < pq_high <= 1, got {self.pq_low!r}, {self.pq_high!r}")
        for name in ("low_quantile_level", "high_quantile_level", "min_valid_fraction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"PilSettings.{name} must be in [0, 1], got {value!r}")
        if self.harmonic2_enabled and self.sensor_count < 5:
            raise ValueError(f"PilSettings.harmonic2 needs at least 5 sensors, got {self.sensor_count!r}")
        for name in ("min_candidates", "refine_candidates"):
            if getattr(self, name) < 0:
                raise ValueError(f"PilSettings.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.global_candidates < 0:
            raise ValueError(f"PilSettings.global_candidates must be >= 0, got {self.global_candidates!r}")
        for name in ("max_candidates", "shift_hypotheses", "refine_iterations", "refine_beams"):
            if getattr(self, name) < 1:
                raise ValueError(f"PilSettings.{name} must be >= 1, got {getattr(self, name)!r}")
        if not np.isfinite(self.window_size):
            raise ValueError(f"PilSettings.window_size must be finite, got {self.window_size!r}")
        for name in ("lost_score", "kidnap_score", "ambiguity_margin", "ambiguity_angle", "global_switch_margin"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"PilSettings.{name} must be >= 0, got {value!r}")


def make_level_functions(settings: PilSettings) -> list[LevelFunction]:
    """The enabled level functions of equation (4), in :data:`LEVEL_FUNCTION_NAMES` order."""
    evaluators: dict[str, Callable[[NDArray[np.floating]], NDArray[np.float64]]] = {
        "energy": energy,
        "pq": lambda profiles: pq_fraction(profiles, settings.pq_low, settings.pq_high),
        "harmonic1": lambda profiles: harmonic_magnitude(profiles, 1),
        "harmonic2": lambda profiles: harmonic_magnitude(profiles, 2),
        "low_quantile": lambda profiles: profile_quantile(profiles, settings.low_quantile_level),
        "high_quantile": lambda profiles: profile_quantile(profiles, settings.high_quantile_level),
    }
    return [
        LevelFunction(name, getattr(settings, f"{name}_alpha"), getattr(settings, f"{name}_sigma"), evaluators[name])
        for name in LEVEL_FUNCTION_NAMES
        if getattr(settings, f"{name}_enabled")
    ]


def _best_ranked(indices: NDArray[np.int64], rank: NDArray[np.float64], count: int) -> NDArray[np.int64]:
    """The ``count`` entries of ``indices`` with the smallest ``rank``, best first."""
    if count <= 0 or indices.size == 0:
        return np.zeros(0, dtype=np.int64)
    if count < indices.size:
        indices = indices[np.argpartition(rank[indices], count - 1)[:count]]
    return indices[np.argsort(rank[indices], kind="stable")]


@dataclass
class _Search:
    """Ranked candidates of one query."""

    poses: NDArray[np.float64]
    scores: NDArray[np.float64]
    filter_count: int
    candidate_count: int
    passes: NDArray[np.bool_]
    tiles: NDArray[np.int64]
    refined: int
    is_sentinel: NDArray[np.bool_]

    @property
    def best_score(self) -> float:
        return float(self.scores[0]) if self.scores.size else math.inf


class PilLocalizer:
    """PIL as a :class:`~robot_localization_suite.core.localizer.Localizer` and ``GlobalFixer``.

    Args:
        settings: the method's settings.
        log: ``log(level, text)`` with level ``info`` / ``warn``; default: this module's logger.
    """

    def __init__(self, settings: PilSettings | None = None, *, log: Callable[[str, str], None] | None = None) -> None:
        self.settings = settings or PilSettings()
        self._emit = log or (lambda level, text: _logger.log(logging.WARNING if level == "warn" else logging.INFO, text))
        self.level_functions = make_level_functions(self.settings)
        self._alphas = np.array([f.alpha for f in self.level_functions])
        self._sigmas = np.array([f.sigma for f in self.level_functions])
        self._layout = SensorLayout(self.settings.field_of_view, self.settings.sensor_count, self.settings.angular_upsampling)
        self._range = self.settings.max_range
        self.grid_map: GridMap | None = None
        self.learning: PilLearning | None = None
        self._caster: RayCaster | None = None
        self._distance_field: DistanceField | None = None
        self._mapping: BeamMapping | None = None
        self._sheets_key: tuple[float, ...] | None = None
        self._sheet_features: NDArray[np.float32] | None = None
        self._last_passes: NDArray[np.bool_] | None = None
        self._tracked_pose: NDArray[np.float64] | None = None
        # Latest odometry; the reference is the odometry at the tracked pose (no gate: PIL runs on every scan).
        self.odometry = OdometryGate()
        self._switch_evidence = 0.0

    # -- Localizer protocol -------------------------------------------------------
    def set_map(self, grid_map: GridMap) -> None:
        """Learn (or load) the pseudo-images of ``grid_map`` for the current sensor geometry."""
        self.grid_map = grid_map
        self._distance_field = DistanceField(grid_map)
        self._learn()
        self.reinitialize()

    def on_odometry(self, stamp: float, odom_pose: NDArray[np.float64]) -> None:
        """Odometry moves the window centre between scans; it is not used otherwise (non-finite or older: ignored)."""
        self.odometry.add(stamp, odom_pose)

    def on_scan(self, scan: Scan) -> Estimate:
        """Localize from one scan within the window (widened to the whole map when needed).

        Raises:
            MapError: before any map.
            ScanError: a scan with too few valid beams.
        """
        notes = self._prepare(scan)
        profile = self._live_profile(scan)
        centre = self._window_centre()
        window = "whole_map"
        if centre is None or self.settings.window_size <= 0.0:
            search = self._search(scan, profile, None)
        else:
            search = self._prefer_window(self._search(scan, profile, centre))
            window = "window"
            if search.best_score > self.settings.kidnap_score:
                wider = self._search(scan, profile, None)
                window = "whole_map_after_window"
                if wider.best_score < search.best_score:
                    search = wider
        estimate = self._estimate(scan, search, window, notes)
        if estimate.status is LocalizerStatus.LOST:
            self._tracked_pose = None
        else:
            self._tracked_pose = estimate.pose.copy()
            self.odometry.mark_updated(self.odometry.latest)
        return estimate

    def _prefer_window(self, search: _Search) -> _Search:
        """Keep the window's best first unless the places outside it have been clearly better.

        Evidence that the best place outside the window beats the window's best is
        accumulated over updates as a CUSUM, ``e <- max(0, e + d - drift)`` with ``d``
        the score difference and ``drift = global_switch_margin / 10``; the estimate
        leaves the window when ``e`` exceeds ``global_switch_margin``. Twins of a
        symmetric place score alike, so ``e`` stays near 0 and the estimate does not
        jump between them; once the scan tells them apart (a cabinet comes into view),
        the small but steady advantage adds up within a few updates.
        """
        inside = np.flatnonzero(~search.is_sentinel)
        outside = np.flatnonzero(search.is_sentinel)
        if inside.size == 0 or outside.size == 0:
            self._switch_evidence = 0.0
            return search
        margin = self.settings.global_switch_margin
        advantage = float(search.scores[inside[0]] - search.scores[outside[0]])
        self._switch_evidence = max(0.0, self._switch_evidence + advantage - 0.1 * margin)
        if self._switch_evidence > margin:
            self._switch_evidence = 0.0
            first = int(outside[0])
        else:
            first = int(inside[0])
        if first == 0:
            return search
        order = np.r_[first, np.delete(np.arange(search.scores.size), first)]
        return replace(
            search,
            poses=search.poses[order],
            scores=search.scores[order],
            tiles=search.tiles[order],
            is_sentinel=search.is_sentinel[order],
        )

    def global_fix(self, scan: Scan) -> Estimate:
        """Localize from this scan alone over the whole map (no prior, tracking state untouched)."""
        notes = self._prepare(scan)
        profile = self._live_profile(scan)
        return self._estimate(scan, self._search(scan, profile, None), "whole_map", notes)

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Centre the window on ``pose`` (the covariance is not used: the window size is a parameter)."""
        pose = np.asarray(pose, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(pose)):
            raise ValueError(f"initial pose must be finite, got {pose.tolist()!r}")
        self._tracked_pose = pose.copy()
        self.odometry.mark_updated(self.odometry.latest)

    def reinitialize(self) -> None:
        """Forget the last estimate: the next scan searches the whole map."""
        self._tracked_pose = None
        self.odometry.reset(force=False)
        self._switch_evidence = 0.0

    def request_nomotion_update(self) -> None:
        """PIL updates on every scan, moving or not: nothing to do."""

    # -- inspection ---------------------------------------------------------------
    @property
    def layout(self) -> SensorLayout:
        return self._layout

    @property
    def max_range(self) -> float:
        """``R`` of the current learning [m]."""
        return self._range

    @property
    def candidate_image(self) -> NDArray[np.bool_] | None:
        """The binary image of equation (4) of the last query (``L_max x C_max``), or None."""
        if self.learning is None or self._last_passes is None:
            return None
        image = np.zeros((self.learning.grid.lines, self.learning.grid.columns), dtype=bool)
        image[self.learning.tile_lines, self.learning.tile_columns] = self._last_passes
        return image

    def level_images(self, sheet: int = 0) -> dict[str, NDArray[np.float64]]:
        """The pseudo-images ``I_n`` of the level functions (paper figure 2) on one heading sheet."""
        if self.learning is None or self._sheet_features is None:
            raise MapError("PIL has not learned a map yet")
        return {
            function.name: self.learning.pseudo_image(self._sheet_features[sheet, f])
            for f, function in enumerate(self.level_functions)
        }

    # -- learning -----------------------------------------------------------------
    def _learn(self) -> None:
        if self.grid_map is None:
            raise MapError("PIL has no map to learn")
        self.learning = learn_pseudo_images(
            self.grid_map,
            tile_size=self.settings.tile_size,
            angle_count=self._layout.angle_count,
            max_range=self._range,
            unknown_blocks=self.settings.unknown_blocks,
            cache_dir=self.settings.cache_dir or None,
            use_cache=self.settings.use_cache,
            show_progress=self.settings.show_progress,
            log=self._emit,
        )
        self.learning.spectra  # noqa: B018 - derived once here, not in the first query
        self._caster = RayCaster(self.grid_map, max_range=self._range, unknown_blocks=self.settings.unknown_blocks)
        self._sheets_key = None
        self._sheet_features = None
        self._mapping = None
        if self.learning is not None and self._layout.full_circle:
            self._ensure_sheets(0.0)

    def _prepare(self, scan: Scan) -> dict[str, Any]:
        """Check the scan against the learning; relearn (with a warning) when its geometry differs."""
        if self.grid_map is None or self.learning is None:
            raise MapError("PIL has no map yet: call set_map first")
        if scan.beam_count < 2:
            raise ScanError(f"PIL needs a scan of at least 2 beams, got {scan.beam_count}")
        increment = abs(float(scan.angles[1] - scan.angles[0]))
        if not np.isfinite(increment) or increment <= 0.0:
            raise ScanError(f"scan angle increment {increment!r} is unusable")
        fov = scan.field_of_view
        scan_full = fov >= 2.0 * math.pi - 0.5 * increment
        notes: dict[str, Any] = {}
        reasons = []
        new_fov = self._layout.field_of_view
        if scan_full != self._layout.full_circle or (
            not scan_full
            and abs(fov - self._layout.field_of_view) > max(1.5 * increment, 0.5 * self._layout.sensor_spacing)
        ):
            new_fov = 2.0 * math.pi if scan_full else fov
            reasons.append(
                f"the scan covers {math.degrees(fov):.1f} deg but PIL learned {math.degrees(self._layout.field_of_view):.1f} deg"
            )
        new_range = min(self.settings.max_range, scan.range_max)
        if new_range < self._range - 1e-3 or (self._range < self.settings.max_range and new_range > self._range + 1e-3):
            reasons.append(f"the scan's range_max is {scan.range_max:.2f} m but PIL learned R = {self._range:.2f} m")
        if reasons:
            text = "; ".join(reasons) + f": relearning for {math.degrees(new_fov):.1f} deg and R = {new_range:.2f} m"
            self._emit("warn", text)
            self._layout = replace(self._layout, field_of_view=new_fov)
            self._range = new_range
            self._learn()
            notes["warning"] = text
            notes["relearned"] = True
        if self._mapping is None or not self._mapping.matches(scan):
            self._mapping = BeamMapping(self._layout, scan, self.settings.beam_mapping)
        self._ensure_sheets(float(self._mapping.sensor_angles[0]))
        return notes

    def _ensure_sheets(self, first_sensor_angle: float) -> None:
        """Level functions of every tile on every heading sheet (recomputed when the sensor offset changes)."""
        assert self.learning is not None
        key = (0.0,) if self._layout.full_circle else (round(first_sensor_angle, 9),)
        if self._sheets_key == key and self._sheet_features is not None:
            return
        sectors = sheet_sectors(self._layout, first_sensor_angle, self.settings.reference_headings)
        self._sheet_features = sheet_features(self.learning.intensities, sectors, self.level_functions)
        self._sheets_key = key

    # -- on-line ------------------------------------------------------------------
    def _live_profile(self, scan: Scan) -> LiveProfile:
        assert self._mapping is not None
        profile = self._mapping.profile(scan, self._range)
        check_live_profile(profile, self.settings.min_valid_fraction)
        return profile

    def _live_features(self, profile: LiveProfile) -> NDArray[np.float64]:
        filled = fill_invalid_circular(profile.intensities, profile.valid, circular=self._layout.full_circle)
        return np.array([float(function.evaluate(filled)) for function in self.level_functions])

    def _window_centre(self) -> NDArray[np.float64] | None:
        """The last estimate moved by the odometry received since (None: search the whole map)."""
        if self._tracked_pose is None:
            return None
        odom, reference = self.odometry.latest, self.odometry.reference
        if reference is None or odom is None:
            return self._tracked_pose
        return compose(self._tracked_pose, relative(reference, odom))

    def _select_tiles(
        self, profile: LiveProfile, centre: NDArray[np.float64] | None
    ) -> tuple[NDArray[np.int64], NDArray[np.bool_], int, NDArray[np.bool_]]:
        """Candidate tiles (ranked), which of them are global sentinels outside the window,
        the count passing equation (4) in the searched area, and the pass mask over all tiles."""
        assert self.learning is not None and self._sheet_features is not None
        settings = self.settings
        passes, rank = feature_distances(
            self._sheet_features, self._live_features(profile), self._alphas, self._sigmas, settings.rank_term_cap
        )
        if centre is None:
            area = np.ones(passes.size, dtype=bool)
        else:
            offset = np.abs(self.learning.tile_centres - centre[None, :2])
            area = (offset[:, 0] <= 0.5 * settings.window_size) & (offset[:, 1] <= 0.5 * settings.window_size)
        pass_mask = passes & area
        chosen = _best_ranked(np.flatnonzero(pass_mask), rank, settings.max_candidates)
        wanted = min(settings.min_candidates, int(area.sum()))
        if chosen.size < wanted:
            chosen = np.concatenate([chosen, _best_ranked(np.flatnonzero(area & ~passes), rank, wanted - chosen.size)])
        sentinels = np.zeros(0, dtype=np.int64)
        if centre is not None and settings.global_candidates > 0:
            sentinels = _best_ranked(np.flatnonzero(~area), rank, settings.global_candidates)
        tiles = np.concatenate([chosen, sentinels])
        is_sentinel = np.concatenate([np.zeros(chosen.size, dtype=bool), np.ones(sentinels.size, dtype=bool)])
        return tiles, is_sentinel, int(pass_mask.sum()), pass_mask

    def _search(self, scan: Scan, profile: LiveProfile, centre: NDArray[np.float64] | None) -> _Search:
        assert self.learning is not None and self._caster is not None and self._distance_field is not None
        settings = self.settings
        tiles, is_sentinel, filter_count, pass_mask = self._select_tiles(profile, centre)
        self._last_passes = pass_mask
        if tiles.size == 0:
            return _Search(np.zeros((0, 3)), np.zeros(0), filter_count, 0, pass_mask, tiles, 0, is_sentinel)
        correlation = correlate_profiles(
            self.learning.intensities,
            self.learning.spectra,
            tiles,
            profile,
            self._layout.upsampling,
            settings.score_truncation,
            settings.shift_hypotheses,
        )
        step = self.learning.angle_step
        thetas = wrap_angle(correlation.shifts * step - profile.sensor_angles[0])
        poses = np.column_stack([self.learning.tile_centres[tiles], np.atleast_1d(thetas)])
        scores = correlation.scores.copy()
        order = np.argsort(scores, kind="stable")
        poses, scores, tiles, is_sentinel = poses[order], scores[order], tiles[order], is_sentinel[order]

        refined = min(settings.refine_candidates, len(poses))
        if refined > 0:
            angles, ranges = scan.hits()
            angles, ranges = angles[ranges <= self._range], ranges[ranges <= self._range]
            if angles.size > settings.refine_beams:
                pick = np.round(np.linspace(0, angles.size - 1, settings.refine_beams)).astype(np.int64)
                angles, ranges = angles[pick], ranges[pick]
            better, _ = refine_poses(
                self._distance_field,
                poses[:refined],
                angles,
                ranges,
                iterations=settings.refine_iterations,
                max_shift=settings.tile_size,
                truncation=settings.refine_truncation,
            )
            both = np.concatenate([poses[:refined], better])
            cast = self._caster.cast(both, profile.sensor_angles)
            recast = truncated_scores(1.0 - np.minimum(cast, self._range) / self._range, profile, settings.score_truncation)
            use_refined = recast[refined:] <= recast[:refined]
            poses[:refined] = np.where(use_refined[:, None], better, poses[:refined])
            scores[:refined] = np.minimum(recast[:refined], recast[refined:])
            order = np.argsort(scores, kind="stable")
            poses, scores, tiles, is_sentinel = poses[order], scores[order], tiles[order], is_sentinel[order]
        return _Search(poses, scores, filter_count, len(poses), pass_mask, tiles, refined, is_sentinel)

    def _estimate(self, scan: Scan, search: _Search, window: str, notes: dict[str, Any]) -> Estimate:
        settings = self.settings
        details: dict[str, Any] = {
            "window": window,
            "filter_count": search.filter_count,
            "candidate_count": search.candidate_count,
            "refined_candidates": search.refined,
            "outside_window": bool(search.is_sentinel.size and search.is_sentinel[0]),
            "learned_fov_deg": round(math.degrees(self._layout.field_of_view), 3),
            "learned_range_m": self._range,
            "sheets": 1 if self._layout.full_circle else settings.reference_headings,
            **notes,
        }
        if search.poses.shape[0] == 0:
            details["best_score"] = math.inf
            cov = np.diag([1e6, 1e6, math.pi**2])
            pose = self._tracked_pose.copy() if self._tracked_pose is not None else np.zeros(3)
            return Estimate(scan.stamp, pose, cov, LocalizerStatus.LOST, np.zeros((0, 3)), np.zeros(0), details)
        best = search.poses[0]
        best_score = search.best_score
        separation = np.hypot(*(search.poses[:, :2] - best[:2]).T)
        turn = np.abs(angle_difference(search.poses[:, 2], best[2]))
        separate = (separation > settings.ambiguity_distance) | (turn > settings.ambiguity_angle)
        rivals = np.flatnonzero(separate)
        runner_up = float(search.scores[rivals[0]]) if rivals.size else math.inf
        near = search.scores <= best_score + settings.ambiguity_margin
        ambiguous = bool(np.any(near & separate))
        if best_score > settings.lost_score:
            status = LocalizerStatus.LOST
        elif ambiguous:
            status = LocalizerStatus.AMBIGUOUS
        else:
            status = LocalizerStatus.LOCALIZED
        temperature = max(settings.ambiguity_margin, 1e-6) / 3.0
        # The window's best may lead a place outside the window that scores a little better
        # (see _prefer_window): such places weigh as much as the best, never more.
        weights = np.exp(-np.maximum(search.scores - best_score, 0.0) / temperature)
        diffs = np.column_stack(
            [search.poses[near, 0] - best[0], search.poses[near, 1] - best[1], angle_difference(search.poses[near, 2], best[2])]
        )
        near_weights = weights[near] / weights[near].sum()
        covariance = (diffs * near_weights[:, None]).T @ diffs
        quantisation = np.diag(
            [settings.tile_size**2 / 12.0, settings.tile_size**2 / 12.0, self._layout.sensor_spacing**2 / 12.0]
        )
        details.update(
            best_score=best_score,
            runner_up_score=runner_up,
            near_best_count=int(near.sum()),
            ambiguous=ambiguous,
        )
        return Estimate(
            stamp=scan.stamp,
            pose=best.copy(),
            covariance=covariance + quantisation,
            status=status,
            candidates=search.poses.copy(),
            candidate_weights=weights / weights.sum(),
            details=details,
        )

    def settings_dict(self) -> dict[str, Any]:
        """The settings as a plain dict (for logs and reports)."""
        return asdict(self.settings)
