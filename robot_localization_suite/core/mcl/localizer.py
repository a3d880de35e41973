"""Monte Carlo localization at the level of nav2_amcl.

The filter is the one of nav2_amcl (itself Player's ``amcl``) and of the
seeds' baselines (004 section 5.1, Algorithm 2; 001 section IV-C/D):

* particles over the *laser* pose (x, y, theta) in the map; the adapter turns
  it into the base pose (DESIGN.md: core localizers estimate the laser pose);
* prediction by the shared :class:`OdometryMotionModel` (nav2's differential
  model, or its omnidirectional one), applied only once the odometry has moved
  by ``update_min_d`` [m] or turned by ``update_min_a`` [rad] since the last
  filter update (Euclidean translation and absolute rotation; nav2 compares
  each axis separately), or when an update is forced (first scan after an
  initialisation, ``request_nomotion_update``);
* correction by the likelihood-field model (default) or the beam model of
  :mod:`.sensor_models`, on at most ``max_beams`` beams;
* KLD-sampling of the particle count (``min_particles``..``max_particles``,
  ``pf_err``, ``pf_z``) and low-variance resampling every
  ``resample_interval`` updates (:mod:`.mcl_particles`), selectively: see
  "Selective resampling";
* Augmented MCL (Thrun et al., *Probabilistic Robotics* table 8.3):
  short- and long-term averages ``w_fast``, ``w_slow`` of the measurement fit
  (``recovery_alpha_fast``, ``recovery_alpha_slow``); at each resampling a
  fraction ``max(0, 1 - w_fast / w_slow)`` of the new particles is drawn
  over free space (uniformly as in nav2, or, by default, the best-fitting of
  many uniform draws: see "Recovery sampling");
* the estimate is the weighted mean of the heaviest particle cluster (nav2's
  ``getMaxWeightHyps``), with that cluster's covariance.

Choices where nav2 or the papers leave room, and why:

Particle weight. nav2 scores a particle by ``1 + sum_b p_b^3``, which hardly
separates a good pose from a bad one (DESIGN.md, measured). Here the weight is
a tempered product of the per-beam likelihoods,
``log w = min(1, effective_beams / B) * sum_b log p_b`` over the ``B`` beams
used. Each ``p_b`` is bounded below by the ``z_rand / max_range`` component,
which is the per-beam cap: one outlier costs at most
``log(z_hit + z_rand/max_range) - log(z_rand/max_range)`` nats, never
``-inf``. The tempering exponent accounts for the correlation of neighbouring
beams (and the map's own errors): without it, 60 beams make the posterior so
peaked that the filter over-commits; ``effective_beams`` is the number of
independent beams the scan is worth. It also makes the sharpness independent
of how many beams survived the validity checks.

Adaptive tempering. When one update would leave fewer than
``min_effective_fraction * N`` effective particles (``1 / sum w^2``), its
exponent is lowered (bisection) until that many remain. This only happens when
the cloud is spread over poses of very different fit (a global start, an
injection after a kidnapping): without it the first scan from a uniform cloud
picks a handful of particles, usually wrong ones, and the filter commits to
them; with it several hypotheses survive until motion separates them
(tempered likelihoods against weight degeneracy, as in SMC samplers). While
tracking, the effective sample size stays far above the floor and the weight
is the plain tempered product.

Beams. Valid readings are selected first (``Scan.hit_mask`` plus
``laser_min_range`` / ``laser_max_range``, and for the beam model the
no-returns), then ``max_beams`` of them are taken evenly spaced with
``Scan.subsample``: a scan with invalid readings still contributes
``max_beams`` beams when it has that many valid ones (nav2 subsamples first
and then drops the invalid ones). A scan with no usable beam is skipped
(``None``). A laser pose outside the map or inside an occupied cell gets the
lowest possible score (every beam at the floor): the robot cannot be inside a
wall, which nav2 does not exploit.

Recovery signal. Augmented MCL averages the measurement likelihood over the
particles. With a sharp log-likelihood, the raw average mixes scales wildly,
and with nav2's averaging the freshly injected random particles drag the
average down, which injects more random particles (nav2 therefore resets
``w_slow = w_fast = 0`` after each injection, which stops recovery after one
round). Here the fit of a scan is the geometric-mean per-beam likelihood
``exp(mean_b log p_b)`` of each particle averaged with the *posterior*
weights: it is how well the particles that explain the scan explain it, it is
independent of the beam count, and random particles with low likelihood do
not lower it. Injection therefore continues while the fit stays below its
long-term average, and stops as soon as a particle near the true pose
explains the scan again; there is no reset.
``w_slow`` and ``w_fast`` are exponential averages with Adam's bias
correction (running means over the first ``1/alpha`` updates) rather than
nav2's start at the first value: with ``recovery_alpha_slow = 0.001`` the
poor fit of an unconverged start would otherwise remain the reference for a
thousand updates and hide a later collapse (measured: the twin-office
kidnapping of ``office_kidnap`` went unnoticed for 20 s).

Recovery sampling. ``recovery_sampling: uniform`` draws the injected
particles uniformly over free space (Augmented MCL, nav2). The default,
``measurement``, draws ``recovery_candidates`` times as many uniform poses
(at most ``max_particles``), scores them against the scan of the update and
keeps the best-fitting ones: the sensor-resetting idea (Lenser & Veloso 2000)
and the dual proposal of Mixture MCL (Thrun, Fox, Burgard & Dellaert, "Robust
Monte Carlo localization", AI 2001, the seeds' reference [13] of 004). A
uniform particle must land within a few centimetres and degrees of the true
pose to beat a converged wrong cluster; the best of ten draws lands there ten
times as often. Measured on the simulated kidnap bags (3 seeds): office
kidnappings recovered in 18-20 s / 2-3 s versus 19-26 s / 2-3 s, and every
kidnapping of the corridor in global mode within 3.5 s.

Injection dead band. While tracking well, ``w_fast`` wanders a few percent
around ``w_slow``, so Thrun's formula injects a percent or two of random
particles about half of the time; each lands in its own KLD bin and would keep
the cloud near ``max_particles`` for nothing. Fractions below
``recovery_min_injection`` are therefore ignored. When the filter is lost the
fraction is large, and the random draws enter the KLD count as in nav2 (they
occupy many bins), so the cloud grows towards ``max_particles`` exactly when
coverage is needed.

Selective resampling. nav2 resamples at every update. Each resampling
copies the heaviest particles and drops the rest, so a converged cloud loses
its diversity even when the weights hardly differ (sample impoverishment);
after a recovery the cloud then sits 0.1 m off for seconds, moved only by the
motion noise. Here, as in Doucet et al. and GMapping (Grisetti, Stachniss &
Burgard 2007), the filter resamples only when the effective sample size
``1 / sum w^2`` falls below ``resample_effective_fraction * N`` (0.5), or
when Augmented MCL has particles to inject; otherwise the weights carry over
to the next update. Measured over filter seeds 0-2 (``rls_bench --mode
tracking``): tracking RMSE on corridor_kidnap 0.055 / 0.039 / 0.030 m with
1.0 (nav2) and 0.032 / 0.021 / 0.024 m with 0.5; office and floor within
0.005 m; the real logs stay at 100 % correct in both modes. (Raising
``alpha3`` to 0.05 instead gave similar simulated figures but 98.7 % on
orebro, whose scans are up to 3 m apart.)

Clusters. Particles holding at least ``cluster_weight_mass`` of the weight are
clustered (the nearly weightless rest would bridge separate hypotheses into
one cluster, most visibly during a global start), with nav2's bins and
26-neighbourhood, heading bins wrapping around.

Status. LOCALIZED when the heaviest cluster holds at least half the weight,
the weights are not degenerate (effective sample size at least
``localized_min_effective_particles``), its position standard deviation (largest axis) is at most
``localized_max_std_xy`` and its heading standard deviation at most
``localized_max_std_yaw``, and the fit is not collapsing
(``w_fast >= lost_fit_ratio * w_slow``); otherwise AMBIGUOUS when a second
cluster holds at least ``ambiguous_cluster_weight``, LOST when the filter had
been localized since the last initialisation, else INITIALIZING.

Cost. The likelihood lookup is a numba kernel (one table read per beam); the
rest is numpy without BLAS calls (OpenBLAS thread start-up costs milliseconds
on a busy 2-core machine). Clusters are formed from the particles heavier than
``(1 - cluster_weight_mass) / N``, which hold at least that share of the
weight, so no sort of the whole cloud is needed.

Output. ``on_scan`` returns an estimate only when the filter updated (nav2
publishes ``amcl_pose`` only then), ``None`` otherwise. Candidates are the
particles of the update, heaviest first, at most ``max_reported_particles``.

Initialisation. Without an initial pose the cloud is uniform over free space
with ``max_particles`` particles (nav2 ``pf_init_model``); ``set_initial_pose``
draws ``max_particles`` from a Gaussian (covariance diagonal floored at
``(2 cm)^2`` and ``(0.01 rad)^2`` so a zero covariance still spans a few KLD
bins). ``set_initial_pose`` parameter poses use ROS 1 amcl's initial
covariance (0.5 m, pi/12 rad standard deviations), since nav2 passes a zero one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..filter.odometry_gate import OdometryGate
from ..filter.particles import (
    cluster_particles,
    kld_particle_count,
    low_variance_resample,
    normalize_log_weights,
    weighted_pose_statistics,
)
from ..grid_map import GridMap
from ..localizer import Estimate, LocalizerStatus
from ..motion import OdometryMotionModel
from ..scan import Scan
from ..se2 import wrap_angle
from .sensor_models import BeamModel, LikelihoodFieldModel

__all__ = ["MclSettings", "MonteCarloLocalizer", "LASER_MODEL_TYPES", "ROBOT_MODEL_TYPES", "RECOVERY_SAMPLINGS"]

LASER_MODEL_TYPES = ("likelihood_field", "beam")
RECOVERY_SAMPLINGS = ("measurement", "uniform")
# nav2 (jazzy) names its motion-model plugins; older configs use the short names.
ROBOT_MODEL_TYPES = {
    "differential": False,
    "nav2_amcl::DifferentialMotionModel": False,
    "omnidirectional": True,
    "omni": True,
    "nav2_amcl::OmniMotionModel": True,
}

_MIN_INITIAL_STD_XY = 0.02  # [m]
_MIN_INITIAL_STD_YAW = 0.01  # [rad]


@dataclass(frozen=True)
class MclSettings:
    """Every setting of the Monte Carlo localizer (nav2_amcl names where nav2 has the concept).

    Sources: "nav2" = nav2_amcl's default (``amcl_node.cpp``, jazzy); "ours" =
    not in nav2, chosen here; deviations from nav2 are argued in each line.

    Attributes:
        min_particles: lower bound of the KLD particle count (nav2 500).
        max_particles: upper bound, and the size of a global or initial cloud.
            nav2 uses 2000; 50000 here because a global start needs the coverage
            (nav2 itself needed 50000 and 41 updates on Intel, DESIGN.md; 20000 here
            missed the 15 s first fix on office_kidnap) and KLD-sampling brings a
            converged cloud back to ``min_particles``, so tracking costs the same.
        alpha1..alpha4: odometry noise (nav2 names and semantics, std = sqrt(a * motion^2)).
            nav2's 0.2 loses track on the real logs (DESIGN.md: within 12 updates
            on Intel, while 0.02 holds). 0.02 (a standard deviation of 14 % of the
            motion) still covers several times the odometry errors of the bags;
            measured here, 0.05 dropped orebro (up to 3 m between scans) to
            96 % correct and 0.02 gave 100 % on all three real logs.
        alpha5: strafe noise of the omnidirectional model (same reasoning).
        robot_model_type: ``differential`` or ``omnidirectional`` (nav2 plugin names accepted).
        laser_model_type: ``likelihood_field`` (nav2 default) or ``beam``.
        z_hit, z_rand: likelihood-field / beam mixture weights (nav2 0.5, 0.5).
        z_short, z_max: beam-model weights (nav2 0.05, 0.05).
        sigma_hit: hit Gaussian standard deviation [m] (nav2 0.2).
        lambda_short: short-reading decay [1/m] (nav2 0.1).
        laser_likelihood_max_dist: distance cap of the likelihood field [m] (nav2 2.0).
        max_beams: beams used per scan (nav2 60).
        laser_max_range: readings at or beyond are no-returns [m]; <= 0: the scan's own (nav2 100).
        laser_min_range: readings below are invalid [m]; <= 0: the scan's own (nav2 -1).
        update_min_d: translation before a filter update [m] (nav2 0.25).
        update_min_a: rotation before a filter update [rad] (nav2 0.2).
        resample_interval: filter updates between resamplings (nav2 1).
        resample_effective_fraction: resample only when the effective sample size is below
            this fraction of the particle count (or particles are due to be injected); 1.0
            resamples every ``resample_interval`` updates, as nav2 (ours, see module doc).
        recovery_alpha_slow, recovery_alpha_fast: Augmented MCL averaging rates. nav2
            disables recovery (0.0, 0.0) and suggests 0.001 / 0.1; the suggested
            values are used because recovering from kidnapping is required here.
        recovery_min_injection: injected fractions below this are ignored (ours, see module doc).
        recovery_sampling: ``measurement`` (default, ours) or ``uniform`` (nav2), see module doc.
        recovery_candidates: uniform draws per injected particle for ``measurement`` (ours).
        pf_err: KLD bound on the Kullback-Leibler error (nav2 0.05).
        pf_z: normal quantile of the KLD bound, used as nav2 uses it (nav2 0.99).
        set_initial_pose: start around ``initial_pose_*`` instead of uniformly (nav2 false).
        initial_pose_x, initial_pose_y, initial_pose_yaw: that pose [m, m, rad] (nav2 0).
        initial_std_xy, initial_std_yaw: its standard deviations [m, rad] (ROS 1 amcl's
            initial_cov_xx = 0.25, initial_cov_aa = (pi/12)^2; nav2 uses zero).
        effective_beams: independent beams a scan is worth in the weight (ours, see module doc;
            20 of 60: the three real logs were 100 % correct with it, and 10 or 40
            did no better on the simulated ones).
        min_effective_fraction: adaptive tempering keeps at least this share of effective
            particles (ours, see module doc; 0.1 gave the first fix on office_kidnap
            within 3-15 s over 3 seeds, 0 took 17-21 s and 0.2 lost kidnappings).
        random_seed: seed of the generator; -1 draws one from the OS (ours; nav2 has none).
        cluster_weight_mass: weight share of the particles that are clustered (ours).
        localized_max_std_xy: LOCALIZED needs the cluster's position std at most this [m] (ours).
        localized_max_std_yaw: ... and its heading std at most this [rad] (ours).
        localized_min_effective_particles: ... and the effective sample size ``1 / sum w^2``
            at least this (ours: one lucky particle after a global start is not a fix).
        lost_fit_ratio: the fit is collapsing when w_fast < this * w_slow (ours).
        ambiguous_cluster_weight: a second cluster this heavy means AMBIGUOUS (ours).
        max_reported_particles: cap on the particles returned in an estimate (ours;
            the PoseArray conversion stops at 5000 anyway).
    """

    min_particles: int = 500
    max_particles: int = 50000
    alpha1: float = 0.02
    alpha2: float = 0.02
    alpha3: float = 0.02
    alpha4: float = 0.02
    alpha5: float = 0.02
    robot_model_type: str = "differential"
    laser_model_type: str = "likelihood_field"
    z_hit: float = 0.5
    z_short: float = 0.05
    z_max: float = 0.05
    z_rand: float = 0.5
    sigma_hit: float = 0.2
    lambda_short: float = 0.1
    laser_likelihood_max_dist: float = 2.0
    max_beams: int = 60
    laser_max_range: float = 100.0
    laser_min_range: float = -1.0
    update_min_d: float = 0.25
    update_min_a: float = 0.2
    resample_interval: int = 1
    resample_effective_fraction: float = 0.5
    recovery_alpha_slow: float = 0.001
    recovery_alpha_fast: float = 0.1
    recovery_min_injection: float = 0.05
    recovery_sampling: str = "measurement"
    recovery_candidates: int = 10
    pf_err: float = 0.05
    pf_z: float = 0.99
    set_initial_pose: bool = False
    initial_pose_x: float = 0.0
    initial_pose_y: float = 0.0
    initial_pose_yaw: float = 0.0
    initial_std_xy: float = 0.5
    initial_std_yaw: float = math.pi / 12.0
    effective_beams: float = 20.0
    min_effective_fraction: float = 0.1
    random_seed: int = 0
    cluster_weight_mass: float = 0.99
    localized_max_std_xy: float = 0.25
    localized_max_std_yaw: float = 0.15
    localized_min_effective_particles: float = 10.0
    lost_fit_ratio: float = 0.6
    ambiguous_cluster_weight: float = 0.2
    max_reported_particles: int = 5000

    def __post_init__(self) -> None:
        def finite(name: str) -> float:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"MCL setting {name} must be a finite number, got {value!r}")
            return float(value)

        def at_least(name: str, low: float, *, strict: bool = False) -> None:
            value = finite(name)
            if value < low or (strict and value == low):
                relation = ">" if strict else ">="
                raise ValueError(f"MCL setting {name} must be {relation} {low}, got {value!r}")

        for name in ("min_particles", "max_particles", "max_beams", "resample_interval", "max_reported_particles",
                     "recovery_candidates"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"MCL setting {name} must be an integer, got {value!r}")
        at_least("min_particles", 1)
        at_least("max_particles", 1)
        if self.min_particles > self.max_particles:
            raise ValueError(
                f"MCL setting min_particles ({self.min_particles!r}) exceeds max_particles ({self.max_particles!r})"
            )
        at_least("max_beams", 1)
        at_least("resample_interval", 1)
        at_least("resample_effective_fraction", 0.0, strict=True)
        if self.resample_effective_fraction > 1.0:
            raise ValueError(f"MCL setting resample_effective_fraction must be <= 1, got {self.resample_effective_fraction!r}")
        at_least("max_reported_particles", 0)
        at_least("recovery_candidates", 1)
        for name in ("alpha1", "alpha2", "alpha3", "alpha4", "alpha5", "z_hit", "z_short", "z_max", "z_rand"):
            at_least(name, 0.0)
        if self.z_hit + self.z_rand <= 0.0:
            raise ValueError(f"MCL settings z_hit + z_rand must be positive, got {self.z_hit!r} + {self.z_rand!r}")
        for name in ("sigma_hit", "lambda_short", "laser_likelihood_max_dist", "effective_beams", "pf_err"):
            at_least(name, 0.0, strict=True)
        for name in ("laser_max_range", "laser_min_range", "initial_pose_x", "initial_pose_y", "initial_pose_yaw"):
            finite(name)
        for name in ("update_min_d", "update_min_a", "pf_z", "initial_std_xy", "initial_std_yaw"):
            at_least(name, 0.0)
        for name in ("recovery_alpha_slow", "recovery_alpha_fast", "recovery_min_injection", "min_effective_fraction",
                     "cluster_weight_mass", "lost_fit_ratio",
                     "ambiguous_cluster_weight"):
            value = finite(name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"MCL setting {name} must be in [0, 1], got {value!r}")
        if self.cluster_weight_mass <= 0.0:
            raise ValueError(f"MCL setting cluster_weight_mass must be > 0, got {self.cluster_weight_mass!r}")
        at_least("localized_max_std_xy", 0.0, strict=True)
        at_least("localized_max_std_yaw", 0.0, strict=True)
        at_least("localized_min_effective_particles", 0.0)
        if self.robot_model_type not in ROBOT_MODEL_TYPES:
            raise ValueError(
                f"MCL setting robot_model_type must be one of {sorted(ROBOT_MODEL_TYPES)}, got {self.robot_model_type!r}"
            )
        if self.laser_model_type not in LASER_MODEL_TYPES:
            raise ValueError(
                f"MCL setting laser_model_type must be one of {LASER_MODEL_TYPES}, got {self.laser_model_type!r}"
                + (" (beam skipping is not implemented; use likelihood_field)"
                   if self.laser_model_type == "likelihood_field_prob" else "")
            )
        if self.recovery_sampling not in RECOVERY_SAMPLINGS:
            raise ValueError(
                f"MCL setting recovery_sampling must be one of {RECOVERY_SAMPLINGS}, got {self.recovery_sampling!r}"
            )
        if not isinstance(self.random_seed, (int, np.integer)) or isinstance(self.random_seed, bool):
            raise ValueError(f"MCL setting random_seed must be an integer, got {self.random_seed!r}")
        if self.random_seed < -1:
            raise ValueError(f"MCL setting random_seed must be >= -1, got {self.random_seed!r}")

    @property
    def omnidirectional(self) -> bool:
        return ROBOT_MODEL_TYPES[self.robot_model_type]

    def motion_model(self) -> OdometryMotionModel:
        return OdometryMotionModel(
            self.alpha1, self.alpha2, self.alpha3, self.alpha4, self.alpha5, omnidirectional=self.omnidirectional
        )


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

    def update(self, x: float) -> None:
        if self.alpha == 0.0:
            if self.value == 0.0:
                self.value = float(x)
            return
        self._raw += self.alpha * (float(x) - self._raw)
        self._decay *= 1.0 - self.alpha
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
        self.counters = MclCounters()
        self.grid_map: GridMap | None = None
        self._map_fingerprint: str | None = None
        self._sensor: LikelihoodFieldModel | BeamModel | None = None
        self._free_mask: NDArray[np.bool_] | None = None
        self.particles = np.zeros((0, 3))
        self.log_weights = np.zeros(0)
        # Odometry poses for interpolation at scan stamps; the reference is the odometry at the last update.
        self.odometry = OdometryGate(self.settings.update_min_d, self.settings.update_min_a)
        self._reset_filter_state()
        self.last_estimate: Estimate | None = None
        if self.settings.set_initial_pose:
            s = self.settings
            self._pending: _Init | None = _Init(
                np.array([s.initial_pose_x, s.initial_pose_y, s.initial_pose_yaw]),
                np.diag([s.initial_std_xy**2, s.initial_std_xy**2, s.initial_std_yaw**2]),
            )
        else:
            self._pending = _Init()
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
                grid_map, z_hit=s.z_hit, z_rand=s.z_rand, sigma_hit=s.sigma_hit, max_distance=s.laser_likelihood_max_dist
            )
        self._free_mask = ~grid_map.occupied_mask
        # Load the compiled kernels now (map setup), not in the first update.
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
        if not (moved or gate.forced):
            return None
        if moved:
            self.particles = self.motion_model.sample(self.particles, gate.reference, odom, self.rng)
        gate.mark_updated(odom if moved else gate.reference)
        return self._update(scan.stamp, beams)

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
        if init.pose is None:
            self.particles = self.grid_map.sample_free_poses(count, self.rng)
        else:
            cov = 0.5 * (init.covariance + init.covariance.T)
            floor = np.array([_MIN_INITIAL_STD_XY**2, _MIN_INITIAL_STD_XY**2, _MIN_INITIAL_STD_YAW**2])
            cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
            values, vectors = np.linalg.eigh(cov)
            scale = vectors * np.sqrt(np.maximum(values, 0.0))
            particles = init.pose + self.rng.standard_normal((count, 3)) @ scale.T
            particles[:, 2] = wrap_angle(particles[:, 2])
            self.particles = particles
        self.log_weights = np.zeros(count)
        self._reset_filter_state()

    def _reset_filter_state(self) -> None:
        """What a fresh cloud starts with: no odometry reference, recovery averages cleared."""
        self.odometry.reset()
        self._updates_since_resample = 0
        self.w_slow = 0.0
        self.w_fast = 0.0
        self._fit_slow = _RunningAverage(self.settings.recovery_alpha_slow)
        self._fit_fast = _RunningAverage(self.settings.recovery_alpha_fast)
        self._ever_localized = False

    def _select_beams(self, scan: Scan) -> _Beams | None:
        """Valid beams of ``scan``, ``max_beams`` of them evenly spaced; None if there is none."""
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

    def _update(self, stamp: float, beams: _Beams) -> Estimate:
        s = self.settings
        assert self._sensor is not None and self.grid_map is not None
        beam_count = len(beams.angles)
        log_likelihood = self._sensor.log_likelihood(self.particles, beams.angles, beams.ranges, max_range=beams.max_range)
        floor = self._sensor.floor_log_likelihood(beams.max_range)
        log_likelihood[~self._pose_is_possible(self.particles)] = beam_count * floor
        temper = min(1.0, s.effective_beams / beam_count)
        temper *= self._adaptive_temper(temper * log_likelihood)
        self.log_weights = self.log_weights + temper * log_likelihood
        weights = normalize_log_weights(self.log_weights)

        # Augmented MCL: posterior-weighted geometric-mean per-beam likelihood (module docstring).
        fit = float((weights * np.exp(log_likelihood / beam_count)).sum())
        self._fit_slow.update(fit)
        self._fit_fast.update(fit)
        self.w_slow, self.w_fast = self._fit_slow.value, self._fit_fast.value

        effective = float(1.0 / np.sum(weights * weights))  # effective sample size
        estimate = self._estimate(stamp, weights, fit, beam_count, effective)

        self._updates_since_resample += 1
        # Selective resampling (module docstring): only when the weights have degenerated, or
        # when Augmented MCL wants to inject particles.
        degenerate = (s.resample_effective_fraction >= 1.0
                      or effective < s.resample_effective_fraction * len(weights))
        if self._updates_since_resample >= s.resample_interval and (degenerate or self._injection_fraction() > 0.0):
            self._updates_since_resample = 0
            next_count, injected, bins = self._resample(weights, beams)
            estimate.details.update(particles_next=next_count, injected=injected, kld_bins=bins)
        self.counters.updates += 1
        self.last_estimate = estimate
        return estimate

    def _estimate(self, stamp: float, weights: NDArray[np.float64], fit: float, beam_count: int,
                  effective: float) -> Estimate:
        s = self.settings
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

        std_xy = math.sqrt(max(float(np.linalg.eigvalsh(covariance[:2, :2])[-1]), 0.0))
        std_yaw = math.sqrt(max(float(covariance[2, 2]), 0.0))
        compact = best_weight >= 0.5 and effective >= s.localized_min_effective_particles and std_xy <= s.localized_max_std_xy and std_yaw <= s.localized_max_std_yaw
        fit_holds = self.w_slow <= 0.0 or self.w_fast >= s.lost_fit_ratio * self.w_slow
        if compact and fit_holds:
            status = LocalizerStatus.LOCALIZED
            self._ever_localized = True
        elif second_weight >= s.ambiguous_cluster_weight:
            status = LocalizerStatus.AMBIGUOUS
        elif self._ever_localized:
            status = LocalizerStatus.LOST
        else:
            status = LocalizerStatus.INITIALIZING

        reported = _heaviest_first(weights, s.max_reported_particles)

        return Estimate(
            stamp=float(stamp),
            pose=pose,
            covariance=covariance,
            status=status,
            candidates=self.particles[reported].copy(),
            candidate_weights=weights[reported].copy(),
            details={
                "particles": int(len(self.particles)),
                "clusters": int(cluster_count),
                "cluster_weight": round(best_weight, 4),
                "beams": int(beam_count),
                "fit": round(fit, 5),
                "effective_sample_size": round(effective, 1),
                "w_slow": round(self.w_slow, 5),
                "w_fast": round(self.w_fast, 5),
            },
        )

    def _recovery_poses(self, count: int, beams: _Beams) -> NDArray[np.float64]:
        """``count`` poses for Augmented-MCL injection (``recovery_sampling``)."""
        assert self.grid_map is not None and self._sensor is not None
        s = self.settings
        if s.recovery_sampling == "uniform" or count == 0:
            return self.grid_map.sample_free_poses(count, self.rng)
        # measurement: the best-fitting of recovery_candidates x count uniform poses (sensor
        # resetting), the pool capped at max_particles to bound the cost of one update
        pool = max(count, min(count * s.recovery_candidates, s.max_particles))
        candidates = self.grid_map.sample_free_poses(pool, self.rng)
        scores = self._sensor.log_likelihood(candidates, beams.angles, beams.ranges, max_range=beams.max_range)
        best = np.argpartition(-scores, count - 1)[:count]
        return candidates[best]

    def _injection_fraction(self) -> float:
        """Augmented MCL's share of random particles, ``max(0, 1 - w_fast / w_slow)``, 0 inside the dead band."""
        inject = max(0.0, 1.0 - self.w_fast / self.w_slow) if self.w_slow > 0.0 else 0.0
        return inject if inject >= self.settings.recovery_min_injection else 0.0

    def _resample(self, weights: NDArray[np.float64], beams: _Beams) -> tuple[int, int, int]:
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
        kept = low_variance_resample(weights, count - injected, self.rng)
        particles = self.particles[kept]
        if injected:
            particles = np.vstack([particles, self._recovery_poses(injected, beams)])
            self.counters.injected_particles += injected
        self.particles = particles
        self.log_weights = np.zeros(len(particles))
        return count, injected, bins
