"""Every parameter of ``pil_localizer`` (Lambert et al. 2020), with the paper's value where it gives one.

Angles a user types are degrees in ROS (``field_of_view_deg``, ``ambiguity_angle_deg``) and
radians inside. Why each default departs from the paper: docs/pil.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import SettingsError
from ..settings import Settings, setting

__all__ = ["PilSettings", "BEAM_MAPPINGS", "LEVEL_FUNCTION_NAMES", "MATCH_SCORES"]

BEAM_MAPPINGS = ("nearest", "sector_min")
MATCH_SCORES = ("truncated_difference", "correlation")
LEVEL_FUNCTION_NAMES = ("energy", "pq", "harmonic1", "harmonic2", "low_quantile", "high_quantile")
_BIG = 1e6


def _alpha(name: str) -> float:
    return setting(1.0, f"alpha_n of {name} in equation (4) (paper 1)", low=0.0, low_open=True, high=_BIG)


def _sigma(name: str, default: float) -> float:
    return setting(default, f"sigma_n of {name} in equation (4) (paper 0.05)", unit="intensity",
                   low=0.0, low_open=True, high=10.0)


@dataclass(frozen=True)
class PilSettings(Settings):
    """Settings of :class:`~.localizer.PilLocalizer`: learning (section 2.2), level functions (2.3),
    candidates (2.4, 2.7), heading and score (2.5), status and cache."""

    tile_size: float = setting(0.2, "r: side of a learned tile (paper 0.2)", unit="m", low=0.01, high=5.0,
                               read_only=True)
    sensor_count: int = setting(57, "N_s: sensors evenly spaced over the field of view (paper 57)", low=4, high=4096,
                                read_only=True)
    max_range: float = setting(10.0, "R: sensor range of the pseudo-images, capped by the scan's range_max "
                               "(paper figure 1: 6)", unit="m", low=0.1, high=65.0, read_only=True)
    field_of_view: float = setting(
        2.0 * math.pi, "field of view learned first; a scan with another one triggers a relearning (paper 360 deg)",
        unit="rad", ros_unit="deg", low=0.0, low_open=True, high=2.0 * math.pi, ros_name="field_of_view_deg",
        read_only=True,
    )
    angular_upsampling: int = setting(4, "learned directions per sensor step of N_s sensors over 360 deg: the learned "
                                      "angular step is 2 pi / (N_s x this) for any field of view (ours)", low=1,
                                      high=64, read_only=True)
    reference_headings: int = setting(8, "K: heading sheets for a limited field of view (ours)", low=1, high=360,
                                      read_only=True)
    mark_unknown_rays: bool = setting(
        True, "a learned ray that leaves the map, or crosses unknown space and hits nothing, is unknown: no evidence "
        "either way (ours); false: it reads what it finds, as in the paper's fully known environment", read_only=True)
    unknown_blocks: bool = setting(False, "without mark_unknown_rays: unknown map cells stop the learning rays as "
                                   "walls do", read_only=True)
    beam_mapping: str = setting("nearest", "live beams -> sensors", choices=BEAM_MAPPINGS)

    energy_enabled: bool = setting(True, "use the level function Energy (mean intensity, paper I_1)")
    energy_alpha: float = _alpha("energy")
    energy_sigma: float = _sigma("energy", 0.03)
    pq_enabled: bool = setting(True, "use the level function pq% (fraction of intensities in [pq_low, pq_high], "
                               "paper I_2)")
    pq_low: float = setting(0.25, "p of pq% (paper 0.25)", unit="intensity", low=0.0, high=1.0)
    pq_high: float = setting(0.75, "q of pq% (paper 0.75)", unit="intensity", low=0.0, high=1.0)
    pq_alpha: float = _alpha("pq")
    pq_sigma: float = _sigma("pq", 0.08)
    harmonic1_enabled: bool = setting(True, "use the level function first DFT harmonic magnitude of the profile (ours)")
    harmonic1_alpha: float = _alpha("harmonic1")
    harmonic1_sigma: float = _sigma("harmonic1", 0.025)
    harmonic2_enabled: bool = setting(True, "use the level function second DFT harmonic magnitude of the profile "
                                      "(ours)")
    harmonic2_alpha: float = _alpha("harmonic2")
    harmonic2_sigma: float = _sigma("harmonic2", 0.02)
    low_quantile_enabled: bool = setting(True, "use the level function low quantile of the sorted profile (ours)")
    low_quantile_level: float = setting(0.1, "level of low_quantile", low=0.0, high=1.0)
    low_quantile_alpha: float = _alpha("low_quantile")
    low_quantile_sigma: float = _sigma("low_quantile", 0.06)
    high_quantile_enabled: bool = setting(True, "use the level function high quantile of the sorted profile (ours)")
    high_quantile_level: float = setting(0.9, "level of high_quantile", low=0.0, high=1.0)
    high_quantile_alpha: float = _alpha("high_quantile")
    high_quantile_sigma: float = _sigma("high_quantile", 0.02)

    min_candidates: int = setting(5000, "best-ranked tiles added when fewer pass equation (4); 0: passing tiles "
                                  "only, still at most max_candidates (ours)", low=0, high=10_000_000)
    max_candidates: int = setting(5000, "most candidate tiles correlated per scan (ours)", low=1, high=10_000_000)
    fine_candidates: int = setting(300, "best (tile, heading) pairs of the coarse correlation taken to the learned "
                                   "angular step (ours)", low=1, high=1_000_000)
    coarse_sensors: int = setting(19, "sensors the coarse correlation compares, evenly spread (ours)", low=1,
                                  high=4096)
    coarse_block: int = setting(2, "the coarse correlation scores the best-ranked tile of each block of n x n tiles, "
                                "the fine one it and its neighbours; 1: every tile (ours)", low=1, high=2)
    rank_term_cap: float = setting(9.0, "cap of each level function's squared term in the candidate ranking (ours)",
                                   low=0.0, low_open=True, high=_BIG)
    window_size: float = setting(4.0, "side of the square search window around the last estimate; <= 0: whole map "
                                 "(paper 4)", unit="m", low=-1.0, high=10_000.0)
    global_candidates: int = setting(50, "best-ranked tiles outside the window scored with every windowed update; "
                                     "0: hard window, as the paper", low=0, high=1_000_000)
    global_switch_margin: float = setting(0.05, "a tile outside the window wins once its accumulated score "
                                          "advantage exceeds this (ours)", low=0.0, high=1.0)

    match_score: str = setting("truncated_difference", "score that ranks the candidates: the normalised truncated "
                               "squared difference of the profiles (ours), or the correlation of the distance "
                               "profiles, highest first (paper 2.5; reported as 1 - sum D_r D_s / (N R^2))",
                               choices=MATCH_SCORES)
    score_truncation: float = setting(0.1, "tau of the truncated squared profile difference (ours)", unit="intensity",
                                      low=0.0, low_open=True, high=1.0)
    unknown_cost: float = setting(0.5, "cost of a sensor whose learned ray is unknown, between a match (0) and a "
                                  "contradiction (1) (ours)", low=0.0, high=1.0)
    short_cost: float = setting(1.0, "most a reading shorter than the learned range costs (something unmapped in "
                                "front); 1: as any mismatch (ours)", low=0.0, high=1.0)
    shift_hypotheses: int = setting(3, "correlation optima kept per candidate tile (ours)", low=1, high=64)
    refine_candidates: int = setting(20, "best candidates refined below the tile size; 0: off (ours)",
                                     low=0, high=10_000)
    refine_iterations: int = setting(10, "Gauss-Newton iterations of the refinement", low=1, high=100)
    refine_beams: int = setting(180, "live hits used by the refinement at most", low=1, high=100_000)
    refine_truncation: float = setting(0.3, "refinement ignores endpoints farther than this from obstacles",
                                       unit="m", low=0.0, low_open=True, high=10.0)

    lost_score: float = setting(0.5, "best normalised score above which the estimate is LOST", low=0.0, high=1.0)
    kidnap_score: float = setting(0.2, "best score in the window above which the whole map is searched",
                                  low=0.0, high=1.0)
    localized_min_explained: float = setting(
        0.9, "LOCALIZED needs this share of the scan's end points within two cells of a mapped obstacle at the best "
        "pose, AMBIGUOUS below it: a place the map cannot vouch for is a guess (docs/pil.md, \"Status\"); 0: off",
        low=0.0, high=1.0)
    ambiguity_margin: float = setting(0.03, "a separate candidate this close to the best score makes the estimate "
                                      "AMBIGUOUS", low=0.0, high=1.0)
    ambiguity_distance: float = setting(1.0, "candidates farther apart than this are separate", unit="m",
                                        low=0.0, low_open=True, high=1000.0)
    ambiguity_angle: float = setting(0.5, "candidates turned more than this are separate", unit="rad", ros_unit="deg",
                                     low=0.0, high=math.pi, ros_name="ambiguity_angle_deg")
    min_valid_fraction: float = setting(0.3, "fraction of sensors that must receive a valid beam", low=0.0, high=1.0)

    cache_dir: str = setting("", "learning cache directory; empty: $RLS_CACHE_DIR or ~/.cache/robot_localization_suite",
                             read_only=True)
    use_cache: bool = setting(True, "read and write the learning cache", read_only=True)
    cache_mmap_mb: float = setting(256.0, "learned rays above this size are memory-mapped from the cache file "
                                   "instead of held in memory", unit="MB", low=0.0, high=1e6, read_only=True)
    show_progress: bool = setting(True, "progress bar while learning")

    def validate(self) -> None:
        if not self.pq_low < self.pq_high:
            raise SettingsError(f"PilSettings needs pq_low < pq_high, got {self.pq_low!r}, {self.pq_high!r}")
        if self.harmonic2_enabled and self.sensor_count < 5:
            raise SettingsError(f"PilSettings.harmonic2 needs at least 5 sensors, got {self.sensor_count!r}")
