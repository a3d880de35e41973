"""``ir_initializer``: information-retrieval global initialisation and a 100-particle tracker, as a ROS 2 node.

Aycard & Brouard (seed 001). Each ROS parameter is copied one to one into
:class:`~robot_localization_suite.core.ir.IRSettings`, whose docstring (and
``core/ir.py``'s module docstring) gives units, defaults and their sources.
Angles are in radians (REP 103); nav2_amcl's names where it has the same
notion (``alpha1..4``, ``update_min_d``, ``update_min_a``, ``max_beams``).

The node initialises on the first scan after the map (precomputing, or
loading from the cache, the index first), on
``~/reinitialize_global_localization``, and by itself when the particles stop
matching the map (LOST). ``~/candidates`` holds the ranked poses after an
initialisation and the particles afterwards.
"""

from __future__ import annotations

import math
import sys
from typing import Any

from ..core.ir.localizer import IRLocalizer, IRSettings
from .common import ParamSpec
from .localizer_node import localizer_node_main

__all__ = ["NODE_NAME", "DESCRIPTION", "PARAMS", "make_localizer", "settings_from_params", "main"]

NODE_NAME = "ir_initializer"
DESCRIPTION = (
    "Global localization by information retrieval (Aycard & Brouard): expected scans precomputed over the map, "
    "patterns and a two-level hit -> pattern -> position index, idf-ranked poses, then a small particle filter "
    "with an end-point sensor model that reinitialises itself when lost."
)

_D = IRSettings()

PARAMS = (
    # scanner model
    ParamSpec("beam_count", _D.beam_count, "scanner beams; 0: from the first scan", 0, 100_000),
    ParamSpec("field_of_view", _D.field_of_view, "scanner field of view [rad]; 0: from the first scan", 0.0, 2 * math.pi),
    ParamSpec("max_range", _D.max_range,
              "longest range precomputed [m], capped at 254 * range_resolution; 0: the first scan's range_max", 0.0, 1e4),
    ParamSpec("angular_resolution", _D.angular_resolution,
              "precomputed rays at least this far apart [rad] (1 deg; paper 1/3 deg)", 1e-4, math.pi / 4),
    # precomputation
    ParamSpec("grid_resolution", _D.grid_resolution, "spacing of the candidate positions [m] (paper 0.05)", 0.005, 10.0),
    ParamSpec("range_resolution", _D.range_resolution, "quantisation of stored ranges [m]", 0.001, 1.0),
    ParamSpec("min_clearance", _D.min_clearance, "positions at least this far from obstacles/unknown cells [m]", 0.0, 10.0),
    ParamSpec("unknown_blocks", _D.unknown_blocks, "unknown cells stop the precomputed rays"),
    ParamSpec("pattern_max_range", _D.pattern_max_range, "beyond this a reading ends a pattern [m] (paper 5.5)", 0.01, 1e4),
    ParamSpec("pattern_range_bin", _D.pattern_range_bin, "range bin of a first-level hit [m]", 0.001, 10.0),
    ParamSpec("pattern_terms_per_end", _D.pattern_terms_per_end, "beams indexed from each end of a pattern", 1, 100_000),
    ParamSpec("min_pattern_beams", _D.min_pattern_beams, "shortest pattern [beams]", 1, 100_000),
    ParamSpec("split_at_jump", _D.split_at_jump, "range jump that also ends a pattern [m]; 0: no-returns only (paper)", 0.0, 1e3),
    # query
    ParamSpec("heading_step", _D.heading_step, "heading step of step 2 [rad] (paper 5 deg)", 1e-3, math.pi),
    ParamSpec("patterns_per_live_pattern", _D.patterns_per_live_pattern, "step 1: closest patterns kept per live pattern (paper N)", 1, 10_000_000),
    ParamSpec("step1_positions", _D.step1_positions, "step 1: positions passed to step 2 (paper N)", 1, 10_000_000),
    ParamSpec("soft_bin_weight", _D.soft_bin_weight, "step 1: weight of a hit in a neighbouring range bin", 0.0, 1.0),
    ParamSpec("weight_patterns_by_length", _D.weight_patterns_by_length, "step 1: a live pattern votes by its length"),
    ParamSpec("step2_range_bin", _D.step2_range_bin, "step 2: range bin of a beam hit [m]", 0.001, 10.0),
    ParamSpec("step2_tolerance_bins", _D.step2_tolerance_bins, "step 2: a pose holds a hit within this many bins", 0, 1000),
    ParamSpec("use_idf", _D.use_idf, "step 2: idf weights (paper); false: plain counting"),
    ParamSpec("idf_log", _D.idf_log, "step 2: log(N / df) instead of the paper's N / df"),
    ParamSpec("no_return_terms", _D.no_return_terms, "step 2: no-return readings are hits of their own bin"),
    ParamSpec("refine_candidates", _D.refine_candidates, "best step-2 poses aligned to the map and re-ranked; 0: paper's list", 0, 1_000_000),
    ParamSpec("refine_iterations", _D.refine_iterations, "Gauss-Newton iterations of the refinement", 0, 1000),
    ParamSpec("refine_sigma", _D.refine_sigma, "end-point likelihood width of the refinement [m]", 1e-3, 10.0),
    ParamSpec("refine_max_shift", _D.refine_max_shift, "refinement moves a pose at most this far [m]", 0.0, 10.0),
    ParamSpec("refine_max_turn", _D.refine_max_turn, "refinement turns a pose at most this much [rad]", 0.0, math.pi),
    ParamSpec("nms_distance", _D.nms_distance, "candidates this close to a better one are dropped [m]; 0: keep all", 0.0, 100.0),
    ParamSpec("nms_angle", _D.nms_angle, "... and within this heading [rad]", 0.0, math.pi),
    ParamSpec("max_candidates", _D.max_candidates, "candidates returned by an initialisation", 1, 10_000_000),
    ParamSpec("fallback_positions", _D.fallback_positions,
              "a scan with hits but no delimited pattern is matched against about this many positions; 0: no candidates (paper)",
              0, 10_000_000),
    # tracking
    ParamSpec("particle_count", _D.particle_count, "particles tracked after an initialisation (paper 100)", 1, 10_000_000),
    ParamSpec("update_min_d", _D.update_min_d, "translation before a filter update [m] (paper 1 m)", 0.0, 1e3),
    ParamSpec("update_min_a", _D.update_min_a, "rotation before a filter update [rad] (paper 20 deg)", 0.0, 7.0),
    ParamSpec("alpha1", _D.alpha1, "rotation noise from rotation (nav2 name; 0.02)", 0.0, 100.0),
    ParamSpec("alpha2", _D.alpha2, "rotation noise from translation", 0.0, 100.0),
    ParamSpec("alpha3", _D.alpha3, "translation noise from translation", 0.0, 100.0),
    ParamSpec("alpha4", _D.alpha4, "translation noise from rotation", 0.0, 100.0),
    ParamSpec("max_beams", _D.max_beams, "end-points scored per update (nav2 name)", 1, 100_000),
    ParamSpec("endpoint_tolerance", _D.endpoint_tolerance, "an end-point within this of an occupied cell scores [m]; 0: the cell", 0.0, 10.0),
    ParamSpec("score_exponent", _D.score_exponent, "particle weight = end-point score ** this (paper 1; 4 sharpens 100 particles)", 0.0, 1000.0),
    ParamSpec("lost_score_threshold", _D.lost_score_threshold, "best end-point score below this counts towards LOST", 0.0, 1.0),
    ParamSpec("lost_score_ratio", _D.lost_score_ratio,
              "... or below this fraction of its running average over good updates", 0.0, 1.0),
    ParamSpec("lost_update_count", _D.lost_update_count, "updates in a row below the threshold before reinitialising", 1, 1_000_000),
    ParamSpec("global_check_updates", _D.global_check_updates,
              "every this many updates, restart from a global fix that fits clearly better; 0: never (paper)", 0, 1_000_000),
    ParamSpec("global_check_margin", _D.global_check_margin,
              "... better by this much of the mean end-point likelihood", 0.0, 1.0),
    ParamSpec("localized_spread", _D.localized_spread, "LOCALIZED when the particles' xy spread is at most this [m]", 1e-6, 1e3),
    ParamSpec("seed", _D.seed, "seed of the filter's random numbers", 0, 2**31 - 1),
    # cache
    ParamSpec("cache_dir", _D.cache_dir, "index cache directory; empty: $RLS_CACHE_DIR or ~/.cache/robot_localization_suite"),
    ParamSpec("use_cache", _D.use_cache, "load/save the precomputed index on disk"),
    ParamSpec("progress", _D.progress, "show a progress bar while precomputing"),
    ParamSpec("cache_budget_mb", _D.cache_budget_mb,
              "after writing an index, delete the least recently used ones beyond this [MB]; 0: $RLS_CACHE_BUDGET_MB or 2048",
              0.0, 1e9),
)


def settings_from_params(params: dict[str, Any]) -> IRSettings:
    """The core settings from parameter values (missing ones take the defaults, unknown ones are ignored)."""
    return IRSettings.from_dict(params)


def make_localizer(params: dict[str, Any]) -> IRLocalizer:
    """Build the core localizer from parameter values."""
    return IRLocalizer(settings_from_params(params))


def main() -> int:
    return localizer_node_main(sys.modules[__name__])


if __name__ == "__main__":
    sys.exit(main())
