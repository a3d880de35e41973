"""Every parameter of ``mcl_baseline``, with nav2_amcl's names where nav2 has the concept.

Each default says its source: "nav2 X" is nav2_amcl's default (jazzy ``amcl_node.cpp``)
where ours differs, "ours" a setting nav2 does not have. Why each differs: docs/mcl.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import SettingsError
from ..motion import OdometryMotionModel
from ..settings import Settings, setting

__all__ = ["MclSettings", "LASER_MODEL_TYPES", "ROBOT_MODEL_TYPES", "RECOVERY_SAMPLINGS"]

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
_BIG = 1e6


@dataclass(frozen=True)
class MclSettings(Settings):
    """Settings of :class:`~.localizer.MonteCarloLocalizer` (docs/mcl.md argues each departure from nav2)."""

    min_particles: int = setting(500, "fewest particles KLD-sampling keeps (nav2 500)", low=1, high=10_000_000)
    max_particles: int = setting(
        50000, "most particles; also the size of a global or initial cloud (nav2 2000)", low=1, high=10_000_000
    )
    alpha1: float = setting(
        0.02, "rotation noise from rotation, std = sqrt(alpha1 rot^2 + alpha2 trans^2) (nav2 0.2)", low=0.0, high=100.0
    )
    alpha2: float = setting(0.02, "rotation noise from translation (nav2 0.2)", low=0.0, high=100.0)
    alpha3: float = setting(0.02, "translation noise from translation (nav2 0.2)", low=0.0, high=100.0)
    alpha4: float = setting(0.02, "translation noise from rotation (nav2 0.2)", low=0.0, high=100.0)
    alpha5: float = setting(
        0.02, "strafe noise from translation, omnidirectional model only (nav2 0.2)", low=0.0, high=100.0
    )
    tracking_alpha1: float = setting(
        -1.0, "alpha1 once the filter has been LOCALIZED since its last start: the odometry's own noise; negative: "
        "alpha1 (nav2: one set). Until then the wider alpha1..alpha4 keep a searching cloud diverse (docs/mcl.md)",
        low=-1.0, high=100.0)
    tracking_alpha2: float = setting(-1.0, "alpha2 once LOCALIZED since the last start; negative: alpha2", low=-1.0,
                                     high=100.0)
    tracking_alpha3: float = setting(-1.0, "alpha3 once LOCALIZED since the last start; negative: alpha3", low=-1.0,
                                     high=100.0)
    tracking_alpha4: float = setting(-1.0, "alpha4 once LOCALIZED since the last start; negative: alpha4", low=-1.0,
                                     high=100.0)
    robot_model_type: str = setting(
        "differential", "odometry motion model (nav2 plugin names accepted)", choices=tuple(ROBOT_MODEL_TYPES)
    )
    laser_model_type: str = setting("likelihood_field", "laser sensor model (nav2 likelihood_field); only the "
                                    "likelihood field reads unknown space as unknown (unknown_occupancy), the beam "
                                    "model scores it as nav2 does (docs/mcl.md, Partial maps)",
                                    choices=LASER_MODEL_TYPES)
    z_hit: float = setting(0.5, "weight of the hit component of the laser model (nav2 0.5)", low=0.0, high=_BIG)
    z_short: float = setting(0.05, "weight of the short-reading component, beam model (nav2 0.05)", low=0.0, high=_BIG)
    z_max: float = setting(0.05, "weight of the max-range component, beam model (nav2 0.05)", low=0.0, high=_BIG)
    z_rand: float = setting(0.5, "weight of the random-reading component (nav2 0.5)", low=0.0, high=_BIG)
    sigma_hit: float = setting(0.2, "standard deviation of the hit Gaussian (nav2 0.2)", unit="m",
                               low=0.0, low_open=True, high=100.0)
    lambda_short: float = setting(0.1, "decay of the short-reading exponential, beam model (nav2 0.1)", unit="1/m",
                                  low=0.0, low_open=True, high=_BIG)
    laser_likelihood_max_dist: float = setting(
        2.0, "distance to obstacles beyond which the likelihood field is flat (nav2 2.0)", unit="m",
        low=0.0, low_open=True, high=1e3,
    )
    max_beams: int = setting(60, "valid beams used per scan, evenly spaced (nav2 60)", low=1, high=100_000)
    unknown_occupancy: float = setting(
        0.8, "once converged, an end point in open unknown space (or off the map) scores at least this share "
        "of a mapped hit, as if unknown cells held an obstacle with this probability; 0: by its distance to the "
        "nearest mapped obstacle, as nav2 (ours)", low=0.0, high=1.0,
    )
    unmapped_obstacle_weight: float = setting(
        0.5, "likelihood field: an obstacle the map does not hold (a person, a box) explains a reading at range r "
        "with weight * decay * exp(-decay * r), the beam model's short-reading class; a reading scores the "
        "better of that and the map's explanation. 0.5 (z_hit): right at the laser it explains a reading as "
        "well as a mapped wall; 0: nav2 (ours)", low=0.0, high=_BIG,
    )
    unmapped_obstacle_decay: float = setting(
        1.0, "decay of the unmapped-obstacle explanation with range (1: it halves every 0.69 m; ours)",
        unit="1/m", low=0.0, low_open=True, high=_BIG,
    )
    do_beamskip: bool = setting(True, "once converged, skip the beams that few particles place near a mapped "
                                "obstacle (nav2 false, and only with likelihood_field_prob)")
    beam_skip_distance: float = setting(0.5, "an end point this close to a mapped obstacle agrees with the map "
                                        "(nav2 0.5)", unit="m", low=0.0, low_open=True, high=100.0)
    beam_skip_threshold: float = setting(0.3, "a beam is skipped when particles holding less than this share of "
                                         "the weight agree (nav2 0.3, of the particle count)", low=0.0, high=1.0)
    beam_skip_error_threshold: float = setting(0.9, "when more than this share of the beams would be skipped, none "
                                               "is (the filter, not the map, is likely wrong; nav2 0.9)",
                                               low=0.0, high=1.0)
    laser_max_range: float = setting(
        100.0, "readings at or beyond are no-returns; <= 0: the scan's range_max (nav2 100)", unit="m",
        low=-1.0, high=_BIG,
    )
    laser_min_range: float = setting(
        -1.0, "readings below are ignored; <= 0: the scan's range_min (nav2 -1)", unit="m", low=-1.0, high=_BIG
    )
    update_min_d: float = setting(0.25, "translation before a filter update (nav2 0.25)", unit="m", low=0.0, high=1e3)
    update_min_a: float = setting(0.2, "rotation before a filter update (nav2 0.2)", unit="rad", low=0.0, high=7.0)
    standstill_check: bool = setting(
        True, "a scan without motion enough for an update still updates the filter when it contradicts it (its fit "
        "at the last LOCALIZED pose collapses, or the last update's did): a robot carried away while standing; "
        "false: nav2, no update without motion (ours)")
    resample_interval: int = setting(1, "filter updates between resamplings (nav2 1)", low=1, high=1000)
    resample_effective_fraction: float = setting(
        0.5, "resample only when the effective sample size is below this fraction of the particles "
        "(1.0: every resample_interval updates, as nav2; ours)", low=0.0, low_open=True, high=1.0,
    )
    recovery_alpha_slow: float = setting(
        0.001, "rate of the slow average of the scan fit; 0 with recovery_alpha_fast 0 disables recovery "
        "(nav2 0.0, suggests 0.001)", low=0.0, high=1.0,
    )
    recovery_alpha_fast: float = setting(
        0.1, "rate of the fast average of the scan fit (nav2 0.0, suggests 0.1)", low=0.0, high=1.0
    )
    recovery_unknown_neutral: bool = setting(
        True, "once converged, beams the map cannot judge (end points credited as open unknown space) are neutral "
        "to the injection: the fit that drives it leaves them out and moves its averages by the share of beams it "
        "judges, and with recovery_requires_better they count at the slow average fit, whatever the status; the "
        "credit is also kept while the cloud spreads by the motion model alone after LOCALIZED; false: they count "
        "as scored and only a compact cloud is credited, as before (ours)")
    recovery_min_injection: float = setting(
        0.05, "random-particle fractions below this are not injected (ours)", low=0.0, high=1.0
    )
    recovery_sampling: str = setting(
        "measurement", "injected poses: the best-fitting of many uniform draws (measurement, ours) or uniform (nav2)",
        choices=RECOVERY_SAMPLINGS,
    )
    recovery_requires_better: bool = setting(
        True, "while LOCALIZED, with recovery_sampling measurement, inject only draws that explain the scan "
        "better than every particle (ours)")
    recovery_candidates: int = setting(
        10, "uniform draws scored per injected particle with recovery_sampling measurement (ours)", low=1, high=1000
    )
    global_start_candidates: int = setting(
        10, "a global start (no initial pose, reinitialize, a new map while not LOCALIZED) keeps, at its first scan, "
        "the max_particles poses that explain the scan best among this many times as many uniform draws (sensor "
        "resetting, ours); 1: nav2's uniform cloud", low=1, high=1000
    )
    pf_err: float = setting(0.05, "KLD-sampling: bound on the Kullback-Leibler error (nav2 0.05)",
                            low=0.0, low_open=True, high=1.0)
    pf_z: float = setting(
        0.99, "KLD-sampling: normal quantile of the bound, used as nav2 uses it (nav2 0.99)", low=0.0, high=10.0
    )
    initial_std_xy: float = setting(
        0.5, "position standard deviation of a new cloud around a known pose (ROS 1 amcl 0.5)", unit="m",
        low=0.0, high=1e3,
    )
    initial_std_yaw: float = setting(
        math.pi / 12.0, "heading standard deviation of a new cloud around a known pose (ROS 1 amcl pi/12)", unit="rad",
        low=0.0, high=7.0,
    )
    effective_beams: float = setting(
        20.0, "independent beams a scan counts for in the particle weight (tempering; ours)",
        low=0.0, low_open=True, high=_BIG,
    )
    min_effective_fraction: float = setting(
        0.1, "adaptive tempering keeps at least this share of effective particles per update; 0: off (ours)",
        low=0.0, high=1.0,
    )
    random_seed: int = setting(0, "seed of the filter's random numbers; -1: from the OS (ours)", low=-1, high=2**31 - 1)
    cluster_weight_mass: float = setting(0.99, "share of the weight whose particles are clustered (ours)",
                                         low=0.0, low_open=True, high=1.0)
    localized_max_std_xy: float = setting(
        0.25, "LOCALIZED needs the cluster's position std at most this (ours)", unit="m",
        low=0.0, low_open=True, high=1e3,
    )
    localized_max_std_yaw: float = setting(
        0.15, "LOCALIZED needs the cluster's heading std at most this (ours)", unit="rad",
        low=0.0, low_open=True, high=7.0,
    )
    localized_min_effective_particles: float = setting(
        10.0, "LOCALIZED needs at least this effective sample size (ours)", low=0.0, high=1e9
    )
    lost_fit_ratio: float = setting(
        0.6, "the fit is collapsing (not LOCALIZED) when the fit over every beam, averaged fast or of this scan, "
        "falls below this share of its slow average (ours)", low=0.0, high=1.0
    )
    localized_min_explained: float = setting(
        0.9, "a place the filter did not reach by tracking a LOCALIZED one (a global start, an injection, a rival "
        "that won) is LOCALIZED only once this share of a scan's end points lie within two cells of a mapped "
        "obstacle at the estimate, AMBIGUOUS until then: a place the map cannot vouch for is a guess; the "
        "initial pose vouches for itself; 0: off (ours)", low=0.0, high=1.0
    )
    ambiguous_cluster_weight: float = setting(
        0.2, "a second cluster this heavy makes the state AMBIGUOUS, never LOCALIZED (ours)", low=0.0, high=1.0
    )
    rival_odds: float = setting(
        100.0, "a particle cluster is a rival hypothesis while its posterior odds against the best cluster exceed "
        "1 / rival_odds: kept after resampling drops it, it holds the state at AMBIGUOUS until the scans rule it "
        "out, and the filter moves to it when its odds exceed rival_odds; beam skipping and the injection's "
        "must-do-better rule wait until the other clusters hold less than 1 / rival_odds (ours)",
        low=1.0, low_open=True, high=1e12,
    )
    max_rivals: int = setting(8, "rival hypotheses kept at most, the likeliest; 0: none (ours)", low=0, high=1000)
    rival_separation: float = setting(
        1.0, "a cluster this close to the best one (or to a rival), heading within 45 degrees, is the same "
        "hypothesis (ours)", unit="m", low=0.0, high=1e3,
    )
    max_reported_particles: int = setting(
        5000, "particles returned with each estimate, heaviest first (ours)", low=0, high=10_000_000
    )

    def validate(self) -> None:
        if self.min_particles > self.max_particles:
            raise SettingsError(
                f"MclSettings.min_particles ({self.min_particles!r}) exceeds max_particles ({self.max_particles!r})"
            )
        if self.z_hit + self.z_rand <= 0.0:
            raise SettingsError(f"MclSettings.z_hit + z_rand must be positive, got {self.z_hit!r} + {self.z_rand!r}")

    @property
    def omnidirectional(self) -> bool:
        return ROBOT_MODEL_TYPES[self.robot_model_type]

    def motion_model(self) -> OdometryMotionModel:
        return OdometryMotionModel(
            self.alpha1, self.alpha2, self.alpha3, self.alpha4, self.alpha5, omnidirectional=self.omnidirectional
        )

    def tracking_motion_model(self) -> OdometryMotionModel:
        """The motion model once the filter has been LOCALIZED since its last start: ``tracking_alpha*`` where set,
        else ``alpha*``."""
        def own(tracking: float, wide: float) -> float:
            return tracking if tracking >= 0.0 else wide

        return OdometryMotionModel(
            own(self.tracking_alpha1, self.alpha1), own(self.tracking_alpha2, self.alpha2),
            own(self.tracking_alpha3, self.alpha3), own(self.tracking_alpha4, self.alpha4), self.alpha5,
            omnidirectional=self.omnidirectional,
        )
