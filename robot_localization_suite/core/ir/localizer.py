"""The IR localizer: the global fix of :mod:`.global_fix` feeding a small particle filter (seed 001, IV-C, IV-D).

O. Aycard and C. Brouard, "A new tool to initialize global localization for a mobile robot".
``particle_count`` particles drawn from the ranked poses of a global fix are tracked with the
odometry motion model and an end-point sensor model, resampled at every update; the localizer
initialises again by itself when the particles stop matching the map. Beyond the paper (a
switch): a periodic global check that restarts the tracker from a clearly better fix.
Notes (the interpretation of the paper, status, measured figures): docs/ir.md.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ScanError
from ..filter.odometry_gate import OdometryGate
from ..filter.particles import (
    densest_neighbourhood_mean,
    low_variance_resample,
    pose_spread,
    weighted_pose_statistics,
)
from ..grid_map import GridMap
from ..localizer import Estimate, LocalizerStatus
from ..metrics import CORRECT_THETA_RAD, CORRECT_XY_M
from ..motion import OdometryMotionModel, VelocityMotionModel
from ..scan import Scan
from ..se2 import angle_difference, compose, relative, wrap_angle
from .global_fix import COVARIANCE_FLOOR, IRGlobalFixer
from .index import FanModel, IndexSettings, IRIndex
from .settings import IRSettings

__all__ = ["IRSettings", "IRLocalizer", "IRIndex", "FanModel", "IndexSettings"]

_LOG = logging.getLogger(__name__)


class IRLocalizer:
    """The IR initialiser (a :class:`~.localizer.GlobalFixer`) and its particle tracker (a :class:`~.localizer.Localizer`).

    Args:
        settings: the method's settings.
        grid_map: optional map to start with (as :meth:`set_map`).
    """

    def __init__(self, settings: IRSettings | None = None, grid_map: GridMap | None = None) -> None:
        self.settings = settings or IRSettings()
        self.grid_map: GridMap | None = None
        self.fixer = IRGlobalFixer(self.settings)
        self._rng = np.random.default_rng(self.settings.seed)
        s = self.settings
        model = VelocityMotionModel if s.motion_model == "velocity" else OdometryMotionModel
        self._motion: OdometryMotionModel | VelocityMotionModel = model(
            alpha1=s.alpha1, alpha2=s.alpha2, alpha3=s.alpha3, alpha4=s.alpha4)
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
        # the places elsewhere that the last global check found to fit as well, and the odometry then
        self._lookalikes: tuple[NDArray[np.float64], NDArray[np.float64] | None] | None = None
        # a global fix whose best place fitted clearly better, the odometry then, and the updates that confirmed it
        self._challenger: tuple[Estimate, NDArray[np.float64] | None, int] | None = None

    @property
    def initialized(self) -> bool:
        return self.particles is not None

    # -- Localizer protocol ---------------------------------------------------------------------
    def set_map(self, grid_map: GridMap) -> None:
        """Use this map; builds (or loads) the index now when the scanner model is given by the settings."""
        self.grid_map = grid_map
        self.fixer.set_map(grid_map)
        self._reset_tracking()

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
        if self.odometry.due() or self._contradicted(scan):
            estimate = self._update(scan)
            if estimate is not None:
                return estimate
            return self._initialise(scan, reason="lost")
        estimate = self._tracking_estimate(scan.stamp, self._predicted_particles(), {"phase": "tracking", "updated": False})
        if self._fix_pose is not None:
            estimate = replace(estimate, pose=self._predicted_poses(self._fix_pose[None, :])[0])
        return self._listed(estimate)

    # -- GlobalFixer ----------------------------------------------------------------------------
    def global_fix(self, scan: Scan) -> Estimate:
        """Ranked candidate poses of the laser from this scan alone, best first (:class:`~.global_fix.IRGlobalFixer`)."""
        return self.fixer.global_fix(scan)

    def prepare(self, scan: Scan) -> None:
        """Build (or load) the index for this scan's geometry now, not inside the first update."""
        self.fixer.prepare(scan)

    def prepared_for(self, scan: Scan) -> bool:
        """Whether the index serves this scan's scanner (``IRGlobalFixer.prepared_for``)."""
        return self.fixer.prepared_for(scan)

    @property
    def index(self) -> IRIndex | None:
        return self.fixer.index

    # -- internals: tracking --------------------------------------------------------------------
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
        estimate = replace(estimate, details={**estimate.details, "initialized_because": reason})
        count = self.settings.particle_count
        candidates = estimate.candidates
        # One per candidate (the paper), or drawn from the ranked list with probability 1 / rank (the ranking
        # is the evidence: the first candidate gets about a fifth of 100 particles, the hundredth one at most
        # one); copies are spread over half a grid cell and half a heading step so that they explore it.
        if self.settings.initial_particles == "one_per_candidate":
            drawn = np.sort(np.arange(count) % len(candidates))
        else:
            rank_prior = 1.0 / np.arange(1, len(candidates) + 1)
            drawn = np.sort(low_variance_resample(rank_prior, count, self._rng))
        particles = candidates[drawn].copy()
        copies = np.concatenate([[False], drawn[1:] == drawn[:-1]])
        step = self.index.grid_step if self.index is not None else self.settings.grid_resolution
        spread = np.array([step, step, self.settings.heading_step])
        particles[copies] += self._rng.uniform(-0.5, 0.5, size=(int(copies.sum()), 3)) * spread
        particles[:, 2] = wrap_angle(particles[:, 2])
        self._start_tracking(particles, np.full(count, 1.0 / count))
        self._best_score = float("nan")
        # Until the first update the estimate is the fix's best pose (moved by odometry), not the
        # densest particle cluster: several look-alike candidates can outnumber the best one.
        self._fix_pose = estimate.pose.copy()
        return estimate

    def _global_check(self, scan: Scan, estimate: Estimate) -> Estimate:
        """Restart from a global fix that fits the map clearly better than the tracked pose; keep the places that fit
        as well as look-alikes (docs/ir.md, "Beyond the paper")."""
        s = self.settings
        self._updates_since_check, self._lookalikes, self._challenger = 0, None, None
        fix = self.global_fix(scan)
        tracked = self.fixer.refined_scores(scan, estimate.pose[None, :]) if len(fix.candidates) else None
        if tracked is None:
            return estimate
        estimate = replace(estimate, details={**estimate.details, "global_check_tracked_score": float(tracked[0]),
                                              "global_check_fix_score": fix.details["best_score"]})
        # elsewhere: a pose that would not be correct where the tracked one is, or the other way round
        # (0.5 m or 25 degrees apart): the mirrored heading at the same spot of a symmetric corridor too
        far = np.hypot(*(fix.candidates[:, :2] - estimate.pose[:2]).T) > max(s.nms_distance, CORRECT_XY_M)
        turned = np.abs(angle_difference(fix.candidates[:, 2], estimate.pose[2])) > max(s.nms_angle, CORRECT_THETA_RAD)
        elsewhere = far | turned
        if elsewhere[0] and fix.details["best_score"] > float(tracked[0]) + s.global_check_margin:
            if s.global_check_confirmations == 0:
                return self._start_from_fix(fix, "better global fix")
            # one scan's lead may be a few beams that people or an outdated map decide: the next scan after
            # motion must not refute it (docs/ir.md, "Confirmed restarts"); until then it is listed as a look-alike
            reference = self.odometry.reference
            self._challenger = (fix, None if reference is None else reference.copy(), 0)
        # A place elsewhere that fits neither clearly better nor clearly worse is a look-alike: the scans cannot
        # tell that the robot is not there (docs/ir.md, "Look-alike places"); kept until the next check.
        # the fix's candidate weights are its scores normalised (IRGlobalFixer.global_fix): scale back by the best
        weights = fix.candidate_weights if fix.candidate_weights is not None else np.ones(len(fix.candidates))
        scores = weights / weights[0] * fix.details["best_score"] if weights[0] > 0 else np.zeros(len(weights))
        alike = elsewhere & (scores >= float(tracked[0]) - s.global_check_margin)
        reference = self.odometry.reference
        self._lookalikes = None if not alike.any() else (
            fix.candidates[alike], None if reference is None else reference.copy())
        return estimate

    def _confirm_challenger(self, scan: Scan, estimate: Estimate) -> tuple[Estimate, bool]:
        """Score the pending better fix's best place, moved by the odometry, against the tracked pose on this scan:
        clearly worse (by ``global_check_margin``) forgets it; else it is confirmed, and the last confirmation
        restarts the tracker from the fix (True) (docs/ir.md, "Confirmed restarts")."""
        assert self._challenger is not None
        s = self.settings
        fix, then, confirmations = self._challenger
        moved = replace(fix, stamp=scan.stamp)
        if then is not None:
            poses = self._predicted_poses(np.vstack([fix.pose, fix.candidates]), since=then)
            moved = replace(moved, pose=poses[0], candidates=poses[1:])
        scores = self.fixer.refined_scores(scan, np.vstack([moved.pose, estimate.pose]))
        if scores is None or scores[0] < scores[1] - s.global_check_margin:
            # refuted; the look-alikes of the check stay listed until the next one
            self._challenger = None
            return replace(estimate, details={**estimate.details, "challenger_refuted": True}), False
        if confirmations + 1 >= s.global_check_confirmations:
            return self._start_from_fix(moved, "better global fix"), True
        self._challenger = (fix, then, confirmations + 1)
        return estimate, False

    def _listed(self, estimate: Estimate) -> Estimate:
        """``estimate`` with the look-alikes of the last global check (moved by the odometry since): listed after
        its pose, and no LOCALIZED beside them."""
        if self._lookalikes is None:
            return replace(estimate, details={**estimate.details, "lookalikes": 0})
        poses, then = self._lookalikes
        if then is not None:
            poses = self._predicted_poses(poses, since=then)
        weights = estimate.candidate_weights if estimate.candidate_weights is not None else np.zeros(0)
        top = float(weights.max(initial=0.0))
        status = LocalizerStatus.AMBIGUOUS if estimate.status is LocalizerStatus.LOCALIZED else estimate.status
        return replace(estimate, status=status,
                       candidates=np.vstack([estimate.pose[None, :], poses, estimate.candidates]),
                       candidate_weights=np.concatenate([np.full(1 + len(poses), top), weights]),
                       details={**estimate.details, "lookalikes": len(poses)})

    def _start_tracking(self, particles: NDArray[np.float64], weights: NDArray[np.float64]) -> None:
        self._lookalikes, self._challenger = None, None
        self.particles = particles
        self.weights = weights
        self.odometry.mark_updated(self.odometry.latest)
        self._low_score_updates = 0

    def _lost_floor(self) -> float:
        """The best end-point score below which an update counts towards LOST."""
        s = self.settings
        if np.isfinite(self._score_average):
            return max(s.lost_score_threshold, s.lost_score_ratio * self._score_average)
        return s.lost_score_threshold

    def _contradicted(self, scan: Scan) -> bool:
        """Whether a scan that comes without motion enough for an update fits no predicted particle: the robot
        was carried away while standing (docs/ir.md, "Tracking"). Then it updates now, as a moving one would."""
        if self._fix_pose is not None:
            return False  # no update since the fix: the next one is due anyway
        scores = self.endpoint_scores(scan, self._predicted_particles())
        return float(scores.max(initial=0.0)) < self._lost_floor()

    def _predicted_particles(self) -> NDArray[np.float64]:
        """Particles moved by the odometry since the last update, without noise."""
        assert self.particles is not None
        return self._predicted_poses(self.particles)

    def _predicted_poses(
        self, poses: NDArray[np.float64], since: NDArray[np.float64] | None = None
    ) -> NDArray[np.float64]:
        """``poses`` moved by the odometry from ``since`` (default: the last update's reference) to the latest."""
        odom, reference = self.odometry.latest, self.odometry.reference if since is None else since
        if odom is None or reference is None:
            return poses
        return compose(poses, relative(reference, odom))

    def endpoint_scores(self, scan: Scan, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        """Section IV-C-2: fraction of the scan's hit end-points (at most ``max_beams``) on occupied cells.

        Within ``endpoint_tolerance`` of one; with ``neutral_unknown`` an end point in an unknown cell or
        off the map counts the map's chance level instead of a miss (:mod:`.evidence`).
        """
        evidence = self.fixer.evidence
        assert self.grid_map is not None and evidence is not None
        beams = scan.subsample(self.settings.max_beams)
        angles, ranges = beams.hits()
        return evidence.hit_fractions(poses, angles, ranges, neutral_unknown=self.settings.neutral_unknown)

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
        if best < self._lost_floor():
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
        # Pose of the best-scoring particle before resampling, for diagnostics.
        best_particle = moved[int(np.argmax(scores))].tolist()
        estimate = self._tracking_estimate(
            scan.stamp, moved,
            {"phase": "tracking", "updated": True, "best_endpoint_score": best, "best_particle": best_particle}, weights,
        )
        chosen = low_variance_resample(weights, s.particle_count, self._rng)
        self.particles = moved[chosen]
        self.weights = np.full(s.particle_count, 1.0 / s.particle_count)
        self._updates_since_check += 1
        restarted = False
        if self._challenger is not None:
            estimate, restarted = self._confirm_challenger(scan, estimate)
        if not restarted and s.global_check_updates and self._updates_since_check >= s.global_check_updates:
            estimate = self._global_check(scan, estimate)
        return self._listed(estimate)

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
        std_xy, _ = pose_spread(covariance)
        covariance = covariance + COVARIANCE_FLOOR
        details = {**details, "particles": len(particles), "std_xy_m": std_xy, "low_score_updates": self._low_score_updates}
        if np.isfinite(self._best_score):
            details.setdefault("best_endpoint_score", self._best_score)
        # Two standard deviations along the widest axis within 0.5 m: the node stands behind the pose
        # as mcl_baseline does (docs/ir.md, "Status").
        status = LocalizerStatus.LOCALIZED if std_xy <= s.localized_max_std_xy else LocalizerStatus.AMBIGUOUS
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
        index = self.fixer.index
        return {"settings": asdict(self.settings), "index": index.describe() if index else None}


