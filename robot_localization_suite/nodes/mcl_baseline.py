"""``mcl_baseline``: Monte Carlo localization at the level of nav2_amcl, as a ROS 2 node.

Parameter names are nav2_amcl's (``min_particles``, ``alpha1``, ``z_hit``,
``initial_pose.x`` ...), so the ``amcl:`` section of a nav2 params file carries
over once renamed ``mcl_baseline:`` (nav2 parameters this node does not have,
such as frame ids or beam skipping, are simply not declared and are ignored).
Each value is copied one to one into
:class:`~robot_localization_suite.core.mcl.MclSettings`, which documents the
defaults and where they differ from nav2's. The node itself is the shared
:class:`~robot_localization_suite.nodes.localizer_node.LocalizerNode`.
"""

from __future__ import annotations

import sys
from dataclasses import fields
from typing import Any

from ..core.mcl.localizer import MclSettings, MonteCarloLocalizer
from .common import ParamSpec
from .localizer_node import localizer_node_main

__all__ = ["NODE_NAME", "DESCRIPTION", "PARAMS", "make_localizer", "main"]

NODE_NAME = "mcl_baseline"
DESCRIPTION = (
    "Adaptive Monte Carlo localization as nav2_amcl does it (odometry motion model, likelihood-field or "
    "beam laser model, KLD-sampling, Augmented-MCL recovery, estimate from the heaviest particle cluster), "
    "with nav2_amcl's parameter names."
)

_D = MclSettings()

# ROS parameter name -> MclSettings field, where they differ (nav2 nests the initial pose).
_RENAMED = {
    "initial_pose.x": "initial_pose_x",
    "initial_pose.y": "initial_pose_y",
    "initial_pose.yaw": "initial_pose_yaw",
}

PARAMS = (
    ParamSpec("min_particles", _D.min_particles, "fewest particles KLD-sampling keeps (nav2 500)", 1, 10_000_000),
    ParamSpec("max_particles", _D.max_particles, "most particles; also the size of a global or initial cloud (nav2 2000)", 1, 10_000_000),
    ParamSpec("alpha1", _D.alpha1, "rotation noise from rotation, std = sqrt(alpha1 rot^2 + alpha2 trans^2) (nav2 0.2)", 0.0, 100.0),
    ParamSpec("alpha2", _D.alpha2, "rotation noise from translation (nav2 0.2)", 0.0, 100.0),
    ParamSpec("alpha3", _D.alpha3, "translation noise from translation (nav2 0.2)", 0.0, 100.0),
    ParamSpec("alpha4", _D.alpha4, "translation noise from rotation (nav2 0.2)", 0.0, 100.0),
    ParamSpec("alpha5", _D.alpha5, "strafe noise from translation, omnidirectional model only (nav2 0.2)", 0.0, 100.0),
    ParamSpec("robot_model_type", _D.robot_model_type,
              "'differential' or 'omnidirectional' (nav2_amcl::DifferentialMotionModel / OmniMotionModel accepted)"),
    ParamSpec("laser_model_type", _D.laser_model_type, "'likelihood_field' or 'beam'"),
    ParamSpec("z_hit", _D.z_hit, "weight of the hit component of the laser model (nav2 0.5)", 0.0, 1e6),
    ParamSpec("z_short", _D.z_short, "weight of the short-reading component, beam model (nav2 0.05)", 0.0, 1e6),
    ParamSpec("z_max", _D.z_max, "weight of the max-range component, beam model (nav2 0.05)", 0.0, 1e6),
    ParamSpec("z_rand", _D.z_rand, "weight of the random-reading component (nav2 0.5)", 0.0, 1e6),
    ParamSpec("sigma_hit", _D.sigma_hit, "standard deviation of the hit Gaussian [m] (nav2 0.2)", 1e-6, 100.0),
    ParamSpec("lambda_short", _D.lambda_short, "decay of the short-reading exponential, beam model [1/m] (nav2 0.1)", 1e-6, 1e6),
    ParamSpec("laser_likelihood_max_dist", _D.laser_likelihood_max_dist,
              "distance to obstacles beyond which the likelihood field is flat [m] (nav2 2.0)", 1e-3, 1e3),
    ParamSpec("max_beams", _D.max_beams, "valid beams used per scan, evenly spaced (nav2 60)", 1, 100_000),
    ParamSpec("laser_max_range", _D.laser_max_range, "readings at or beyond are no-returns [m]; -1: the scan's range_max (nav2 100)", -1.0, 1e6),
    ParamSpec("laser_min_range", _D.laser_min_range, "readings below are ignored [m]; -1: the scan's range_min (nav2 -1)", -1.0, 1e6),
    ParamSpec("update_min_d", _D.update_min_d, "translation before a filter update [m] (nav2 0.25)", 0.0, 1e3),
    ParamSpec("update_min_a", _D.update_min_a, "rotation before a filter update [rad] (nav2 0.2)", 0.0, 7.0),
    ParamSpec("resample_interval", _D.resample_interval, "filter updates between resamplings (nav2 1)", 1, 1000),
    ParamSpec("resample_effective_fraction", _D.resample_effective_fraction,
              "resample only when the effective sample size is below this fraction of the particles "
              "(1.0: every resample_interval updates, as nav2)", 0.0, 1.0),
    ParamSpec("recovery_alpha_slow", _D.recovery_alpha_slow,
              "rate of the slow average of the scan fit; 0 with recovery_alpha_fast 0 disables recovery (nav2 0.0, suggests 0.001)", 0.0, 1.0),
    ParamSpec("recovery_alpha_fast", _D.recovery_alpha_fast,
              "rate of the fast average of the scan fit (nav2 0.0, suggests 0.1)", 0.0, 1.0),
    ParamSpec("recovery_min_injection", _D.recovery_min_injection,
              "random-particle fractions below this are not injected (not in nav2)", 0.0, 1.0),
    ParamSpec("recovery_sampling", _D.recovery_sampling,
              "injected poses: 'measurement' (best-fitting of many uniform draws) or 'uniform' (nav2)"),
    ParamSpec("recovery_candidates", _D.recovery_candidates,
              "uniform draws scored per injected particle with recovery_sampling 'measurement'", 1, 1000),
    ParamSpec("pf_err", _D.pf_err, "KLD-sampling: bound on the Kullback-Leibler error (nav2 0.05)", 1e-6, 1.0),
    ParamSpec("pf_z", _D.pf_z, "KLD-sampling: normal quantile of the bound, used as nav2 uses it (nav2 0.99)", 0.0, 10.0),
    ParamSpec("set_initial_pose", _D.set_initial_pose, "start around initial_pose.* instead of uniformly over free space"),
    ParamSpec("initial_pose.x", _D.initial_pose_x, "initial pose x in the map [m]"),
    ParamSpec("initial_pose.y", _D.initial_pose_y, "initial pose y in the map [m]"),
    ParamSpec("initial_pose.yaw", _D.initial_pose_yaw, "initial pose heading in the map [rad]", -7.0, 7.0),
    ParamSpec("initial_std_xy", _D.initial_std_xy, "position standard deviation around initial_pose.* [m] (ROS 1 amcl 0.5)", 0.0, 1e3),
    ParamSpec("initial_std_yaw", _D.initial_std_yaw, "heading standard deviation around initial_pose.* [rad] (ROS 1 amcl pi/12)", 0.0, 7.0),
    ParamSpec("effective_beams", _D.effective_beams,
              "independent beams a scan counts for in the particle weight (tempering; not in nav2)", 1e-3, 1e6),
    ParamSpec("min_effective_fraction", _D.min_effective_fraction,
              "adaptive tempering keeps at least this share of effective particles per update; 0: off", 0.0, 1.0),
    ParamSpec("random_seed", _D.random_seed, "seed of the filter's random numbers; -1: from the OS", -1, 2**31 - 1),
    ParamSpec("cluster_weight_mass", _D.cluster_weight_mass, "share of the weight whose particles are clustered", 1e-6, 1.0),
    ParamSpec("localized_max_std_xy", _D.localized_max_std_xy, "LOCALIZED needs the cluster position std at most this [m]", 1e-6, 1e3),
    ParamSpec("localized_max_std_yaw", _D.localized_max_std_yaw, "LOCALIZED needs the cluster heading std at most this [rad]", 1e-6, 7.0),
    ParamSpec("localized_min_effective_particles", _D.localized_min_effective_particles,
              "LOCALIZED needs at least this effective sample size", 0.0, 1e9),
    ParamSpec("lost_fit_ratio", _D.lost_fit_ratio, "the fit is collapsing (not LOCALIZED) when w_fast < this * w_slow", 0.0, 1.0),
    ParamSpec("ambiguous_cluster_weight", _D.ambiguous_cluster_weight, "a second cluster this heavy makes the state AMBIGUOUS", 0.0, 1.0),
    ParamSpec("max_reported_particles", _D.max_reported_particles, "particles returned with each estimate (heaviest first)", 0, 10_000_000),
)


def _flatten(params: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"initial_pose": {"x": 1}}`` -> ``{"initial_pose.x": 1}`` (nav2 files nest the initial pose)."""
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def make_localizer(params: dict[str, Any]) -> MonteCarloLocalizer:
    """Build the core localizer from parameter values (missing ones take the defaults, unknown ones are ignored)."""
    flat = _flatten(params)
    settings_fields = {field.name: field for field in fields(MclSettings)}
    values: dict[str, Any] = {}
    for key, value in flat.items():
        name = _RENAMED.get(key, key)
        if name not in settings_fields:
            continue
        default = settings_fields[name].default
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        values[name] = value
    return MonteCarloLocalizer(MclSettings(**values))


def main() -> int:
    return localizer_node_main(sys.modules[__name__])


if __name__ == "__main__":
    sys.exit(main())
