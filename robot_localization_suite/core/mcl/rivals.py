"""Rival hypotheses the particle cloud let go, kept and weighed until the scans rule them out (docs/mcl.md, "Rivals").

KLD sampling shrinks a converged cloud to a few hundred particles around its
heaviest cluster, and resampling drops the other clusters however well they
explain the scans: in twin rooms the filter then commits to one at random and
cannot tell that the other was never ruled out. A :class:`RivalTracker` keeps
each such cluster as a handful of samples, moves them by the same motion model
and weighs them with the same tempered scan likelihood as the cloud, summing
the log posterior odds of each rival against the cloud's best cluster. A rival
is ruled out when its odds fall below ``1 / odds`` and wins when they exceed
``odds``: a multiple-hypothesis test (Jensfelt & Kristensen, IEEE T-RA 17(5),
2001, section IV) on top of the particle filter.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

from ..filter.particles import low_variance_resample, normalize_log_weights
from ..motion import OdometryMotionModel
from ..se2 import angle_difference

__all__ = ["Rival", "RivalTracker"]

# Two hypotheses whose headings differ by more than this are rivals even at one place (a mirrored room).
_SEPARATE_HEADING = math.pi / 4


@dataclass(eq=False)  # compared by identity: a rival is removed from its list as itself (arrays have no truth value)
class Rival:
    """One hypothesis outside the cloud: its samples ``(M, 3)``, their best-scoring pose at the last scan and
    its log posterior odds against the cloud."""

    samples: NDArray[np.float64]
    log_odds: float
    best: NDArray[np.float64]


class RivalTracker:
    """The rivals of one particle filter.

    Args:
        odds: a cluster is a rival while its posterior odds against the best cluster exceed ``1 / odds``,
            and it wins when they exceed ``odds``.
        capacity: at most this many rivals (the likeliest are kept).
        samples: poses per rival.
        separation: a cluster nearer the best one (or a rival) than this, with a heading within 45 degrees,
            is the same hypothesis [m].
    """

    def __init__(self, odds: float, capacity: int, samples: int, separation: float) -> None:
        self.log_threshold = math.log(odds)
        self.capacity = int(capacity)
        self.sample_count = int(samples)
        self.separation = float(separation)
        self.rivals: list[Rival] = []

    def clear(self) -> None:
        self.rivals = []

    def __len__(self) -> int:
        return len(self.rivals)

    def apart(self, a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
        """Whether poses ``a`` and ``b`` are different hypotheses (``separation`` apart, or turned 45 degrees)."""
        return bool(self.apart_from(np.asarray(a, dtype=np.float64)[None, :], b)[0])

    def apart_from(self, poses: NDArray[np.float64], pose: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Per pose of ``poses`` ``(N, 3)``, whether it is a different hypothesis from ``pose`` (:meth:`apart`)."""
        return np.asarray((np.hypot(poses[:, 0] - pose[0], poses[:, 1] - pose[1]) > self.separation)
                          | (np.abs(angle_difference(poses[:, 2], pose[2])) > _SEPARATE_HEADING))

    def predict(self, model: OdometryMotionModel, previous_odom: NDArray[np.float64],
                current_odom: NDArray[np.float64], rng: np.random.Generator) -> None:
        """Move every rival's samples through the odometry step, as the particles."""
        for rival in self.rivals:
            rival.samples = model.sample(rival.samples, previous_odom, current_odom, rng)

    def weigh(self, score: Callable[[NDArray[np.float64]], NDArray[np.float64]], cloud_log_predictive: float,
              temper: float, best_pose: NDArray[np.float64], rng: np.random.Generator) -> None:
        """Multiply each rival's odds by its Bayes factor on this scan; drop the ruled-out and the merged.

        ``score`` maps poses to summed beam log-likelihoods; a rival's log predictive likelihood is
        the log of the mean of its samples' tempered likelihoods, and ``cloud_log_predictive`` is the
        cloud's (its prior weights times its tempered likelihoods): their difference is the scan's
        log Bayes factor between the two hypotheses, as the particle filter itself weighs modes.
        """
        kept = []
        for rival in self.rivals:
            tempered = temper * score(rival.samples)
            rival.best = rival.samples[int(np.argmax(tempered))].copy()
            rival.log_odds += float(logsumexp(tempered)) - math.log(len(tempered)) - cloud_log_predictive
            rival.samples = rival.samples[low_variance_resample(normalize_log_weights(tempered), len(tempered), rng)]
            if rival.log_odds >= -self.log_threshold and self.apart(rival.best, best_pose):
                kept.append(rival)
        self.rivals = kept

    def weigh_cue(self, log_likelihood: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                  cloud_log_predictive: float) -> None:
        """Multiply each rival's odds by another sensor's Bayes factor (``log_likelihood`` of poses, untempered;
        ``cloud_log_predictive`` the cloud's); the next scan rules out or crowns them as usual."""
        for rival in self.rivals:
            values = log_likelihood(rival.samples)
            rival.log_odds += float(logsumexp(values)) - math.log(len(values)) - cloud_log_predictive

    def consider(self, means: NDArray[np.float64], weights: NDArray[np.float64],
                 members: list[NDArray[np.float64]], member_weights: list[NDArray[np.float64]],
                 best_pose: NDArray[np.float64], best_weight: float, rng: np.random.Generator) -> None:
        """Take the clusters (other than the best) whose odds exceed ``1 / odds`` as rivals, likeliest first."""
        for mean, weight, poses, pose_weights in zip(means, weights, members, member_weights, strict=True):
            log_odds = math.log(max(float(weight), 1e-300) / best_weight)
            if log_odds < -self.log_threshold or not self.apart(mean, best_pose):
                continue
            if any(not self.apart(mean, rival.best) for rival in self.rivals):
                continue
            if len(self.rivals) >= self.capacity:
                weakest = min(range(len(self.rivals)), key=lambda i: self.rivals[i].log_odds)
                if self.rivals[weakest].log_odds >= log_odds:
                    continue
                del self.rivals[weakest]
            chosen = low_variance_resample(pose_weights / pose_weights.sum(), self.sample_count, rng)
            self.rivals.append(Rival(poses[chosen].copy(), log_odds, np.asarray(mean, dtype=np.float64).copy()))

    def winner(self) -> Rival | None:
        """The rival whose odds exceed ``odds`` (the likeliest), or None."""
        best = max(self.rivals, key=lambda r: r.log_odds, default=None)
        return best if best is not None and best.log_odds >= self.log_threshold else None
