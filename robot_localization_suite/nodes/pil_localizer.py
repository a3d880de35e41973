"""``pil_localizer``: Pseudo Image Localization (Lambert et al. 2020) as a ROS 2 node.

Parameters are copied one to one into :class:`~robot_localization_suite.core.pil.PilSettings`
(angles in degrees where a user types them: ``field_of_view_deg``, ``ambiguity_angle_deg``).
The node itself is the shared :class:`~robot_localization_suite.nodes.localizer_node.LocalizerNode`.
"""

from __future__ import annotations

import math
import sys
from dataclasses import fields
from typing import Any

from ..core.pil.localizer import PilLocalizer, PilSettings
from .common import ParamSpec
from .localizer_node import localizer_node_main

__all__ = ["NODE_NAME", "DESCRIPTION", "PARAMS", "make_localizer", "main"]

NODE_NAME = "pil_localizer"
DESCRIPTION = (
    "Pseudo Image Localization: learns range pseudo-images of every tile of the map off-line, then "
    "finds (x, y) from orientation-free level functions and theta by profile correlation, from each scan "
    "alone (global localization and kidnapping recovery, no odometry needed)."
)

_DEFAULTS = PilSettings()
_LEVEL_TEXT = {
    "energy": "Energy (mean intensity, paper I_1)",
    "pq": "pq% (fraction of intensities in [pq_low, pq_high], paper I_2)",
    "harmonic1": "first DFT harmonic magnitude of the profile",
    "harmonic2": "second DFT harmonic magnitude of the profile",
    "low_quantile": "low quantile of the sorted profile",
    "high_quantile": "high quantile of the sorted profile",
}


def _level_specs() -> list[ParamSpec]:
    specs = []
    for name, text in _LEVEL_TEXT.items():
        specs += [
            ParamSpec(f"{name}_enabled", getattr(_DEFAULTS, f"{name}_enabled"), f"use the level function {text}"),
            ParamSpec(f"{name}_alpha", getattr(_DEFAULTS, f"{name}_alpha"), f"alpha_n of {name} in equation (4)", 1e-6, 1e6),
            ParamSpec(f"{name}_sigma", getattr(_DEFAULTS, f"{name}_sigma"), f"sigma_n of {name} in equation (4) [intensity]", 1e-6, 10.0),
        ]
    return specs


PARAMS = (
    ParamSpec("tile_size", _DEFAULTS.tile_size, "r: side of a learned tile [m] (paper: 0.2)", 0.01, 5.0),
    ParamSpec("sensor_count", _DEFAULTS.sensor_count, "N_s: sensors evenly spaced over the field of view (paper: 57)", 4, 4096),
    ParamSpec("max_range", _DEFAULTS.max_range, "R: sensor range of the pseudo-images [m] (capped by the scan's range_max)", 0.1, 65.0),
    ParamSpec("field_of_view_deg", 360.0, "field of view learned first [deg]; a scan with another one triggers a relearning", 1.0, 360.0),
    ParamSpec("angular_upsampling", _DEFAULTS.angular_upsampling, "learned directions per sensor step", 1, 64),
    ParamSpec("reference_headings", _DEFAULTS.reference_headings, "K: heading sheets for a limited field of view", 1, 360),
    ParamSpec("unknown_blocks", _DEFAULTS.unknown_blocks, "unknown map cells stop the learning rays"),
    ParamSpec("beam_mapping", _DEFAULTS.beam_mapping, "live beams -> sensors: 'nearest' or 'sector_min'"),
    *_level_specs(),
    ParamSpec("pq_low", _DEFAULTS.pq_low, "p of pq% [intensity]", 0.0, 1.0),
    ParamSpec("pq_high", _DEFAULTS.pq_high, "q of pq% [intensity]", 0.0, 1.0),
    ParamSpec("low_quantile_level", _DEFAULTS.low_quantile_level, "level of low_quantile (0..1)", 0.0, 1.0),
    ParamSpec("high_quantile_level", _DEFAULTS.high_quantile_level, "level of high_quantile (0..1)", 0.0, 1.0),
    ParamSpec("min_candidates", _DEFAULTS.min_candidates, "best-ranked tiles added when fewer pass equation (4); 0: pure filter", 0, 1_000_000),
    ParamSpec("max_candidates", _DEFAULTS.max_candidates, "most candidate tiles correlated per scan", 1, 1_000_000),
    ParamSpec("rank_term_cap", _DEFAULTS.rank_term_cap, "cap of each level function's squared term in the candidate ranking", 1e-3, 1e6),
    ParamSpec("window_size", _DEFAULTS.window_size, "side of the square search window around the last estimate [m]; <= 0: whole map", -1.0, 10_000.0),
    ParamSpec("global_candidates", _DEFAULTS.global_candidates, "best-ranked tiles outside the window scored with every windowed update; 0: hard window", 0, 1_000_000),
    ParamSpec("global_switch_margin", _DEFAULTS.global_switch_margin, "a tile outside the window wins only when its score is better by this much", 0.0, 1.0),
    ParamSpec("score_truncation", _DEFAULTS.score_truncation, "tau of the truncated squared profile difference [intensity]", 1e-4, 1.0),
    ParamSpec("shift_hypotheses", _DEFAULTS.shift_hypotheses, "correlation optima rescored per candidate", 1, 64),
    ParamSpec("refine_candidates", _DEFAULTS.refine_candidates, "best candidates refined below the tile size; 0: off", 0, 10_000),
    ParamSpec("refine_iterations", _DEFAULTS.refine_iterations, "Gauss-Newton iterations of the refinement", 1, 100),
    ParamSpec("refine_beams", _DEFAULTS.refine_beams, "live hits used by the refinement at most", 1, 100_000),
    ParamSpec("refine_truncation", _DEFAULTS.refine_truncation, "refinement ignores endpoints farther than this from obstacles [m]", 0.01, 10.0),
    ParamSpec("lost_score", _DEFAULTS.lost_score, "best normalised score above which the estimate is LOST (0..1)", 0.0, 1.0),
    ParamSpec("kidnap_score", _DEFAULTS.kidnap_score, "best score in the window above which the whole map is searched (0..1)", 0.0, 1.0),
    ParamSpec("ambiguity_margin", _DEFAULTS.ambiguity_margin, "a separate candidate this close to the best score makes the estimate AMBIGUOUS", 0.0, 1.0),
    ParamSpec("ambiguity_distance", _DEFAULTS.ambiguity_distance, "candidates farther apart than this are separate [m]", 0.01, 1000.0),
    ParamSpec("ambiguity_angle_deg", math.degrees(_DEFAULTS.ambiguity_angle), "candidates turned more than this are separate [deg]", 0.0, 180.0),
    ParamSpec("min_valid_fraction", _DEFAULTS.min_valid_fraction, "fraction of sensors that must receive a valid beam", 0.0, 1.0),
    ParamSpec("cache_dir", _DEFAULTS.cache_dir, "learning cache directory; empty: $RLS_CACHE_DIR or ~/.cache/robot_localization_suite"),
    ParamSpec("use_cache", _DEFAULTS.use_cache, "read and write the learning cache"),
    ParamSpec("show_progress", _DEFAULTS.show_progress, "progress bar while learning"),
)


def make_localizer(params: dict[str, Any]) -> PilLocalizer:
    """Build the core PIL localizer from parameter values (missing ones take the defaults)."""
    names = {field.name for field in fields(PilSettings)}
    values = {key: value for key, value in params.items() if key in names}
    if "field_of_view_deg" in params:
        values["field_of_view"] = math.radians(float(params["field_of_view_deg"]))
    if "ambiguity_angle_deg" in params:
        values["ambiguity_angle"] = math.radians(float(params["ambiguity_angle_deg"]))
    for field in fields(PilSettings):
        if field.name in values and isinstance(field.default, float):
            values[field.name] = float(values[field.name])
    return PilLocalizer(PilSettings(**values))


def main() -> int:
    return localizer_node_main(sys.modules[__name__])


if __name__ == "__main__":
    sys.exit(main())
