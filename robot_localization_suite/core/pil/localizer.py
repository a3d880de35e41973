"""Pseudo Image Localization (PIL): Lambert, Jaiem, Lapierre, Crestani, "PIL: A new algorithm
for mobile robot localization", 2020 (hal-02494512).

Off-line (:mod:`.learning`, section 2.2): pseudo-images ``I = 1 - D_s / R`` of
every valid tile of an ``r``-sized grid, and their orientation-free level
functions (section 2.3, :mod:`.levels`). On-line (this module and
:mod:`.matching`, sections 2.4-2.7): the level functions of the live scan
select candidate tiles (equation 4) inside a spatial window, theta of every
candidate comes from circular cross-correlation of the profiles (section
2.5), and the best candidate is the estimate.

Beyond the paper: candidates ranked by the level functions rather than only
filtered, a truncated squared-difference score, sub-tile refinement, heading
sheets for a limited field of view, and an escape from the window when places
outside it keep scoring better.

Notes (choices, departures, status, measured figures): docs/pil.md.
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
    LevelFunction,
    energy,
    fill_invalid_circular,
    harmonic_magnitude,
    pq_fraction,
    profile_quantile,
)
from .matching import (
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
from .settings import LEVEL_FUNCTION_NAMES, PilSettings

__all__ = ["PilSettings", "PilLocalizer", "make_level_functions"]

_logger = logging.getLogger(__name__)


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
            area: NDArray[np.bool_] = np.ones(passes.size, dtype=bool)
        else:
            offset = np.abs(self.learning.tile_centres - centre[None, :2])
            area = (offset[:, 0] <= 0.5 * settings.window_size) & (offset[:, 1] <= 0.5 * settings.window_size)
        pass_mask = passes & area
        chosen = _best_ranked(np.flatnonzero(pass_mask), rank, settings.max_candidates)
        wanted = min(settings.min_candidates, int(area.sum()))
        if chosen.size < wanted:
            chosen = np.concatenate([chosen, _best_ranked(np.flatnonzero(area & ~passes), rank, wanted - chosen.size)])
        sentinels: NDArray[np.int64] = np.zeros(0, dtype=np.int64)
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
            return Estimate(scan.stamp, pose, cov, LocalizerStatus.LOST, np.zeros((0, 3)), np.zeros(0), details=details)
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
