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
filtered, a coarse-to-fine correlation of many tiles, a truncated
squared-difference score in which unknown space and readings shorter than the
map are weak evidence, sub-tile refinement, heading sheets for a limited field
of view, and an escape from the window when places outside it keep scoring
better.

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
from ..metrics import scan_explained
from ..raycast import RAY_UNKNOWN, ClassifiedRayCaster
from ..scan import Scan
from ..se2 import angle_difference, compose, relative, wrap_angle
from .learning import PilLearning, encode_ranges, learn_pseudo_images
from .levels import (
    LevelFunction,
    energy,
    fill_invalid_circular,
    harmonic_magnitude,
    learned_level_features,
    pq_fraction,
    profile_quantile,
)
from .matching import (
    BeamMapping,
    LevelIndex,
    LiveProfile,
    SensorLayout,
    check_live_profile,
    correlate_tiles,
    cost_table,
    decode_features,
    encode_features,
    profile_costs,
    rank_tiles,
    select_ranked,
    sheet_sectors,
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
        self._caster: ClassifiedRayCaster | None = None
        self._distance_field: DistanceField | None = None
        self._mapping: BeamMapping | None = None
        self._sheets_key: tuple[int, ...] | None = None
        self._sheet_features: NDArray[np.uint8] | None = None
        self._tile_index: NDArray[np.int32] | None = None
        self._level_index: LevelIndex | None = None
        self._last_passes: NDArray[np.bool_] | None = None
        self._tracked_pose: NDArray[np.float64] | None = None
        # Latest odometry; the reference is the odometry at the tracked pose (no gate: PIL runs on every scan).
        self.odometry = OdometryGate()
        self._switch_evidence = 0.0

    # -- Localizer protocol -------------------------------------------------------
    def set_map(self, grid_map: GridMap) -> None:
        """Learn (or load) the pseudo-images of ``grid_map`` and their level functions for the set field of view.

        A scanner whose field of view or range differs from the settings is learned again
        by :meth:`prepare` or its first scan (with a warning).
        """
        self.grid_map = grid_map
        self.learning = None
        self._sheet_features = None
        if self.settings.tile_size < grid_map.resolution:
            self._emit("warn", f"tile_size {self.settings.tile_size:g} m is finer than the map's {grid_map.resolution:g} m "
                               "cells: PIL's tiles are the cells")
        self._learn()
        # The float32 distance field, gradients taken where sampled: 4 bytes a cell.
        self._distance_field = DistanceField(grid_map, compact=True)
        self.reinitialize()

    @property
    def tile_size(self) -> float:
        """``r`` [m]: the setting, or the map's cell when that is coarser (finer tiles would only repeat a cell)."""
        resolution = self.grid_map.resolution if self.grid_map is not None else 0.0
        return max(self.settings.tile_size, resolution)

    def prepare(self, scan: Scan) -> None:
        """Learn for this scanner's geometry now (field of view, range, beam layout) rather than in its first scan."""
        self._prepare(scan)

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
            function.name: self.learning.pseudo_image(decode_features(self._sheet_features[:, sheet, f]))
            for f, function in enumerate(self.level_functions)
        }

    # -- learning -----------------------------------------------------------------
    def _learn(self) -> None:
        if self.grid_map is None:
            raise MapError("PIL has no map to learn")
        settings = self.settings
        self._sheet_features = None  # the old features go before the new learning is made
        self.learning = None
        if self._caster is None or self._caster.grid_map is not self.grid_map or self._caster.max_range != self._range:
            self._caster = None
            self._caster = ClassifiedRayCaster(self.grid_map, max_range=self._range,
                                               unknown_stops=settings.unknown_blocks and not settings.mark_unknown_rays)
        self.learning = learn_pseudo_images(
            self.grid_map,
            tile_size=self.tile_size,
            angle_count=self._layout.angle_count,
            max_range=self._range,
            unknown_blocks=settings.unknown_blocks,
            mark_unknown=settings.mark_unknown_rays,
            cache_dir=settings.cache_dir or None,
            use_cache=settings.use_cache,
            mmap_bytes=int(settings.cache_mmap_mb * 2**20),
            show_progress=settings.show_progress,
            log=self._emit,
            caster=self._caster,
        )
        self._tile_index = self.learning.tile_index_image()
        self._sheets_key = None
        self._mapping = None
        # The level functions for a scan centred on the laser's x axis; another centre recomputes them.
        self._ensure_sheets(-0.5 * (self._layout.sensor_count - 1) * self._layout.sensor_spacing)

    def prepared_for(self, scan: Scan) -> bool:
        """Whether this scan's geometry needs no learning and no level functions beyond what PIL holds.

        A beam more or less, or an ``angle_min`` a hair off, are the same scanner (an RPLIDAR's beam
        count varies from scan to scan): only what :meth:`prepare` would recompute counts.
        """
        if self.grid_map is None or self.learning is None:
            return False
        try:
            reasons, _, _ = self._geometry_change(scan)
        except ScanError:
            return True  # on_scan says why; there is nothing to prepare for it
        if reasons:
            return False
        mapping = self._mapping
        if mapping is None or not mapping.matches(scan):
            mapping = BeamMapping(self._layout, scan, self.settings.beam_mapping)
        return self._sheet_features is not None and self._sheets_key == self._sheets_key_for(
            float(mapping.sensor_angles[0]))

    def _geometry_change(self, scan: Scan) -> tuple[list[str], float, float]:
        """Why this scan's field of view or range needs another layout (none: it fits), and that layout's
        field of view [rad] and range [m]."""
        if scan.beam_count < 2:
            raise ScanError(f"PIL needs a scan of at least 2 beams, got {scan.beam_count}")
        if self.grid_map is not None and not scan.range_max >= self.grid_map.resolution:
            # learning for it would cast every ray for a range that sees no cell
            raise ScanError(f"scan range_max {scan.range_max!r} m is shorter than a map cell "
                            f"({self.grid_map.resolution:g} m): no scanner's")
        increment = abs(float(scan.angles[1] - scan.angles[0]))
        if not np.isfinite(increment) or increment <= 0.0:
            raise ScanError(f"scan angle increment {increment!r} is unusable")
        fov = scan.field_of_view
        scan_full = fov >= 2.0 * math.pi - 0.5 * increment
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
        return reasons, new_fov, new_range

    def _prepare(self, scan: Scan) -> dict[str, Any]:
        """Check the scan against the learning; relearn (with a warning) when its geometry differs."""
        if self.grid_map is None or self.learning is None:
            raise MapError("PIL has no map yet: call set_map first")
        reasons, new_fov, new_range = self._geometry_change(scan)
        notes: dict[str, Any] = {}
        if reasons:
            layout = replace(self._layout, field_of_view=new_fov)
            if layout.angle_count == self.learning.angle_count and abs(new_range - self._range) <= 1e-3:
                # The learned rays do not depend on the field of view, only their directions' count.
                text = "; ".join(reasons) + (f": the learned rays serve for {math.degrees(new_fov):.1f} deg as they are, "
                                             "its level functions are computed again")
                self._layout = layout
                self._mapping = None
            else:
                text = "; ".join(reasons) + f": relearning for {math.degrees(new_fov):.1f} deg and R = {new_range:.2f} m"
                self._layout = layout
                self._range = new_range
                self._learn()
                notes["relearned"] = True
            self._emit("warn", text)
            notes["warning"] = text
        if self._mapping is None or not self._mapping.matches(scan):
            self._mapping = BeamMapping(self._layout, scan, self.settings.beam_mapping)
        self._ensure_sheets(float(self._mapping.sensor_angles[0]))
        return notes

    def _ensure_sheets(self, first_sensor_angle: float) -> None:
        """Level functions of every tile on every heading sheet (recomputed when the sensor offset changes)."""
        assert self.learning is not None
        sectors = sheet_sectors(self._layout, first_sensor_angle, self.settings.reference_headings)
        key = self._sheets_key_for(first_sensor_angle, sectors)
        if self._sheets_key == key and self._sheet_features is not None:
            return
        self._sheet_features = None
        self._sheet_features = self._level_bytes(sectors)
        self._level_index = LevelIndex(self._sheet_features, self.learning.tile_lines, self.learning.tile_columns)
        self._sheets_key = key

    def _sheets_key_for(self, first_sensor_angle: float,
                        sectors: NDArray[np.int64] | None = None) -> tuple[int, ...]:
        """The learned directions each heading sheet starts at, for a scan whose first sensor is at this angle."""
        if sectors is None:
            sectors = sheet_sectors(self._layout, first_sensor_angle, self.settings.reference_headings)
        return tuple(int(start) for start in sectors[:, 0])

    def _level_bytes(self, sectors: NDArray[np.int64]) -> NDArray[np.uint8]:
        """Level functions ``(T, S, F)`` of every tile and sheet as bytes, computed in pieces."""
        assert self.learning is not None
        settings = self.settings
        names = [f.name for f in self.level_functions]
        codes = self.learning.codes
        out = np.empty((codes.shape[0], sectors.shape[0], len(names)), dtype=np.uint8)
        step = 1 << 16
        for first in range(0, codes.shape[0], step):
            out[first : first + step] = encode_features(learned_level_features(
                codes[first : first + step], sectors, names, pq_low=settings.pq_low, pq_high=settings.pq_high,
                low_level=settings.low_quantile_level, high_level=settings.high_quantile_level,
            ))
        return out

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
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], int, NDArray[np.bool_]]:
        """Candidate tiles in the searched area, global sentinels outside the window, the count
        passing equation (4) in the searched area (among the tiles scored), and their pass mask.

        Candidates are taken passing equation (4) first, then by rank: ``min_candidates`` of
        them, or (``min_candidates`` 0, the paper's filter) the passing ones only, at most
        ``max_candidates``.
        """
        assert self.learning is not None and self._sheet_features is not None and self._level_index is not None
        settings = self.settings
        live = self._live_features(profile)
        pass_mask = np.zeros(self.learning.tile_count, dtype=bool)
        sentinels: NDArray[np.int64] = np.zeros(0, dtype=np.int64)
        wanted = settings.min_candidates if settings.min_candidates > 0 else settings.max_candidates
        if centre is None:
            ranked = self._level_index.query(live, self._alphas, self._sigmas, settings.rank_term_cap, wanted)
            area_tiles, rank, passes = ranked.tiles, ranked.rank, ranked.passes
        else:
            area_tiles = self._window_tiles(centre)
            passes, rank = rank_tiles(self._sheet_features[area_tiles], live, self._alphas, self._sigmas,
                                      settings.rank_term_cap)
            if settings.global_candidates > 0:
                ranked = self._level_index.query(live, self._alphas, self._sigmas, settings.rank_term_cap,
                                                 settings.global_candidates + area_tiles.size)
                outside = np.flatnonzero(~np.isin(ranked.tiles, area_tiles))
                sentinels = ranked.tiles[outside[select_ranked(ranked.rank[outside], ranked.passes[outside],
                                                               settings.global_candidates)]]
        pass_mask[area_tiles[passes]] = True
        chosen = select_ranked(rank, passes, wanted)
        if settings.min_candidates == 0:
            chosen = chosen[passes[chosen]]
        return area_tiles[chosen], sentinels, int(passes.sum()), pass_mask

    def _window_tiles(self, centre: NDArray[np.float64]) -> NDArray[np.int64]:
        """Tiles whose centre is within the square window around ``centre``."""
        assert self.learning is not None and self._tile_index is not None
        grid = self.learning.grid
        half = 0.5 * self.settings.window_size
        low = np.floor(grid.world_to_image(centre[:2] - half) - 1e-9).astype(np.int64)
        high = np.ceil(grid.world_to_image(centre[:2] + half) + 1e-9).astype(np.int64)
        low = np.clip(low, 0, [grid.lines, grid.columns])
        high = np.clip(high + 1, 0, [grid.lines, grid.columns])
        block = self._tile_index[low[0] : high[0], low[1] : high[1]]
        tiles = block[block >= 0].astype(np.int64)
        offset = np.abs(self.learning.tile_centres[tiles] - centre[None, :2])
        return np.sort(tiles[(offset[:, 0] <= half) & (offset[:, 1] <= half)])

    def _search(self, scan: Scan, profile: LiveProfile, centre: NDArray[np.float64] | None) -> _Search:
        assert self.learning is not None and self._caster is not None and self._distance_field is not None
        settings = self.settings
        learning = self.learning
        chosen, sentinels, filter_count, pass_mask = self._select_tiles(profile, centre)
        self._last_passes = pass_mask
        table = self._table(profile)
        found = []
        neighbours = None
        if settings.coarse_block > 1:
            assert self._tile_index is not None
            neighbours = (self._tile_index, learning.tile_lines, learning.tile_columns)
        for tiles, keep in ((chosen, settings.fine_candidates), (sentinels, settings.global_candidates)):
            if tiles.size:
                if neighbours is not None:
                    tiles = self._block_representatives(tiles)
                found.append(correlate_tiles(learning.codes, tiles, table, profile.valid, self._layout.directions_per_sensor,
                                             keep=keep, per_tile=settings.shift_hypotheses,
                                             coarse_sensors=settings.coarse_sensors, neighbours=neighbours))
        if not found:
            return _Search(np.zeros((0, 3)), np.zeros(0), filter_count, 0, pass_mask, np.zeros(0, np.int64), 0,
                           np.zeros(0, dtype=bool))
        tiles = np.concatenate([h.tiles for h in found])
        shifts = np.concatenate([h.shifts for h in found])
        scores = np.concatenate([h.costs for h in found])
        is_sentinel = np.concatenate([np.full(h.tiles.size, i == 1 and centre is not None) for i, h in enumerate(found)])
        thetas = wrap_angle(shifts * learning.angle_step - profile.sensor_angles[0])
        poses = np.column_stack([learning.tile_centres[tiles], np.atleast_1d(thetas)])
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
                max_shift=self.tile_size,
                truncation=settings.refine_truncation,
            )
            both = np.concatenate([poses[:refined], better])
            recast = profile_costs(self._pose_codes(both, profile), table, profile.valid)
            use_refined = recast[refined:] <= recast[:refined]
            poses[:refined] = np.where(use_refined[:, None], better, poses[:refined])
            scores[:refined] = np.minimum(recast[:refined], recast[refined:])
            order = np.argsort(scores, kind="stable")
            poses, scores, tiles, is_sentinel = poses[order], scores[order], tiles[order], is_sentinel[order]
        if centre is not None and scores.size:
            # Equal scores (a symmetric place and its twin): the one nearer the tracked pose first.
            near = np.hypot(poses[:, 0] - centre[0], poses[:, 1] - centre[1])
            order = np.lexsort((near, np.round(scores, 6)))
            poses, scores, tiles, is_sentinel = poses[order], scores[order], tiles[order], is_sentinel[order]
        return _Search(poses, scores, filter_count, len(poses), pass_mask, tiles, refined, is_sentinel)

    def _table(self, profile: LiveProfile) -> NDArray[np.float32]:
        settings = self.settings
        return cost_table(profile, settings.score_truncation, unknown_cost=settings.unknown_cost,
                          short_cost=settings.short_cost, correlation=settings.match_score == "correlation")

    def _block_representatives(self, tiles: NDArray[np.int64]) -> NDArray[np.int64]:
        """The first tile of ``tiles`` (ranked, best first) in each block of ``coarse_block`` x ``coarse_block`` tiles."""
        assert self.learning is not None
        block = self.settings.coarse_block
        keys = (self.learning.tile_lines[tiles].astype(np.int64) // block) * (self.learning.grid.columns // block + 1) + (
            self.learning.tile_columns[tiles].astype(np.int64) // block
        )
        _, first = np.unique(keys, return_index=True)
        return tiles[np.sort(first)]

    def _pose_codes(self, poses: NDArray[np.float64], profile: LiveProfile) -> NDArray[np.uint8]:
        """Learned bytes ``(P, N_s)`` of the sensors at arbitrary poses, cast as the learning casts them."""
        assert self._caster is not None
        ranges, outcome = self._caster.cast(poses, profile.sensor_angles)
        if self.settings.mark_unknown_rays:
            ranges[outcome == RAY_UNKNOWN] = np.nan
        return encode_ranges(ranges, self._range)

    def _map_vouches_for(self, pose: NDArray[np.float64], scan: Scan) -> bool:
        """Whether ``localized_min_explained`` of the scan's end points lie within two cells of a mapped
        obstacle at ``pose`` (``map_coverage``; no hit to judge by: no)."""
        share = self.settings.localized_min_explained
        if share <= 0.0 or self.grid_map is None:
            return True
        explained = scan_explained(self.grid_map, pose[None, :], scan)[0]
        return bool(explained >= share)

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
        elif ambiguous or best_score > settings.kidnap_score or not self._map_vouches_for(best, scan):
            # A best score the window search would take for a kidnapping is the whole map's best guess, and
            # so is a place the map cannot vouch for: not a fix the node stands behind (docs/pil.md, "Status").
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
            [self.tile_size**2 / 12.0, self.tile_size**2 / 12.0, self._layout.sensor_spacing**2 / 12.0]
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
