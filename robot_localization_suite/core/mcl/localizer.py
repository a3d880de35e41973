"""Monte Carlo localization at the level of nav2_amcl (``mcl_baseline``).

Adaptive (KLD-sampling) Augmented MCL as nav2_amcl (Player's ``amcl``) and the
seeds' baselines run it (004 section 5.1, Algorithm 2; 001 sections IV-C/D;
Thrun, Burgard & Fox, *Probabilistic Robotics* table 8.3): particles over the
laser pose, prediction by the shared odometry motion model once the robot has
moved ``update_min_d`` or turned ``update_min_a``, correction by the
likelihood field or the beam model of :mod:`.sensor_models`, KLD-sized
low-variance resampling (:mod:`..filter.particles`) with Augmented-MCL
injection, and the estimate from the heaviest particle cluster.

Departures from nav2, each measured: a tempered log-likelihood weight with
adaptive tempering, a posterior-weighted recovery signal, measurement-guided
recovery sampling, selective resampling, alphas 0.02 and 50,000 particles for
a global start.

Notes (choices, departures, status, measured figures): docs/mcl.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

from ..filter.odometry_gate import OdometryGate
from ..filter.particles import (
    cluster_particles,
    kld_particle_count,
    low_variance_resample,
    normalize_log_weights,
    pose_spread,
    weighted_pose_statistics,
)
from ..grid_map import GridMap
from ..localizer import Estimate, LocalizerStatus
from ..metrics import map_coverage
from ..scan import Scan
from ..se2 import compose, relative, wrap_angle
from .rivals import RivalTracker
from .sensor_models import BeamModel, LikelihoodFieldModel, PartialMapScores
from .settings import LASER_MODEL_TYPES, RECOVERY_SAMPLINGS, ROBOT_MODEL_TYPES, MclSettings

__all__ = ["MclSettings", "MonteCarloLocalizer", "LASER_MODEL_TYPES", "ROBOT_MODEL_TYPES", "RECOVERY_SAMPLINGS"]

_MIN_INITIAL_STD_XY = 0.02  # [m]
_MIN_INITIAL_STD_YAW = 0.01  # [rad]
_RIVAL_SAMPLES = 128  # poses per rival hypothesis (docs/mcl.md, "Rival hypotheses")


@dataclass
class _Init:
    """A pending (re)initialisation: uniform when ``pose`` is None, else Gaussian."""

    pose: NDArray[np.float64] | None = None
    covariance: NDArray[np.float64] | None = None


@dataclass
class _Beams:
    angles: NDArray[np.float64]
    ranges: NDArray[np.float64]
    max_range: float


def _heaviest_first(weights: NDArray[np.float64], count: int) -> NDArray[np.int64]:
    """Indices of the ``count`` heaviest weights, heaviest first (O(N) selection, then a small sort)."""
    count = min(count, len(weights))
    if count <= 0:
        return np.zeros(0, dtype=np.int64)
    chosen = np.argpartition(-weights, count - 1)[:count] if count < len(weights) else np.arange(len(weights))
    return chosen[np.argsort(-weights[chosen], kind="stable")]


class _RunningAverage:
    """Exponential average ``w += alpha (x - w)`` from ``w = 0``, divided by ``1 - (1 - alpha)^n``.

    The division (the bias correction of Adam, Kingma & Ba 2015) makes the
    average of the first ``n << 1/alpha`` values their plain mean instead of
    the first value dragged slowly (nav2 starts ``w_slow`` at the first value:
    with ``alpha = 0.001`` the poor fit of an unconverged start then stays the
    reference for a thousand updates and hides a later collapse of the fit).
    ``alpha = 0`` keeps the first value, as nav2 does.
    """

    def __init__(self, alpha: float) -> None:
        self.alpha = float(alpha)
        self._raw = 0.0
        self._decay = 1.0
        self.value = 0.0

    def update(self, x: float, evidence: float = 1.0) -> None:
        """Move towards ``x`` by ``alpha * evidence``: ``evidence`` in [0, 1] is how much of a full value ``x`` is
        (0 leaves the average as it is)."""
        if self.alpha == 0.0:
            if self.value == 0.0:
                self.value = float(x)
            return
        if evidence <= 0.0:
            return
        rate = self.alpha * min(1.0, evidence)
        self._raw += rate * (float(x) - self._raw)
        self._decay *= 1.0 - rate
        self.value = self._raw / (1.0 - self._decay)


@dataclass
class MclCounters:
    """What the localizer skipped, for diagnostics and tests."""

    updates: int = 0
    skipped_scans: int = 0
    ignored_odometry: int = 0
    injected_particles: int = 0


class MonteCarloLocalizer:
    """Adaptive (KLD) Augmented Monte Carlo localization; implements :class:`Localizer`.

    Args:
        settings: the filter's settings (defaults: :class:`MclSettings`).
        grid_map: optional map to start with (else call :meth:`set_map`).
    """

    def __init__(self, settings: MclSettings | None = None, grid_map: GridMap | None = None) -> None:
        self.settings = settings or MclSettings()
        seed = None if self.settings.random_seed < 0 else int(self.settings.random_seed)
        self.rng = np.random.default_rng(seed)
        self.motion_model = self.settings.motion_model()
        self.tracking_motion_model = self.settings.tracking_motion_model()
        self.counters = MclCounters()
        self.grid_map: GridMap | None = None
        self._map_fingerprint: str | None = None
        self._sensor: LikelihoodFieldModel | BeamModel | None = None
        self._free_mask: NDArray[np.bool_] | None = None
        self.particles: NDArray[np.float64] = np.zeros((0, 3))
        self.log_weights: NDArray[np.float64] = np.zeros(0)
        # Odometry poses for interpolation at scan stamps; the reference is the odometry at the last update.
        self.odometry = OdometryGate(self.settings.update_min_d, self.settings.update_min_a)
        self.rivals = RivalTracker(self.settings.rival_odds, self.settings.max_rivals, _RIVAL_SAMPLES,
                                   self.settings.rival_separation)
        self._vouched: tuple[NDArray[np.float64], NDArray[np.float64] | None] | None = None  # _vouched_for
        self._reset_filter_state()
        self.last_estimate: Estimate | None = None
        self._selected: tuple[Scan, _Beams | None] | None = None  # the last scan's beams (a hybrid asks 3 times)
        # The node's set_initial_pose / initial_pose.* (registry.NodeSettings) arrive through set_initial_pose.
        self._pending: _Init | None = _Init()
        if grid_map is not None:
            self.set_map(grid_map)

    # -- Localizer protocol ---------------------------------------------------------
    def set_map(self, grid_map: GridMap) -> None:
        """Use ``grid_map``; a different map restarts the filter (around the last estimate if localized)."""
        fingerprint = grid_map.fingerprint()
        if fingerprint == self._map_fingerprint:
            return
        had_map = self.grid_map is not None
        self.grid_map = grid_map
        self._map_fingerprint = fingerprint
        s = self.settings
        if s.laser_model_type == "beam":
            self._sensor = BeamModel(
                grid_map,
                z_hit=s.z_hit,
                z_short=s.z_short,
                z_max=s.z_max,
                z_rand=s.z_rand,
                sigma_hit=s.sigma_hit,
                lambda_short=s.lambda_short,
            )
        else:
            self._sensor = LikelihoodFieldModel(
                grid_map, z_hit=s.z_hit, z_rand=s.z_rand, sigma_hit=s.sigma_hit, max_distance=s.laser_likelihood_max_dist,
                unknown_occupancy=s.unknown_occupancy, unmapped_weight=s.unmapped_obstacle_weight,
                unmapped_decay=s.unmapped_obstacle_decay,
            )
        self._free_mask = ~grid_map.occupied_mask
        # Load the compiled kernels now (map setup), not in the first update.
        if isinstance(self._sensor, LikelihoodFieldModel):
            self._sensor.load_kernels()
            if s.do_beamskip:
                self._sensor.beam_agreement(np.zeros((1, 3)), np.ones(1), np.zeros(1), np.ones(1),
                                            distance=s.beam_skip_distance)
        else:
            self._sensor.log_likelihood(np.zeros((1, 3)), np.zeros(1), np.ones(1), max_range=10.0)
        if had_map and self._pending is None:
            last = self.last_estimate
            if last is not None and last.status == LocalizerStatus.LOCALIZED:
                self._pending = _Init(last.pose.copy(), np.diag([s.initial_std_xy**2] * 2 + [s.initial_std_yaw**2]))
            else:
                self._pending = _Init()
        self._apply_pending()

    def on_odometry(self, stamp: float, odom_pose: NDArray[np.float64]) -> None:
        """Record an odometry pose ``(3,)`` [m, m, rad] at ``stamp`` [s]; older or non-finite ones are ignored."""
        if not self.odometry.add(stamp, odom_pose):
            self.counters.ignored_odometry += 1

    def set_initial_pose(self, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Restart with ``max_particles`` drawn around ``pose`` ``(3,)`` with ``covariance`` ``(3, 3)``."""
        pose_arr = np.asarray(pose, dtype=np.float64).reshape(3)
        cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
        if not (np.all(np.isfinite(pose_arr)) and np.all(np.isfinite(cov))):
            raise ValueError(f"initial pose {pose_arr.tolist()!r} / covariance must be finite")
        self._pending = _Init(pose_arr, cov)
        self._apply_pending()

    def reinitialize(self) -> None:
        """Spread ``max_particles`` uniformly over free space (global localization)."""
        self._pending = _Init()
        self._apply_pending()

    def request_nomotion_update(self) -> None:
        """Update on the next scan even if the robot has not moved."""
        self.odometry.request_update()

    def on_scan(self, scan: Scan) -> Estimate | None:
        """Filter update with ``scan`` (laser frame); ``None`` when no update was due or possible."""
        if self.grid_map is None or self._sensor is None or len(self.particles) == 0:
            self.counters.skipped_scans += 1
            return None
        beams = self._select_beams(scan)
        if beams is None:
            self.counters.skipped_scans += 1
            return None
        gate = self.odometry
        odom = gate.at(scan.stamp)
        moved = False
        if odom is not None:
            if gate.reference is None:
                gate.reference = odom
            else:
                moved = gate.moved(odom)
        if not (moved or gate.forced or self._contradicted(beams, odom)):
            return None
        # the hypothesis the unknown-space credit belongs to, before the gate moves on (_elsewhere)
        tracked = None if self.last_estimate is None else compose(self.last_estimate.pose,
                                                                   self.odometry_since_update(odom))
        # Every update moves the particles by the odometry since the last one, as nav2 does for a forced
        # update: one forced or contradicted below the thresholds (a robot turning in place) must not weigh
        # a scan at poses the robot has left (docs/mcl.md, "Standing still").
        if gate.reference is not None and odom is not None and not np.array_equal(odom, gate.reference):
            # the odometry's own noise once LOCALIZED; the wider noise keeps a searching cloud diverse (docs/mcl.md)
            motion = self.tracking_motion_model if self._ever_localized else self.motion_model
            self.particles = motion.sample(self.particles, gate.reference, odom, self.rng)
            self.rivals.predict(motion, gate.reference, odom, self.rng)
            gate.mark_updated(odom)
        else:
            gate.mark_updated(gate.reference)
        return self._update(scan.stamp, beams, tracked)

    def contradicts(self, scan: Scan, odom: NDArray[np.float64] | None) -> bool:
        """Whether ``scan``, at odometry ``odom`` (no update due), contradicts the filter: its fit at the last
        LOCALIZED pose moved by the odometry falls below ``lost_fit_ratio`` of the slow average, or the last update
        found the fit collapsed (docs/mcl.md, "Standing still"); ``standstill_check`` makes such a scan update."""
        beams = self._select_beams(scan) if self._sensor is not None else None
        return beams is not None and self._contradicts(beams, odom)

    def _contradicted(self, beams: _Beams, odom: NDArray[np.float64] | None) -> bool:
        """:meth:`contradicts`, with ``standstill_check``: the robot was carried away while standing; it updates."""
        return self.settings.standstill_check and self._contradicts(beams, odom)

    def _contradicts(self, beams: _Beams, odom: NDArray[np.float64] | None) -> bool:
        last, slow = self.last_estimate, self._scan_fit_slow.value
        if last is None or slow <= 0.0:
            return False
        if self.fit_dropped:
            return True
        if last.status is not LocalizerStatus.LOCALIZED:
            return False
        pose = compose(last.pose, self.odometry_since_update(odom))
        return bool(self._fit_at(pose[None, :], beams)[0] < self.settings.lost_fit_ratio * slow)

    def _fit_at(self, poses: NDArray[np.float64], beams: _Beams) -> NDArray[np.float64]:
        """:meth:`scan_fit` of already selected beams."""
        assert self._sensor is not None
        log_likelihood = self._scan_log_likelihood(poses, beams)
        log_likelihood[~self._pose_is_possible(poses)] = len(beams.angles) * self._sensor.floor_log_likelihood(
            beams.max_range)
        return np.asarray(np.exp(log_likelihood / len(beams.angles)), dtype=np.float64)

    # -- hooks for a composite localizer (core/hybrid) -------------------------------------
    def odometry_since_update(self, odom: NDArray[np.float64] | None) -> NDArray[np.float64]:
        """The motion ``odom`` reports since the last filter update, in that update's robot frame (zero if
        either is unknown): what moves the last estimate to ``odom``'s instant."""
        reference = self.odometry.reference
        return relative(reference, odom) if reference is not None and odom is not None else np.zeros(3)

    def scan_fit(self, poses: NDArray[np.float64], scan: Scan) -> NDArray[np.float64]:
        """Per laser pose ``(P, 3)``, how well ``scan`` fits there: the geometric-mean per-beam likelihood the
        status judges (``fit`` in the details; docs/mcl.md), the floor's for a pose off the map or in an obstacle.

        NaN for every pose before a map or for a scan without a usable beam.
        """
        pose_arr = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        beams = self._select_beams(scan) if self._sensor is not None else None
        if beams is None or len(pose_arr) == 0:
            return np.full(len(pose_arr), np.nan)
        return self._fit_at(pose_arr, beams)

    @property
    def fit_dropped(self) -> bool:
        """Whether the last update's fit over every beam fell below ``lost_fit_ratio`` of its slow average: the
        scan contradicts the cloud (a kidnapping drops it at once; a partial map lowers it slowly)."""
        slow = self._scan_fit_slow.value
        return slow > 0.0 and self._scan_fit < self.settings.lost_fit_ratio * slow

    def seed_from_poses(self, poses: NDArray[np.float64], weights: NDArray[np.float64], count: int,
                        std_xy: float, std_yaw: float) -> None:
        """Restart with ``count`` particles drawn around weighted poses (ranked global-fix candidates)
        with Gaussian spread, as :meth:`set_initial_pose` does around one pose. Ignored before a map."""
        if self.grid_map is None:
            return
        self._pending = None
        self.particles = self._draw_around(poses, weights, max(int(count), 1), std_xy, std_yaw)
        self.log_weights = np.zeros(len(self.particles))
        self._reset_filter_state()

    def weigh(self, log_likelihood: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> None:
        """Another sensor's measurement (a composite's cue, e.g. the hybrid's camera): ``log_likelihood`` maps poses
        ``(M, 3)`` to ``(M,)`` logs. Each particle's weight is multiplied by its likelihood, and each rival's odds
        by the measurement's Bayes factor against the cloud, as a scan weighs them; the next update's estimate,
        rivals and resampling follow."""
        if len(self.particles) == 0:
            return

        def finite(poses: NDArray[np.float64]) -> NDArray[np.float64]:
            values = np.asarray(log_likelihood(poses), dtype=np.float64).reshape(-1)
            return np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0)

        values = finite(self.particles)
        with np.errstate(divide="ignore"):
            cloud_log_predictive = float(logsumexp(np.log(self.weights) + values))
        self.log_weights = self.log_weights + values
        self.rivals.weigh_cue(finite, cloud_log_predictive)

    def inject_around(self, poses: NDArray[np.float64], weights: NDArray[np.float64], fraction: float,
                      std_xy: float, std_yaw: float) -> int:
        """Replace ``fraction`` of the particles by draws around weighted poses; returns how many.

        A resampling, as Augmented MCL's injection (the rest is drawn from the current weights,
        then every weight is equal), but around given poses instead of uniform ones.
        """
        count = len(self.particles)
        injected = min(count, int(round(fraction * count)))
        if injected == 0 or self.grid_map is None:
            return 0
        kept = self.particles[low_variance_resample(self.weights, count - injected, self.rng)]
        self.particles = np.vstack([kept, self._draw_around(poses, weights, injected, std_xy, std_yaw)])
        self.log_weights = np.zeros(count)
        self.counters.injected_particles += injected
        self._moved_since_localized = False  # particles the motion model did not put there
        return injected

    def _draw_around(self, poses: NDArray[np.float64], weights: NDArray[np.float64], count: int,
                     std_xy: float, std_yaw: float) -> NDArray[np.float64]:
        centres = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        share = np.maximum(np.asarray(weights, dtype=np.float64).reshape(-1), 0.0)
        share = share / share.sum() if share.sum() > 0.0 else np.full(len(centres), 1.0 / len(centres))
        chosen = centres[low_variance_resample(share, count, self.rng)]
        spread = np.array([max(std_xy, _MIN_INITIAL_STD_XY)] * 2 + [max(std_yaw, _MIN_INITIAL_STD_YAW)])
        drawn = chosen + self.rng.standard_normal((count, 3)) * spread
        drawn[:, 2] = wrap_angle(drawn[:, 2])
        return drawn

    # -- internals --------------------------------------------------------------------
    @property
    def particle_count(self) -> int:
        return int(len(self.particles))

    @property
    def weights(self) -> NDArray[np.float64]:
        """Normalised particle weights ``(N,)``."""
        return normalize_log_weights(self.log_weights)

    def _apply_pending(self) -> None:
        if self.grid_map is None or self._pending is None:
            return
        init, self._pending = self._pending, None
        count = self.settings.max_particles
        global_start = init.pose is None
        if global_start:
            self.particles = self.grid_map.sample_free_poses(count, self.rng)
        else:
            covariance = init.covariance if init.covariance is not None else np.zeros((3, 3))
            cov = 0.5 * (covariance + covariance.T)
            floor = np.array([_MIN_INITIAL_STD_XY**2, _MIN_INITIAL_STD_XY**2, _MIN_INITIAL_STD_YAW**2])
            cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
            values, vectors = np.linalg.eigh(cov)
            scale = vectors * np.sqrt(np.maximum(values, 0.0))
            particles = init.pose + self.rng.standard_normal((count, 3)) @ scale.T
            particles[:, 2] = wrap_angle(particles[:, 2])
            self.particles = particles
        self.log_weights = np.zeros(count)
        self._reset_filter_state()
        self._draw_at_first_scan = global_start and self.settings.global_start_candidates > 1
        if init.pose is not None:  # an initial pose vouches for itself (its odometry: the first update's)
            self._vouched = (init.pose.copy(), None)

    def _reset_filter_state(self) -> None:
        """What a fresh cloud starts with: no odometry reference, recovery averages cleared."""
        self.odometry.reset()
        self._updates_since_resample = 0
        self.w_slow = 0.0
        self.w_fast = 0.0
        self._fit_slow = _RunningAverage(self.settings.recovery_alpha_slow)
        self._fit_fast = _RunningAverage(self.settings.recovery_alpha_fast)
        # the same averages of the fit over every beam, skipped ones too, for the status
        self._scan_fit_slow = _RunningAverage(self.settings.recovery_alpha_slow)
        self._scan_fit_fast = _RunningAverage(self.settings.recovery_alpha_fast)
        self._scan_fit = 0.0
        self._ever_localized = False
        self._compact = False
        self._moved_since_localized = False  # LOCALIZED once, and since then no particle but by the motion model
        self._trusted = False  # the last update was LOCALIZED, with no other cluster of weight
        self._draw_at_first_scan = False  # a global start's cloud is drawn from the scan's best poses (_update)
        self._scored_with_credit = False  # the last update scored unknown space with unknown_occupancy
        self._vouched = None  # the last pose the map vouched for (or the initial pose), the odometry then
        self.rivals.clear()

    def _select_beams(self, scan: Scan) -> _Beams | None:
        """Valid beams of ``scan``, ``max_beams`` of them evenly spaced; None if there is none."""
        if self._selected is not None and self._selected[0] is scan:
            return self._selected[1]
        beams = self._usable_beams(scan)
        self._selected = (scan, beams)
        return beams

    def _usable_beams(self, scan: Scan) -> _Beams | None:
        s = self.settings
        max_range = scan.range_max if s.laser_max_range <= 0.0 else min(scan.range_max, s.laser_max_range)
        min_range = scan.range_min if s.laser_min_range <= 0.0 else max(scan.range_min, s.laser_min_range)
        if not max_range > min_range:
            return None
        ranges = scan.ranges
        with np.errstate(invalid="ignore"):
            hits = scan.hit_mask & (ranges >= min_range) & (ranges < max_range)
            if s.laser_model_type == "beam":
                no_return = scan.no_return_mask | (scan.hit_mask & (ranges >= max_range))
                usable = hits | no_return
                values = np.where(no_return, np.inf, ranges)
            else:
                usable = hits
                values = ranges
        if not usable.any():
            return None
        selected = Scan(scan.stamp, scan.angles[usable], values[usable], min_range, max_range).subsample(s.max_beams)
        return _Beams(selected.angles, selected.ranges, float(max_range))

    def _pose_is_possible(self, poses: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether laser poses lie on the map and outside occupied cells."""
        assert self.grid_map is not None and self._free_mask is not None
        cells = self.grid_map.world_to_cell(poses[:, :2])
        inside = self.grid_map.in_bounds(cells)
        possible = np.zeros(len(poses), dtype=bool)
        possible[inside] = self._free_mask[cells[inside, 1], cells[inside, 0]]
        return possible

    def _adaptive_temper(self, increment: NDArray[np.float64]) -> float:
        """Largest factor in (0, 1] keeping the effective sample size >= min_effective_fraction * N."""
        fraction = self.settings.min_effective_fraction
        count = len(increment)
        if fraction <= 0.0 or count < 2:
            return 1.0
        target = fraction * count

        def effective(factor: float) -> float:
            weights = normalize_log_weights(self.log_weights + factor * increment)
            return float(1.0 / np.sum(weights * weights))

        if effective(1.0) >= target:
            return 1.0
        low, high = 0.0, 1.0  # effective(low) >= target > effective(high)
        for _ in range(8):  # a factor to 1/256 is plenty
            middle = 0.5 * (low + high)
            if effective(middle) >= target:
                low = middle
            else:
                high = middle
        return max(low, 1e-3)

    def _scan_log_likelihood(self, poses: NDArray[np.float64], beams: _Beams, *,
                             credit: bool = True) -> NDArray[np.float64]:
        """Per pose, the summed log-likelihood of the beams; a converged filter reads unknown space as unknown
        (unless ``credit`` is false: then only what the map holds counts, as for a pose the cloud never held)."""
        assert self._sensor is not None
        if isinstance(self._sensor, LikelihoodFieldModel):
            return self._sensor.log_likelihood(poses, beams.angles, beams.ranges, max_range=beams.max_range,
                                               partial_map=credit and self._converged())
        return self._sensor.log_likelihood(poses, beams.angles, beams.ranges, max_range=beams.max_range)

    def _converged(self) -> bool:
        """Whether the filter has converged (nav2 skips beams only then): at the last update, the heaviest
        cluster held most of the weight, compactly; with ``recovery_unknown_neutral`` also a cloud that has
        spread by the motion model alone since it was last LOCALIZED. A cloud spread otherwise (a global start,
        an injection) reads unknown space as nav2 does, so that it is not drawn into the unexplored parts."""
        return self._compact or (self.settings.recovery_unknown_neutral and self._moved_since_localized)

    def _elsewhere(self, tracked: NDArray[np.float64] | None) -> NDArray[np.bool_] | None:
        """The particles to score without the unknown-space credit (None: none): once the cloud holds particles
        the motion model did not put there (an injection), those apart from the ``tracked`` hypothesis
        (``rival_separation`` away or turned 45 degrees, as rivals). The credit says that unknown space
        contradicts no pose; a draw amid unexplored space earns it for every beam and would outscore the
        track on a poorly explained scan (docs/mcl.md, "The campus")."""
        if tracked is None or self._moved_since_localized:
            return None
        apart = self.rivals.apart_from(self.particles, tracked)
        return apart if apart.any() else None

    def _skip_unexplained_beams(self, beams: _Beams) -> tuple[_Beams, _Beams | None]:
        """nav2's beam skipping: set aside the beams that few particles place near a mapped obstacle.

        Only while the filter has converged (as nav2). A beam is skipped when the particles whose end
        point lies within ``beam_skip_distance`` of an obstacle hold less than ``beam_skip_threshold``
        of the weight (an obstacle the map does not have); when more than ``beam_skip_error_threshold``
        of the beams would go, the filter is more likely wrong than the map, and every beam is kept.
        Returns the kept beams and the skipped ones (None when none is).
        """
        s = self.settings
        if not (s.do_beamskip and self._trusted and isinstance(self._sensor, LikelihoodFieldModel)
                and len(beams.angles)):
            return beams, None
        agreement = self._sensor.beam_agreement(self.particles, self.weights, beams.angles, beams.ranges,
                                                distance=s.beam_skip_distance)
        keep = agreement >= s.beam_skip_threshold
        skipped = int(len(keep) - keep.sum())
        if skipped == 0 or skipped == len(keep) or skipped > s.beam_skip_error_threshold * len(keep):
            return beams, None  # nothing to skip, or (nav2) the filter rather than the map is likely wrong
        return (_Beams(beams.angles[keep], beams.ranges[keep], beams.max_range),
                _Beams(beams.angles[~keep], beams.ranges[~keep], beams.max_range))

    def _update(self, stamp: float, beams: _Beams, tracked: NDArray[np.float64] | None = None) -> Estimate:
        """Weigh, judge and resample the moved cloud on ``beams``; ``tracked``: the last estimate moved by the
        odometry since, the hypothesis the unknown-space credit belongs to (:meth:`_elsewhere`)."""
        s = self.settings
        assert self._sensor is not None and self.grid_map is not None
        if self._draw_at_first_scan:
            self._draw_at_first_scan = False
            count = len(self.particles)
            self.particles, _ = self._best_fitting_poses(count, count * s.global_start_candidates, beams)
            self.log_weights = np.zeros(len(self.particles))
        kept, skipped = self._skip_unexplained_beams(beams)
        beam_count = len(kept.angles)
        self._scored_with_credit = self._converged() and isinstance(self._sensor, LikelihoodFieldModel) \
            and s.unknown_occupancy > 0.0
        elsewhere = self._elsewhere(tracked) if self._scored_with_credit else None
        log_likelihood, partial = self._score_cloud(
            kept, elsewhere, with_unjudged=self._scored_with_credit and s.recovery_unknown_neutral)
        floor = self._sensor.floor_log_likelihood(beams.max_range)
        impossible = ~self._pose_is_possible(self.particles)
        log_likelihood[impossible] = beam_count * floor
        temper = min(1.0, s.effective_beams / beam_count)
        temper *= self._adaptive_temper(temper * log_likelihood)
        prior_log_weights = self.log_weights
        self.log_weights = self.log_weights + temper * log_likelihood
        weights = normalize_log_weights(self.log_weights)

        # Augmented MCL: posterior-weighted geometric-mean per-beam likelihood (docs/mcl.md), over the
        # beams that weighted the particles, as nav2; it drives the injection.
        fit = float((weights * np.exp(log_likelihood / beam_count)).sum())
        injection_fit, evidence = (fit, 1.0) if partial is None else \
            self._judged_fit(weights, partial, beam_count, floor, impossible)
        self._fit_slow.update(injection_fit, evidence)
        self._fit_fast.update(injection_fit, evidence)
        self.w_slow, self.w_fast = self._fit_slow.value, self._fit_fast.value
        # The status judges the fit over every beam, the skipped ones too: a kidnapping must not hide
        # behind beam skipping (docs/mcl.md, "Partial maps").
        all_beams = log_likelihood
        scan_fit = fit
        if skipped is not None:
            all_beams = log_likelihood + self._score_cloud(skipped, elsewhere, with_unjudged=False)[0]
            all_beams[impossible] = len(beams.angles) * floor
            scan_fit = float((weights * np.exp(all_beams / len(beams.angles))).sum())
        self._scan_fit_slow.update(scan_fit)
        self._scan_fit_fast.update(scan_fit)
        self._scan_fit = scan_fit

        if s.max_rivals > 0 and self._weigh_rivals(beams, prior_log_weights, all_beams, floor):
            weights = normalize_log_weights(self.log_weights)
        effective = float(1.0 / np.sum(weights * weights))  # effective sample size
        estimate = self._estimate(stamp, weights, fit, beams, effective)
        if s.do_beamskip:
            skipped_count = 0 if skipped is None else len(skipped.angles)
            estimate = replace(estimate, details={**estimate.details, "skipped_beams": skipped_count,
                                                  "scan_fit": round(scan_fit, 5)})

        self._updates_since_resample += 1
        # Selective resampling (docs/mcl.md): only when the weights have degenerated, or
        # when Augmented MCL wants to inject particles.
        degenerate = (s.resample_effective_fraction >= 1.0
                      or effective < s.resample_effective_fraction * len(weights))
        if self._updates_since_resample >= s.resample_interval and (degenerate or self._injection_fraction() > 0.0):
            self._updates_since_resample = 0
            bar = self._injection_bar(all_beams, len(beams.angles), partial, beam_count, impossible) \
                if self._injection_fraction() > 0.0 else None  # only an injection uses it
            next_count, injected, bins = self._resample(weights, beams, bar)
            estimate = replace(estimate, details={**estimate.details, "particles_next": next_count,
                                                  "injected": injected, "kld_bins": bins})
        self.counters.updates += 1
        self.last_estimate = estimate
        return estimate

    def _score_cloud(self, beams: _Beams, elsewhere: NDArray[np.bool_] | None, *,
                     with_unjudged: bool) -> tuple[NDArray[np.float64], PartialMapScores | None]:
        """Each particle's summed beam log-likelihood, scored once: as :meth:`_scan_log_likelihood`, and the
        ``elsewhere`` ones (:meth:`_elsewhere`) without the unknown-space credit, every beam judged. With
        ``with_unjudged``, also the credited part (``PartialMapScores``; the log-likelihoods are a copy)."""
        held = self.particles if elsewhere is None else self.particles[~elsewhere]
        partial: PartialMapScores | None = None
        if with_unjudged:
            assert isinstance(self._sensor, LikelihoodFieldModel)
            partial = self._sensor.partial_log_likelihood(held, beams.angles, beams.ranges, max_range=beams.max_range)
            held_scores = partial.total
        else:
            held_scores = self._scan_log_likelihood(held, beams)
        if elsewhere is None:
            return (held_scores.copy() if partial is not None else held_scores), partial
        count = len(self.particles)
        log_likelihood = np.empty(count)
        log_likelihood[~elsewhere] = held_scores
        log_likelihood[elsewhere] = self._scan_log_likelihood(self.particles[elsewhere], beams, credit=False)
        if partial is not None:  # the elsewhere ones: every beam judged, none credited
            unjudged_sum, unjudged_count = np.zeros(count), np.zeros(count, dtype=np.int64)
            unjudged_sum[~elsewhere] = partial.unjudged_sum
            unjudged_count[~elsewhere] = partial.unjudged_count
            partial = PartialMapScores(log_likelihood.copy(), unjudged_sum, unjudged_count)
        return log_likelihood, partial

    @staticmethod
    def _judged_fit(weights: NDArray[np.float64], partial: PartialMapScores, beam_count: int, floor: float,
                    impossible: NDArray[np.bool_]) -> tuple[float, float]:
        """The injection's fit over the beams the map can judge, and their posterior-weighted share of the scan.

        A scan that falls into space the map never saw says nothing against the particles; counted in full
        (as nav2), its credited beams lower the fit and set off Augmented MCL's injection, which then fills
        the cloud with places whose mapped walls happen to explain it (docs/mcl.md, "Partial maps").
        """
        judged_count = (beam_count - partial.unjudged_count).astype(np.float64)
        judged_sum = partial.judged_sum
        judged_count[impossible] = beam_count
        judged_sum[impossible] = beam_count * floor
        mass = weights * judged_count
        total = float(mass.sum())
        if total <= 0.0:
            return 0.0, 0.0
        per_beam = np.exp(judged_sum / np.maximum(judged_count, 1.0))
        return float((mass * per_beam).sum() / total), total / beam_count

    def _estimate(self, stamp: float, weights: NDArray[np.float64], fit: float, beams: _Beams,
                  effective: float) -> Estimate:
        s = self.settings
        beam_count = len(beams.angles)
        # Dropping every particle lighter than (1 - mass) / N drops at most (1 - mass) of the
        # weight, so the kept ones hold at least cluster_weight_mass of it (no sort needed).
        kept = np.nonzero(weights >= (1.0 - s.cluster_weight_mass) / len(weights))[0]
        if len(kept) == 0:
            kept = np.array([int(np.argmax(weights))])
        labels, cluster_count = cluster_particles(self.particles[kept])
        cluster_weights = np.bincount(labels, weights=weights[kept], minlength=cluster_count)
        ranked = np.argsort(-cluster_weights, kind="stable")
        best = int(ranked[0])
        members = kept[labels == best]
        pose, covariance = weighted_pose_statistics(self.particles[members], weights[members])
        best_weight = float(cluster_weights[best])
        second_weight = float(cluster_weights[ranked[1]]) if cluster_count > 1 else 0.0

        std_xy, std_yaw = pose_spread(covariance)
        tight = best_weight >= 0.5 and std_xy <= s.localized_max_std_xy and std_yaw <= s.localized_max_std_yaw
        self._compact = tight
        compact = tight and effective >= s.localized_min_effective_particles
        # The fit holds on average and for this scan (a kidnapping drops it at once; w_fast follows slowly).
        scan_slow = self._scan_fit_slow.value
        fit_holds = not self.fit_dropped and (scan_slow <= 0.0
                                              or self._scan_fit_fast.value >= s.lost_fit_ratio * scan_slow)
        # A rival cluster with ambiguous_cluster_weight is a second hypothesis: no LOCALIZED beside it.
        if s.max_rivals > 0:
            self._consider_rivals(labels, ranked, np.asarray(cluster_weights, dtype=np.float64), kept, weights, pose)
        rivals = len(self.rivals)
        if compact and fit_holds and second_weight < s.ambiguous_cluster_weight and not rivals:
            status = LocalizerStatus.LOCALIZED
            self._ever_localized = True
        elif second_weight >= s.ambiguous_cluster_weight or rivals:
            status = LocalizerStatus.AMBIGUOUS
        elif self._ever_localized:
            status = LocalizerStatus.LOST
        else:
            status = LocalizerStatus.INITIALIZING
        # nav2 skips beams once every particle is within 0.5 m; here: once the other clusters are no rival
        self._trusted = status is LocalizerStatus.LOCALIZED and best_weight >= 1.0 - 1.0 / s.rival_odds
        self._moved_since_localized = self._moved_since_localized or self._trusted
        # The filter's own mechanics above follow its status; the robot is told LOCALIZED only where the map
        # vouches for the place (docs/mcl.md, "A place the map vouches for").
        vouched = status is not LocalizerStatus.LOCALIZED or self._vouched_for(pose, beams)
        if not vouched:
            status = LocalizerStatus.AMBIGUOUS

        reported = _heaviest_first(weights, s.max_reported_particles)
        candidates, candidate_weights = self.particles[reported], weights[reported]
        if rivals:  # each rival's best pose after the heaviest particle, weighted by its odds
            rival_poses = np.array([rival.best for rival in self.rivals.rivals])
            rival_weights = best_weight * np.exp([rival.log_odds for rival in self.rivals.rivals])
            candidates = np.vstack([candidates[:1], rival_poses, candidates[1:]])
            candidate_weights = np.concatenate([candidate_weights[:1], rival_weights, candidate_weights[1:]])

        return Estimate(
            stamp=float(stamp),
            pose=pose,
            covariance=covariance,
            status=status,
            candidates=candidates.copy(),
            candidate_weights=candidate_weights.copy(),
            details={
                "particles": int(len(self.particles)),
                "clusters": int(cluster_count),
                "cluster_weight": round(best_weight, 4),
                "beams": int(beam_count),
                "fit": round(fit, 5),
                "effective_sample_size": round(effective, 1),
                "w_slow": round(self.w_slow, 5),
                "w_fast": round(self.w_fast, 5),
                "rivals": rivals,
                "vouched": vouched,
            },
        )

    def _vouched_for(self, pose: NDArray[np.float64], beams: _Beams) -> bool:
        """Whether the map vouches for a LOCALIZED ``pose``: it continues the last vouched pose (moved by the
        odometry since, the same hypothesis as for rivals), or ``localized_min_explained`` of this scan's end
        points lie within two cells of a mapped obstacle there. A vouched pose becomes the last one."""
        assert self.grid_map is not None
        odom = self.odometry.reference
        continues = False
        if self._vouched is not None:
            then_pose, then_odom = self._vouched
            predicted = then_pose if then_odom is None or odom is None else compose(then_pose,
                                                                                   relative(then_odom, odom))
            continues = not self.rivals.apart(pose, predicted)
        if not continues and self.settings.localized_min_explained > 0.0:
            explained = map_coverage(self.grid_map, pose[None, :], beams.angles, beams.ranges,
                                     range_max=beams.max_range)[0]
            if not explained >= self.settings.localized_min_explained:  # NaN: no hit to judge by
                return False
        self._vouched = (pose.copy(), None if odom is None else odom.copy())
        return True

    def _consider_rivals(self, labels: NDArray[np.int64], ranked: NDArray[np.int64],
                         cluster_weights: NDArray[np.float64], kept: NDArray[np.int64],
                         weights: NDArray[np.float64], best_pose: NDArray[np.float64]) -> None:
        """Hand the clusters heavy enough to be rivals (odds above 1 / rival_odds) to the tracker."""
        best_weight = float(cluster_weights[ranked[0]])
        heavy = [int(c) for c in ranked[1: 1 + self.settings.max_rivals]
                 if cluster_weights[c] * self.settings.rival_odds >= best_weight]
        if not heavy:
            return
        means, members, member_weights = [], [], []
        for cluster in heavy:
            index = kept[labels == cluster]
            mean, _ = weighted_pose_statistics(self.particles[index], weights[index])
            means.append(mean)
            members.append(self.particles[index])
            member_weights.append(weights[index])
        self.rivals.consider(np.array(means), cluster_weights[heavy], members, member_weights, best_pose,
                             best_weight, self.rng)

    def _weigh_rivals(self, beams: _Beams, prior_log_weights: NDArray[np.float64],
                      cloud_scores: NDArray[np.float64], floor: float) -> bool:
        """Weigh the rivals on this scan against the cloud; move the cloud to one that wins. True if it moved.

        Rivals and the cloud are scored alike: every beam, nav2's model (no unknown-space credit,
        no beam skipping, which would favour the cloud's own hypothesis); ``cloud_scores`` are the
        particles' scores over every beam, reused when they were taken that way.
        """
        if not len(self.rivals):
            return False
        sensor = self._sensor
        assert sensor is not None
        s = self.settings
        count = len(beams.angles)

        def score(poses: NDArray[np.float64]) -> NDArray[np.float64]:
            values = sensor.log_likelihood(poses, beams.angles, beams.ranges, max_range=beams.max_range)
            values[~self._pose_is_possible(poses)] = count * floor
            return values

        if self._scored_with_credit:
            cloud_scores = score(self.particles)
        temper = min(1.0, s.effective_beams / count)
        prior = normalize_log_weights(prior_log_weights)
        with np.errstate(divide="ignore"):
            cloud_log_predictive = float(logsumexp(np.log(prior) + temper * cloud_scores))
        best = int(np.argmax(prior_log_weights + temper * cloud_scores))
        self.rivals.weigh(score, cloud_log_predictive, temper, self.particles[best], self.rng)
        winner = self.rivals.winner()
        if winner is None:
            return False
        # The rival's odds exceed rival_odds: the cloud (whose odds are now below 1 / rival_odds) moves there.
        self.rivals.rivals.remove(winner)
        count_now = len(self.particles)
        self.particles = self._draw_around(winner.samples, np.ones(len(winner.samples)), count_now,
                                           0.25 * s.initial_std_xy, 0.25 * s.initial_std_yaw)
        self.log_weights = np.zeros(count_now)
        self._moved_since_localized = False
        return True

    def _injection_bar(self, all_beams: NDArray[np.float64], all_count: int, partial: PartialMapScores | None,
                       kept_count: int, impossible: NDArray[np.bool_]) -> float | None:
        """The per-beam log-likelihood an injected draw must beat (``recovery_requires_better``); None: any draw.

        With ``recovery_unknown_neutral`` (``partial`` given), the best particle's score with each beam the map
        cannot judge counted at the slow average fit, what a beam scores at a right pose, whatever the status
        when that particle has such beams: a scan that falls into space the map never saw is no reason to move
        the cloud; a kidnapping still is, as the beams the map judges then contradict it. Otherwise, while
        LOCALIZED, the best particle's score.
        """
        s = self.settings
        if not (s.recovery_requires_better and s.recovery_sampling == "measurement"):
            return None
        if partial is not None and self.w_slow > 0.0:
            neutral = partial.judged_sum + partial.unjudged_count * math.log(self.w_slow)
            neutral[impossible] = -np.inf
            best = int(np.argmax(neutral))
            if self._trusted or partial.unjudged_count[best] > 0:
                return float(neutral[best]) / kept_count
            return None  # the map judges the whole scan: the status decides, as below
        if self._trusted:
            return float(all_beams.max()) / all_count
        return None

    def _recovery_poses(self, count: int, beams: _Beams, better_than: float | None) -> NDArray[np.float64]:
        """At most ``count`` poses for Augmented-MCL injection (``recovery_sampling``).

        With ``better_than`` (``_injection_bar``), only draws whose per-beam log-likelihood beats it are kept:
        a scan the map explains poorly at the true pose is no reason to replace particles by worse ones.
        """
        assert self.grid_map is not None and self._sensor is not None
        s = self.settings
        if s.recovery_sampling == "uniform" or count == 0:
            return self.grid_map.sample_free_poses(count, self.rng)
        # measurement: the best-fitting of recovery_candidates x count uniform poses (sensor
        # resetting), the pool capped at max_particles to bound the cost of one update
        pool = max(count, min(count * s.recovery_candidates, s.max_particles))
        candidates, scores = self._best_fitting_poses(count, pool, beams)
        if better_than is not None:
            return candidates[scores / len(beams.angles) > better_than]
        return candidates

    def _best_fitting_poses(self, count: int, draws: int, beams: _Beams) -> tuple[NDArray[np.float64],
                                                                                NDArray[np.float64]]:
        """The ``count`` poses of ``draws`` uniform ones over free space that explain ``beams`` best, and their
        log-likelihoods (sensor resetting, Lenser & Veloso 2000; docs/mcl.md). Judged by what the map holds:
        with the unknown-space credit the best draws would be places where every end point falls into open
        unknown space, which no scan contradicts (docs/mcl.md, "The campus")."""
        assert self.grid_map is not None
        candidates = self.grid_map.sample_free_poses(draws, self.rng)
        scores = self._scan_log_likelihood(candidates, beams, credit=False)
        best = np.argpartition(-scores, count - 1)[:count]
        return candidates[best], scores[best]

    def _injection_fraction(self) -> float:
        """Augmented MCL's share of random particles, ``max(0, 1 - w_fast / w_slow)``, 0 inside the dead band."""
        inject = max(0.0, 1.0 - self.w_fast / self.w_slow) if self.w_slow > 0.0 else 0.0
        return inject if inject >= self.settings.recovery_min_injection else 0.0

    def _resample(self, weights: NDArray[np.float64], beams: _Beams, bar: float | None) -> tuple[int, int, int]:
        """KLD-sized low-variance resampling with Augmented-MCL injection; returns (count, injected, bins)."""
        s = self.settings
        assert self.grid_map is not None
        inject = self._injection_fraction()
        # KLD: draw candidates in random order (a shuffled low-variance draw, with the
        # injected share uniform) until the bound stops the draw; small batches first so
        # that a converged cloud costs little.
        batch = min(s.max_particles, max(4 * s.min_particles, 2048))
        count, bins = s.max_particles, -1  # -1: no KLD draw (min_particles == max_particles fixes the count)
        while s.min_particles < s.max_particles:
            candidates_index = low_variance_resample(weights, batch, self.rng)
            self.rng.shuffle(candidates_index)
            candidates = self.particles[candidates_index]
            if inject > 0.0:
                random_mask = self.rng.random(batch) < inject
                if random_mask.any():
                    candidates[random_mask] = self.grid_map.sample_free_poses(int(random_mask.sum()), self.rng)
            count, bins, stopped = kld_particle_count(
                candidates, pf_err=s.pf_err, pf_z=s.pf_z, min_count=s.min_particles, max_count=s.max_particles
            )
            if stopped or batch >= s.max_particles:
                break
            batch = min(s.max_particles, 4 * batch)
        injected = int(self.rng.binomial(count, inject)) if inject > 0.0 else 0
        particles = self.particles[low_variance_resample(weights, count - injected, self.rng)]
        if injected:
            recovered = self._recovery_poses(injected, beams, bar)
            if len(recovered) < injected:  # fewer draws beat the particles: the rest are resampled
                extra = self.particles[low_variance_resample(weights, injected - len(recovered), self.rng)]
                particles = np.vstack([particles, extra])
            injected = len(recovered)
            particles = np.vstack([particles, recovered])
            self.counters.injected_particles += injected
            self._moved_since_localized = self._moved_since_localized and injected == 0
        self.particles = particles
        self.log_weights = np.zeros(len(particles))
        return count, injected, bins
