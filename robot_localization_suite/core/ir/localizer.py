"""Information-retrieval global initialisation feeding a small particle filter.

O. Aycard and C. Brouard, "A new tool to initialize global localization for a
mobile robot" (seed 001). The scan the robot should perceive is precomputed
at every position of a grid over the map; a live scan is turned into *hits*,
an inverted index finds the positions (x, y) whose patterns share the most
hits (step 1), an index built on the fly over every heading of those
positions ranks the poses (x, y, theta) by the idf-weighted hits they share
(step 2), and 100 particles drawn from the ranked poses are tracked with the
odometry motion model and an end-point sensor model, resampled at every
update (sections IV-C, IV-D).

Modules: ``ir_index.py`` (precomputation, patterns, the two-level index, the
cache), ``ir_query.py`` (steps 1 and 2, refinement), this one (settings,
:class:`IRLocalizer`: ``global_fix`` and tracking).

Interpretation of the paper (the choices it leaves open, written down)
-----------------------------------------------------------------------
* **Reading classes.** A reading is a *hit* when it returns within
  ``max_range``, a *no-return* otherwise (``inf``, at/above the sensor's
  ``range_max``, or beyond the model's ``max_range``), *invalid* when NaN,
  negative or below ``range_min``. Invalid readings are skipped: they carry
  no hit and neither cut nor anchor a pattern.
* **Pattern** (IV-B-1): a run of consecutive hits between two no-return
  readings (section IV-B-1, figure 8); readings beyond ``pattern_max_range``
  (5.5 m, the paper's laser range) count as no-returns for this purpose.
  Real scanners here reach 30-80 m, so indoors a whole 180-degree scan is
  often one run with no no-return at all, which the paper's definition cannot
  place (15 % of the Intel scans). ``split_at_jump`` (default 0.5 m) also
  cuts runs where consecutive ranges differ by more than that: a range
  discontinuity is as much a fixed point of the world as the edge of an empty
  area. ``split_at_jump = 0`` is the paper's definition. Runs shorter than
  ``min_pattern_beams`` are dropped.
* **First-level hit** (what the two-level index is keyed by; it must be
  computable from a live scan before its pose is known): ``(side, k, range
  bin)``, the quantised range of the beam ``k`` beams inside a pattern,
  counted from its delimiter at the start (``side`` 0) or at the end (1),
  for ``k < pattern_terms_per_end``. It is invariant to the heading. The end
  of a live pattern cut by the edge of a limited field of view is no
  delimiter; only its delimited end yields hits.
* **Positions and headings** (IV-A-2): every free cell centre of a 5 cm grid
  at least ``min_clearance`` from obstacles and unknown cells; one 360-degree
  fan per position (1-degree rays by default, quantised to bytes at 5 cm),
  rotated to each 5-degree heading instead of a cast per (x, y, theta).
  Patterns are taken on the full 360-degree fan, which contains the paper's
  two views at theta and theta + 180 degrees.
* **Step 1** (IV-B-3): for each live pattern, stored patterns are scored by
  the number of common hits (a live hit also matches the neighbouring range
  bins with ``soft_bin_weight``), the ``patterns_per_live_pattern`` best are
  normalised by the best score, and every position sums the normalised
  scores of its patterns times their frequency there; the
  ``step1_positions`` best positions go on.
* **Step 2** (IV-B-4): for every heading of those positions the expected
  scan is the rotated fan; a *second-level hit* is ``(beam index, range
  bin)`` of the live scan (a no-return is also a hit of its own bin when
  ``no_return_terms``); a pose holds it when its expected reading for that
  beam is within ``step2_tolerance_bins`` bins. The weight of a hit is the
  paper's idf, the number of indexed poses divided by the number of poses
  holding it (``idf_log``: its logarithm, the usual idf of information
  retrieval); a pose's score is the sum of the weights of the hits it holds
  (``use_idf = False``: plain counting, the paper's Table II ablation).
* **Beyond the paper** (the issue asks for a better list; each is a switch):
  the ``refine_candidates`` best poses of step 2 are aligned to the map by a
  few Gauss-Newton steps on the distance field and re-ranked by their mean
  end-point likelihood; poses within ``nms_distance`` / ``nms_angle`` of a
  better one are dropped so that the list holds distinct hypotheses.
  ``refine_candidates = 0`` and ``nms_distance = 0`` give the paper's list.
  A scan that has hits but no delimited pattern (a closed room seen whole)
  cannot be placed by step 1; step 2 then runs over a coarse lattice of about
  ``fallback_positions`` positions and the refinement pulls the best poses
  onto the map (``details["fallback"]`` says so; 0 = no candidates, as the
  paper). A scan with no hit at all has no candidates and ``details["reason"]``.
* **Tracking** (IV-C, IV-D): ``particle_count`` particles are drawn from the
  ranked candidates of the initialisation with probability 1 / rank (the
  paper takes "the 100 positions found"; one particle per hypothesis lost the
  right one to motion noise on the test floor whenever it was not alone at
  the top), copies spread over half a grid cell and half a heading step. An
  update happens after ``update_min_d`` metres or ``update_min_a`` radians of
  odometry (the paper's 1 m / 20 degrees): the shared odometry motion model
  moves the particles (the paper's velocity model needs velocities the bags
  do not carry), the end-point model scores each particle by the fraction of
  its hit end-points (at most ``max_beams``) that fall on occupied cells
  (within ``endpoint_tolerance``; 0 = the cell itself, as the paper), weights
  are that score to the power ``score_exponent`` (1 = the paper's vote; 4 by
  default, see :class:`IRSettings`), and the particles are resampled
  (low-variance) at every update. Between updates the particles follow
  odometry without noise, so every scan gets an estimate.
* **LOST**: when the best particle's end-point score stays below
  ``lost_score_threshold``, or below ``lost_score_ratio`` times its running
  average over the good updates, for ``lost_update_count`` updates in a row,
  the localizer initialises again from the current scan by itself.
* **Beyond the paper, tracking**: a place that looks like where the robot
  was (a twin room after a kidnapping) keeps the end-point scores high, so
  the LOST rule never fires. Every ``global_check_updates`` updates the scan
  is also fixed globally; when the fix's best pose, refined and scored as
  the tracked pose is, fits the map better by ``global_check_margin`` and is
  elsewhere, the filter restarts from the fix (``initialized_because`` =
  ``"better global fix"``).
* **Outputs**: after an initialisation the candidates are the ranked poses
  (best first) and the pose is the best of them (moved by odometry until the
  first update); afterwards the candidates are the particles and the pose is
  the weighted mean of the best-supported cluster (0.5 m, 25 degrees).
* **Bad input**: ``global_fix`` returns no candidates and
  ``details["reason"]`` for a scan with no valid reading or no hit;
  ``on_scan`` raises :class:`~.errors.ScanError` with that reason (the
  adapter logs it, throttled, and skips the scan) and keeps its state.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ScanError
from ..filter.odometry_gate import OdometryGate
from ..filter.particles import densest_neighbourhood_mean, low_variance_resample, weighted_pose_statistics
from ..filter.refinement import DistanceField, refine_poses
from ..grid_map import GridMap
from ..localizer import Estimate, LocalizerStatus
from ..motion import OdometryMotionModel
from ..scan import Scan
from ..se2 import compose, relative, wrap_angle
from .index import MAX_HIT_CODE, FanModel, IndexSettings, IRIndex
from .query import (
    live_pattern_terms,
    resample_scan,
    step1_positions,
    step2_poses,
    suppress_duplicates,
)

__all__ = ["IRSettings", "IRLocalizer", "IRIndex", "FanModel", "IndexSettings"]

_LOG = logging.getLogger(__name__)
# Added to reported covariances so that a collapsed cloud still gives a positive-definite one.
_COVARIANCE_FLOOR = np.diag([1e-6, 1e-6, 1e-8])


@dataclass(frozen=True)
class IRSettings:
    """Settings of the IR initialiser and its particle filter (units in brackets, source of each default).

    Scanner model (0 = taken from the first scan):
        beam_count, field_of_view [rad], max_range [m]: when all three are set the
            index is built as soon as the map arrives; ``max_range`` is also capped at
            what one-byte codes hold (254 * range_resolution).
        angular_resolution [rad]: the fan's ray spacing is the smallest multiple of the
            scanner's increment at least this (1 degree; the paper uses 1/3 degree).
    Precomputation (see :class:`~.ir_index.IndexSettings`):
        grid_resolution [m] (paper: 0.05), range_resolution [m] (0.05, the grid),
        min_clearance [m], unknown_blocks, pattern_max_range [m] (paper: 5.5),
        pattern_range_bin [m], pattern_terms_per_end, min_pattern_beams, split_at_jump [m].
    Query:
        heading_step [rad] (paper: 5 degrees), patterns_per_live_pattern and
        step1_positions (the paper's N, unstated), soft_bin_weight, weight_patterns_by_length,
        step2_range_bin [m], step2_tolerance_bins, use_idf (paper: True), idf_log (False: the
        paper's ratio; True: its logarithm, the usual idf), no_return_terms,
        refine_candidates (0 = the paper's ranking), refine_iterations, refine_sigma [m],
        refine_max_shift [m], refine_max_turn [rad], nms_distance [m], nms_angle [rad],
        max_candidates, fallback_positions (a scan step 1 cannot place, hits but no delimited
        pattern, goes to step 2 over about this many positions spread evenly; 0 = no candidates, the paper).
    Tracking:
        particle_count (paper: 100), update_min_d [m] (paper: 1 m), update_min_a [rad]
        (paper: 20 degrees), alpha1..alpha4 (nav2 names; 0.02 here, as mcl_baseline's config:
        nav2's 0.2 spreads 100 particles 0.45 m and 26 degrees per metre, 0.05 still let the cloud
        drift off on the Orebro log (correct rate 0.72), 0.01-0.02 tracked it at 0.98-1.0 and still
        cover the simulator's odometry (alpha3 0.05)),
        max_beams (end-points scored per update), endpoint_tolerance [m],
        score_exponent (paper: 1, the raw vote; 4 here: on the test floor the vote left 100
        particles 0.4-1.8 m wide and converging late, 4 keeps them 0.16-0.19 m wide from the
        second update, 10 and more lock onto look-alike places), lost_score_threshold,
        lost_score_ratio (an update is poor when the best end-point score is below the
        threshold or below this fraction of its running average: maps and sensors differ in
        how well a right pose scores), lost_update_count, global_check_updates (every this many
        updates the scan is also fixed globally and the filter restarts from that fix when its best
        pose fits the map better by global_check_margin than the tracked pose, both refined and
        scored alike; 0 = never, the paper. On a right track both scores agree to 1e-4; after the
        kidnappings of the simulated bags the true place scored 0.01-0.015 better than the twin the
        particles followed, so 0.01),
        localized_spread [m], seed.
    Cache:
        cache_dir ('' = ``$RLS_CACHE_DIR`` or ``~/.cache/robot_localization_suite``),
        use_cache, progress (tqdm bar while precomputing; off whatever this says when
        ``$TQDM_DISABLE`` is set, as in rls_bench's child runs: core/progress.py), cache_budget_mb [MB] (after writing
        an index, the least recently used ones in ``<cache_dir>/ir/`` are deleted down to this;
        0 = ``$RLS_CACHE_BUDGET_MB`` or 2048, room for 5-15 indexes of 120-400 MB; see core/cache.py).
    """

    beam_count: int = 0
    field_of_view: float = 0.0
    max_range: float = 0.0
    angular_resolution: float = math.radians(1.0)
    grid_resolution: float = 0.05
    range_resolution: float = 0.05
    min_clearance: float = 0.15
    unknown_blocks: bool = False
    pattern_max_range: float = 5.5
    pattern_range_bin: float = 0.10
    pattern_terms_per_end: int = 30
    min_pattern_beams: int = 3
    split_at_jump: float = 0.5
    heading_step: float = math.radians(5.0)
    patterns_per_live_pattern: int = 200
    step1_positions: int = 300
    soft_bin_weight: float = 0.5
    weight_patterns_by_length: bool = False
    step2_range_bin: float = 0.10
    step2_tolerance_bins: int = 1
    use_idf: bool = True
    idf_log: bool = False
    no_return_terms: bool = True
    refine_candidates: int = 300
    refine_iterations: int = 8
    refine_sigma: float = 0.15
    refine_max_shift: float = 0.3
    refine_max_turn: float = math.radians(10.0)
    nms_distance: float = 0.3
    nms_angle: float = math.radians(15.0)
    max_candidates: int = 100
    fallback_positions: int = 3000
    particle_count: int = 100
    update_min_d: float = 1.0
    update_min_a: float = math.radians(20.0)
    alpha1: float = 0.02
    alpha2: float = 0.02
    alpha3: float = 0.02
    alpha4: float = 0.02
    max_beams: int = 90
    endpoint_tolerance: float = 0.1
    score_exponent: float = 4.0
    lost_score_threshold: float = 0.3
    lost_score_ratio: float = 0.6
    lost_update_count: int = 3
    global_check_updates: int = 2
    global_check_margin: float = 0.01
    localized_spread: float = 0.5
    seed: int = 0
    cache_dir: str = ""
    use_cache: bool = True
    progress: bool = True
    cache_budget_mb: float = 0.0

    def __post_init__(self) -> None:
        positive = (
            "angular_resolution",
            "grid_resolution",
            "range_resolution",
            "pattern_max_range",
            "pattern_range_bin",
            "heading_step",
            "step2_range_bin",
            "refine_sigma",
            "localized_spread",
        )
        non_negative = (
            "field_of_view",
            "max_range",
            "min_clearance",
            "split_at_jump",
            "soft_bin_weight",
            "refine_max_shift",
            "refine_max_turn",
            "nms_distance",
            "nms_angle",
            "update_min_d",
            "update_min_a",
            "alpha1",
            "alpha2",
            "alpha3",
            "alpha4",
            "endpoint_tolerance",
            "score_exponent",
            "lost_score_threshold",
            "lost_score_ratio",
            "global_check_margin",
            "cache_budget_mb",
        )
        at_least_one = (
            "pattern_terms_per_end",
            "min_pattern_beams",
            "patterns_per_live_pattern",
            "step1_positions",
            "max_candidates",
            "particle_count",
            "max_beams",
            "lost_update_count",
        )
        non_negative_int = (
            "beam_count",
            "step2_tolerance_bins",
            "refine_candidates",
            "refine_iterations",
            "fallback_positions",
            "global_check_updates",
        )
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"IR setting {name} must be positive and finite, got {value!r}")
        for name in non_negative:
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"IR setting {name} must be >= 0 and finite, got {value!r}")
        for name in at_least_one:
            if int(getattr(self, name)) < 1:
                raise ValueError(f"IR setting {name} must be >= 1, got {getattr(self, name)!r}")
        for name in non_negative_int:
            if int(getattr(self, name)) < 0:
                raise ValueError(f"IR setting {name} must be >= 0, got {getattr(self, name)!r}")
        if self.field_of_view > 2.0 * math.pi + 1e-9:
            raise ValueError(f"IR setting field_of_view must be <= 2 pi, got {self.field_of_view!r}")
        if self.heading_step > math.pi:
            raise ValueError(f"IR setting heading_step must be <= pi, got {self.heading_step!r}")
        for name in ("lost_score_threshold", "lost_score_ratio"):
            if getattr(self, name) > 1.0:
                raise ValueError(f"IR setting {name} is a fraction <= 1, got {getattr(self, name)!r}")
        for name in ("pattern_range_bin", "step2_range_bin"):
            if getattr(self, name) < self.range_resolution:
                raise ValueError(
                    f"IR setting {name} must be >= range_resolution {self.range_resolution!r}, got {getattr(self, name)!r}"
                )

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> IRSettings:
        """Settings from a dict of (possibly more) values, e.g. ROS parameters; unknown keys are ignored."""
        names = {f.name: f for f in fields(cls)}
        kwargs = {}
        for name, value in values.items():
            if name in names:
                default = names[name].default
                kwargs[name] = type(default)(value) if isinstance(default, (bool, int, float, str)) else value
        return cls(**kwargs)

    def index_settings(self) -> IndexSettings:
        """The precomputation settings (and so the cache key) taken from the fields of the same names.

        :class:`~.ir_index.IndexSettings` has no defaults of its own: these are the only ones.
        """
        return IndexSettings(**{f.name: getattr(self, f.name) for f in fields(IndexSettings)})

    @property
    def heading_count(self) -> int:
        return max(1, int(round(2.0 * math.pi / self.heading_step)))

    def fan_model(self, increment: float, range_max: float) -> FanModel:
        """The fan for a scanner with this angular ``increment`` [rad] and ``range_max`` [m]."""
        increment = abs(increment)
        if not (np.isfinite(increment) and increment > 0.0):
            raise ScanError(f"scan angle increment {increment!r} is unusable for the IR precomputation")
        stride = max(1, int(math.ceil(self.angular_resolution / increment - 1e-6)))
        rays = max(8, int(round(2.0 * math.pi / (stride * increment))))
        cap = MAX_HIT_CODE * self.range_resolution
        limit = self.max_range if self.max_range > 0.0 else range_max
        return FanModel(rays=rays, max_range=float(min(limit, range_max, cap)), range_resolution=self.range_resolution)


class IRLocalizer:
    """The IR initialiser (a :class:`~.localizer.GlobalFixer`) and its particle tracker (a :class:`~.localizer.Localizer`).

    Args:
        settings: the method's settings.
        grid_map: optional map to start with (as :meth:`set_map`).
    """

    def __init__(self, settings: IRSettings | None = None, grid_map: GridMap | None = None) -> None:
        self.settings = settings or IRSettings()
        self.grid_map: GridMap | None = None
        self.index: IRIndex | None = None
        self._coarse: tuple[IRIndex, NDArray[np.int64]] | None = None
        self._field: DistanceField | None = None
        self._occupied_near: NDArray[np.bool_] | None = None
        self._rng = np.random.default_rng(self.settings.seed)
        self._motion = OdometryMotionModel(
            alpha1=self.settings.alpha1,
            alpha2=self.settings.alpha2,
            alpha3=self.settings.alpha3,
            alpha4=self.settings.alpha4,
        )
        # Latest odometry; the reference is the odometry at the last update (the particles' frame).
        self.odometry = OdometryGate(self.settings.update_min_d, self.settings.update_min_a)
        self._reset_tracking()
        if grid_map is not None:
            self.set_map(grid_map)

    # -- state ----------------------------------------------------------------------------
    def _reset_tracking(self) -> None:
        self.particles: NDArray[np.float64] | None = None
        self.weights: NDArray[np.float64] | None = None
        self.odometry.reset(force=False)
        self._low_score_updates = 0
        self._best_score = float("nan")
        self._score_average = float("nan")
        self._updates_since_check = 0
        self._fix_pose: NDArray[np.float64] | None = None

    @property
    def initialized(self) -> bool:
        return self.particles is not None

    # -- Localizer protocol ---------------------------------------------------------------------
    def set_map(self, grid_map: GridMap) -> None:
        """Use this map; builds (or loads) the index now when the scanner model is given by the settings."""
        self.grid_map = grid_map
        self.index = None
        self._field = DistanceField(grid_map)
        tolerance = self.settings.endpoint_tolerance
        if tolerance > 0.0:
            self._occupied_near = grid_map.distance_field() <= tolerance + 1e-6
        else:
            self._occupied_near = grid_map.occupied_mask
        self._reset_tracking()
        s = self.settings
        if s.beam_count > 0 and s.field_of_view > 0.0 and s.max_range > 0.0:
            self._build_index(s.fan_model(s.field_of_view / s.beam_count, s.max_range))

    def on_odometry(self, stamp: float, odom_pose: NDArray[np.float64]) -> None:
        """Record odometry; non-finite or older poses are ignored."""
        if self.odometry.add(stamp, odom_pose) and self.particles is not None and self.odometry.reference is None:
            self.odometry.reference = self.odometry.latest

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Particles drawn around ``pose`` with the (x, y, theta) covariance."""
        covariance = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
        covariance = 0.5 * (covariance + covariance.T) + np.eye(3) * 1e-9
        samples = self._rng.multivariate_normal(np.asarray(pose, dtype=np.float64), covariance, self.settings.particle_count)
        samples[:, 2] = wrap_angle(samples[:, 2])
        self._start_tracking(samples, np.full(len(samples), 1.0 / len(samples)))

    def reinitialize(self) -> None:
        """Forget the particles; the next scan initialises globally."""
        self._reset_tracking()

    def request_nomotion_update(self) -> None:
        self.odometry.request_update()

    def on_scan(self, scan: Scan) -> Estimate | None:
        """Initialise from this scan when needed, else track; an estimate for every usable scan.

        Raises:
            ScanError: the scan cannot initialise (no pattern: the reason says why) or has no hit
                to score the particles with; the state is unchanged (the adapter logs and skips it).
        """
        if self.grid_map is None:
            return None
        if not self.initialized:
            return self._initialise(scan, reason="start")
        if not scan.hit_mask.any():
            raise ScanError(f"scan at {scan.stamp:.3f} s has no hit to score the particles with")
        if self.odometry.due():
            estimate = self._update(scan)
            if estimate is not None:
                return estimate
            return self._initialise(scan, reason="lost")
        estimate = self._tracking_estimate(scan.stamp, self._predicted_particles(), {"phase": "tracking", "updated": False})
        if self._fix_pose is not None:
            estimate.pose = self._predicted_poses(self._fix_pose[None, :])[0]
        return estimate

    # -- GlobalFixer ----------------------------------------------------------------------------
    def global_fix(self, scan: Scan) -> Estimate:
        """Ranked candidate poses of the laser from this scan alone (best first).

        Returns an estimate with no candidates and ``details["reason"]`` when the
        scan holds no usable pattern.

        Raises:
            ScanError: no map yet, or a scanner geometry the precomputation cannot use.
        """
        if self.grid_map is None:
            raise ScanError("IR global fix needs a map first")
        s = self.settings
        index = self._index_for(scan)
        timings: dict[str, float] = {}
        start = time.perf_counter()
        live = resample_scan(scan, index.fan)
        details: dict[str, Any] = {"phase": "initialization", "positions": 0, "live_patterns": 0}
        if not live.valid.any():
            return self._no_candidates(scan.stamp, "no valid reading in the scan", details)
        terms, anchors = live_pattern_terms(live, index)
        details["live_patterns"] = len(terms)
        if not live.hit_mask.any():
            return self._no_candidates(scan.stamp, "no pattern: every reading is a no-return", details)
        fallback = None
        if terms:
            position_ids, _ = step1_positions(
                index,
                terms,
                patterns_per_live_pattern=s.patterns_per_live_pattern,
                positions=s.step1_positions,
                soft_weight=s.soft_bin_weight,
                weight_by_length=s.weight_patterns_by_length,
            )
            if len(position_ids) == 0:
                fallback = "no stored pattern shares a hit with the scan's patterns"
        elif len(anchors):
            fallback = "no pattern: the scan is one run of hits with no delimiting no-return or range jump"
        else:
            fallback = (
                f"no pattern: no run of at least {s.min_pattern_beams} hits within {index.settings.pattern_max_range} m"
            )
        if fallback is not None:
            if s.fallback_positions <= 0:
                return self._no_candidates(scan.stamp, fallback, details)
            # Step 1 cannot place the scan: step 2 over a coarse lattice of all positions instead.
            details["fallback"] = fallback
            position_ids = self._coarse_positions(index)
        timings["step1_ms"] = (time.perf_counter() - start) * 1e3
        details["positions"] = len(position_ids)
        details["step1_xy"] = index.positions[position_ids]
        mid = time.perf_counter()
        poses, scores = step2_poses(
            index,
            live,
            position_ids,
            heading_count=s.heading_count,
            range_bin=s.step2_range_bin,
            tolerance_bins=s.step2_tolerance_bins,
            use_idf=s.use_idf,
            no_return_terms=s.no_return_terms,
            idf_log=s.idf_log,
        )
        timings["step2_ms"] = (time.perf_counter() - mid) * 1e3
        if len(poses) == 0:
            return self._no_candidates(scan.stamp, "step 2 found no pose sharing a hit with the scan", details)
        mid = time.perf_counter()
        poses, scores = self._rerank(live, poses, scores)
        details["best_score"] = float(scores[0]) if len(scores) else 0.0
        timings["refine_ms"] = (time.perf_counter() - mid) * 1e3
        timings["total_ms"] = (time.perf_counter() - start) * 1e3
        details.update(timings)
        weights = np.maximum(scores, 0.0)
        weights = weights / weights.sum() if weights.sum() > 0 else np.full(len(scores), 1.0 / len(scores))
        return Estimate(
            stamp=scan.stamp,
            pose=poses[0].copy(),
            covariance=_covariance(poses, weights),
            status=LocalizerStatus.AMBIGUOUS if len(poses) > 1 else LocalizerStatus.LOCALIZED,
            candidates=poses,
            candidate_weights=weights,
            details=details,
        )

    # -- internals: index -----------------------------------------------------------------------
    def _index_for(self, scan: Scan) -> IRIndex:
        if self.index is None:
            if scan.beam_count < 2:
                raise ScanError(f"IR needs scans of at least 2 beams to learn the scanner, got {scan.beam_count}")
            increment = float(scan.angles[1] - scan.angles[0])
            self._build_index(self.settings.fan_model(increment, scan.range_max))
        assert self.index is not None
        return self.index

    def _coarse_positions(self, index: IRIndex) -> NDArray[np.int64]:
        """About ``fallback_positions`` positions evenly spread over the map (every n-th lattice row and column)."""
        if self._coarse is None or self._coarse[0] is not index:
            lattice = np.rint((index.positions - index.positions.min(axis=0)) / index.settings.grid_resolution).astype(np.int64)
            stride = max(1, int(math.ceil(math.sqrt(len(index.positions) / self.settings.fallback_positions))))
            chosen = np.flatnonzero((lattice[:, 0] % stride == 0) & (lattice[:, 1] % stride == 0))
            self._coarse = (index, chosen)
        return self._coarse[1]

    def _build_index(self, fan: FanModel) -> None:
        assert self.grid_map is not None
        s = self.settings
        self.index = IRIndex.load_or_build(
            self.grid_map,
            fan,
            s.index_settings(),
            cache_dir=Path(s.cache_dir).expanduser() if s.cache_dir else None,
            use_cache=s.use_cache,
            progress=s.progress,
            cache_budget_mb=s.cache_budget_mb,
        )
        _LOG.info("IR index ready: %s", self.index.describe())

    def _rerank(
        self, live: Any, poses: NDArray[np.float64], scores: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Refinement and duplicate suppression of the step-2 ranking (beyond the paper; see the docstring)."""
        s = self.settings
        count = min(s.refine_candidates, len(poses))
        if count > 0 and self._field is not None and live.hit_mask.any():
            hits = live.hit_mask
            refined, likelihood = refine_poses(
                self._field,
                poses[:count],
                live.angles[hits],
                live.ranges[hits],
                iterations=s.refine_iterations,
                sigma=s.refine_sigma,
                max_shift=s.refine_max_shift,
                max_turn=s.refine_max_turn,
            )
            order = np.argsort(-likelihood, kind="stable")
            head, head_scores = refined[order], likelihood[order]
            keep = suppress_duplicates(head, distance=s.nms_distance, angle=s.nms_angle, limit=s.max_candidates)
            head, head_scores = head[keep], head_scores[keep]
            if len(head) < s.max_candidates and count < len(poses):
                # The unrefined rest follows, ranked by step 2, scores below every refined one.
                tail = poses[count:]
                tail_keep = suppress_duplicates(
                    tail, distance=s.nms_distance, angle=s.nms_angle, limit=s.max_candidates - len(head)
                )
                tail_scores = scores[count:][tail_keep]
                tail_scores = tail_scores / max(float(scores.max()), 1e-12) * float(head_scores.min(initial=1.0)) * 0.5
                head = np.vstack([head, tail[tail_keep]])
                head_scores = np.concatenate([head_scores, tail_scores])
            return head, head_scores
        keep = suppress_duplicates(poses, distance=s.nms_distance, angle=s.nms_angle, limit=s.max_candidates)
        return poses[keep], scores[keep]

    # -- internals: tracking --------------------------------------------------------------------
    def _no_candidates(self, stamp: float, reason: str, details: dict[str, Any]) -> Estimate:
        details = {**details, "reason": reason}
        return Estimate(
            stamp=stamp,
            pose=np.full(3, np.nan),
            covariance=np.full((3, 3), np.nan),
            status=LocalizerStatus.LOST,
            candidates=np.zeros((0, 3)),
            candidate_weights=np.zeros(0),
            details=details,
        )

    def _initialise(self, scan: Scan, *, reason: str) -> Estimate:
        """Global fix and particles from it.

        Raises:
            ScanError: the scan gives no candidate (the reason says why); the next scan tries again.
        """
        estimate = self.global_fix(scan)
        if len(estimate.candidates) == 0:
            self._reset_tracking()
            raise ScanError(f"IR initialisation from the scan at {scan.stamp:.3f} s: {estimate.details['reason']}")
        return self._start_from_fix(estimate, reason)

    def _start_from_fix(self, estimate: Estimate, reason: str) -> Estimate:
        estimate.details["initialized_because"] = reason
        count = self.settings.particle_count
        candidates = estimate.candidates
        # Drawn from the ranked list with probability 1 / rank (the ranking is the evidence: the first
        # candidate gets about a fifth of 100 particles, the hundredth one at most one); copies are spread
        # over half a grid cell and half a heading step so that they explore the hypothesis.
        rank_prior = 1.0 / np.arange(1, len(candidates) + 1)
        drawn = np.sort(low_variance_resample(rank_prior, count, self._rng))
        particles = candidates[drawn].copy()
        copies = np.concatenate([[False], drawn[1:] == drawn[:-1]])
        spread = np.array([self.settings.grid_resolution, self.settings.grid_resolution, self.settings.heading_step])
        particles[copies] += self._rng.uniform(-0.5, 0.5, size=(int(copies.sum()), 3)) * spread
        particles[:, 2] = wrap_angle(particles[:, 2])
        self._start_tracking(particles, np.full(count, 1.0 / count))
        self._best_score = float("nan")
        # Until the first update the estimate is the fix's best pose (moved by odometry), not the
        # densest particle cluster: several look-alike candidates can outnumber the best one.
        self._fix_pose = estimate.pose.copy()
        return estimate

    def _global_check(self, scan: Scan, estimate: Estimate) -> Estimate:
        """Restart from a global fix that fits the map clearly better than the tracked pose (see the docstring)."""
        s = self.settings
        self._updates_since_check = 0
        fix = self.global_fix(scan)
        if len(fix.candidates) == 0 or self._field is None or self.index is None:
            return estimate
        live = resample_scan(scan, self.index.fan)
        hits = live.hit_mask
        _, tracked = refine_poses(
            self._field,
            estimate.pose[None, :],
            live.angles[hits],
            live.ranges[hits],
            iterations=s.refine_iterations,
            sigma=s.refine_sigma,
            max_shift=s.refine_max_shift,
            max_turn=s.refine_max_turn,
        )
        estimate.details["global_check"] = {"tracked_score": float(tracked[0]), "fix_score": fix.details["best_score"]}
        far = float(np.hypot(*(fix.pose[:2] - estimate.pose[:2]))) > max(s.nms_distance, 0.5)
        if far and fix.details["best_score"] > float(tracked[0]) + s.global_check_margin:
            return self._start_from_fix(fix, "better global fix")
        return estimate

    def _start_tracking(self, particles: NDArray[np.float64], weights: NDArray[np.float64]) -> None:
        self.particles = particles
        self.weights = weights
        self.odometry.mark_updated(self.odometry.latest)
        self._low_score_updates = 0

    def _predicted_particles(self) -> NDArray[np.float64]:
        """Particles moved by the odometry since the last update, without noise."""
        assert self.particles is not None
        return self._predicted_poses(self.particles)

    def _predicted_poses(self, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        odom, reference = self.odometry.latest, self.odometry.reference
        if odom is None or reference is None:
            return poses
        return compose(poses, relative(reference, odom))

    def endpoint_scores(self, scan: Scan, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        """Section IV-C-2: fraction of the scan's hit end-points (at most ``max_beams``) on occupied cells."""
        assert self.grid_map is not None and self._occupied_near is not None
        beams = scan.subsample(self.settings.max_beams)
        angles, ranges = beams.hits()
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(ranges) == 0:
            return np.zeros(len(poses))
        heading = poses[:, 2:3] + angles[None, :]
        points = np.stack(
            [poses[:, 0:1] + ranges * np.cos(heading), poses[:, 1:2] + ranges * np.sin(heading)], axis=-1
        )
        cells = self.grid_map.world_to_cell(points)
        inside = self.grid_map.in_bounds(cells)
        hit = np.zeros(inside.shape, dtype=bool)
        hit[inside] = self._occupied_near[cells[..., 1][inside], cells[..., 0][inside]]
        return hit.mean(axis=1)

    def _update(self, scan: Scan) -> Estimate | None:
        """Predict, weight, resample. None when the filter declares itself lost."""
        assert self.particles is not None
        s = self.settings
        odom, reference = self.odometry.latest, self.odometry.reference
        if odom is not None and reference is not None:
            moved = self._motion.sample(self.particles, reference, odom, self._rng)
        else:
            moved = self.particles
        self.odometry.mark_updated(reference if odom is None else odom)
        self._fix_pose = None
        scores = self.endpoint_scores(scan, moved)
        best = float(scores.max(initial=0.0))
        self._best_score = best
        average = self._score_average
        floor = s.lost_score_threshold
        if np.isfinite(average):
            floor = max(floor, s.lost_score_ratio * average)
        if best < floor:
            self._low_score_updates += 1
            if self._low_score_updates >= s.lost_update_count:
                self._reset_tracking()
                return None
        else:
            self._low_score_updates = 0
            # Running average of the good updates' best scores (rate 0.2 after the first).
            self._score_average = best if not np.isfinite(average) else 0.8 * average + 0.2 * best
        weights = scores**s.score_exponent if s.score_exponent != 1.0 else scores.copy()
        if weights.sum() <= 0.0:
            weights = np.ones(len(moved))
        weights /= weights.sum()
        # The estimate comes from the weighted particles (the best-fitting cluster), then they are resampled.
        estimate = self._tracking_estimate(
            scan.stamp, moved, {"phase": "tracking", "updated": True, "best_endpoint_score": best}, weights
        )
        chosen = low_variance_resample(weights, s.particle_count, self._rng)
        self.particles = moved[chosen]
        self.weights = np.full(s.particle_count, 1.0 / s.particle_count)
        # Pose of the best-scoring particle before resampling, for diagnostics.
        estimate.details["best_particle"] = moved[int(np.argmax(scores))].tolist()
        self._updates_since_check += 1
        if s.global_check_updates and self._updates_since_check >= s.global_check_updates:
            return self._global_check(scan, estimate)
        return estimate

    def _tracking_estimate(
        self,
        stamp: float,
        particles: NDArray[np.float64],
        details: dict[str, Any],
        weights: NDArray[np.float64] | None = None,
    ) -> Estimate:
        s = self.settings
        if weights is None:
            weights = self.weights if self.weights is not None else np.full(len(particles), 1.0 / len(particles))
        pose = densest_neighbourhood_mean(particles, weights)
        _, covariance = weighted_pose_statistics(particles, weights)
        # The cloud's xy spread [m]: root of the summed position variances (RMS distance to the centroid).
        spread = float(np.sqrt(max(covariance[0, 0] + covariance[1, 1], 0.0)))
        covariance = covariance + _COVARIANCE_FLOOR
        details = {**details, "particles": len(particles), "spread_m": spread, "low_score_updates": self._low_score_updates}
        if np.isfinite(self._best_score):
            details.setdefault("best_endpoint_score", self._best_score)
        status = LocalizerStatus.LOCALIZED if spread <= s.localized_spread else LocalizerStatus.AMBIGUOUS
        if self._low_score_updates > 0:
            status = LocalizerStatus.LOST
        return Estimate(
            stamp=stamp,
            pose=pose,
            covariance=covariance,
            status=status,
            candidates=particles.copy(),
            candidate_weights=weights.copy(),
            details=details,
        )

    def describe(self) -> dict[str, Any]:
        """Settings and index sizes, for reports."""
        return {"settings": asdict(self.settings), "index": self.index.describe() if self.index else None}


def _covariance(poses: NDArray[np.float64], weights: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weighted covariance of (x, y, theta) (heading wrapped around the mean), with a small floor."""
    return weighted_pose_statistics(poses, weights)[1] + _COVARIANCE_FLOOR
