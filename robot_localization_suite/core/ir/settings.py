"""Every parameter of ``ir_initializer`` (Aycard & Brouard, seed 001), with the paper's value where it gives one.

Angles are radians (REP 103); nav2_amcl's names where it has the same notion (``alpha1..4``,
``update_min_d``, ``update_min_a``, ``max_beams``). Why each default departs from the paper: docs/ir.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

from ..errors import ScanError, SettingsError
from ..settings import Settings, setting

if TYPE_CHECKING:
    from .index import FanModel, IndexSettings

__all__ = ["IRSettings", "MAX_HIT_CODE"]

# Largest range code of a one-byte quantised reading (255 marks a no-return).
MAX_HIT_CODE = 254
_BIG = 1e7


@dataclass(frozen=True)
class IRSettings(Settings):
    """Settings of :class:`~.localizer.IRLocalizer`: scanner model, precomputation (IV-A), query (IV-B),
    tracking (IV-C, IV-D) and the index cache."""

    # scanner model (0: from the first scan); all three given: the index is built with the map
    beam_count: int = setting(0, "scanner beams; with field_of_view and max_range the index is built with the "
                              "map; 0: from the first scan", low=0, high=100_000, read_only=True)
    field_of_view: float = setting(0.0, "scanner angle_max - angle_min (first to last beam); 0: from the first scan",
                                   unit="rad", low=0.0, high=2.0 * math.pi, read_only=True)
    max_range: float = setting(0.0, "longest range precomputed (the scanner's range_max), capped at 254 * "
                               "range_resolution; 0: the first scan's range_max", unit="m", low=0.0, high=1e4,
                               read_only=True)
    angular_resolution: float = setting(math.radians(1.0), "precomputed rays at least this far apart "
                                        "(ours 1 deg; paper 1/3 deg)", unit="rad", low=1e-4, high=math.pi / 4,
                                        read_only=True)
    # precomputation (IV-A)
    grid_resolution: float = setting(0.05, "spacing of the candidate positions (paper 0.05)", unit="m",
                                     low=0.005, high=10.0, read_only=True)
    range_resolution: float = setting(0.10, "quantisation of stored ranges; max_range is capped at 254 times "
                                      "this (0.05 before 2026-12: 12.7 m)", unit="m", low=0.001, high=1.0,
                                      read_only=True)
    max_positions: int = setting(300_000, "the lattice is widened (grid_resolution x k, k >= 1) until at most this "
                                 "many candidate positions remain: bounds the index (about 1 + fan rays bytes each) "
                                 "and its build on large maps; 0: no limit (ours)", low=0, high=1_000_000_000,
                                 read_only=True)
    min_clearance: float = setting(0.15, "positions at least this far from obstacles and unknown cells", unit="m",
                                   low=0.0, high=10.0, read_only=True)
    unknown_blocks: bool = setting(False, "unknown cells stop the precomputed rays", read_only=True)
    pattern_max_range: float = setting(0.0, "beyond this a reading ends a pattern; 0: the sensor's range as "
                                       "precomputed (max_range), as the paper's 5.5 m was its laser's (docs/ir.md)",
                                       unit="m", low=0.0, high=1e4, read_only=True)
    pattern_range_bin: float = setting(0.10, "range bin of a first-level hit", unit="m", low=0.001, high=10.0,
                                       read_only=True)
    pattern_terms_per_end: int = setting(30, "beams indexed from each end of a pattern", low=1, high=100_000,
                                         read_only=True)
    min_pattern_beams: int = setting(3, "shortest pattern, in beams", low=1, high=100_000, read_only=True)
    split_at_jump: float = setting(0.5, "range jump that also ends a pattern; 0: no-returns only (paper)", unit="m",
                                   low=0.0, high=1e3, read_only=True)
    pattern_views: str = setting("circle", "what each indexed position's patterns are cut from: its whole "
                                 "360-degree fan (ours), or two 240-degree views facing 0 and 180 degrees, the "
                                 "paper's scanner (IV-B-1; a pattern at a view's edge is delimited at its other end "
                                 "only)", choices=("circle", "two_240"), read_only=True)
    # query (IV-B)
    heading_step: float = setting(math.radians(5.0), "heading step of step 2 (paper 5 deg)", unit="rad",
                                  low=1e-3, high=math.pi)
    patterns_per_live_pattern: int = setting(200, "step 1: closest patterns kept per live pattern (paper N)",
                                             low=1, high=10_000_000)
    step1_positions: int = setting(300, "step 1: positions passed to step 2 (paper N)", low=1, high=10_000_000)
    soft_bin_weight: float = setting(0.5, "step 1: weight of a hit in a neighbouring range bin", low=0.0, high=1.0)
    weight_patterns_by_length: bool = setting(False, "step 1: a live pattern votes by its length")
    step2_range_bin: float = setting(0.10, "step 2: range bin of a beam hit", unit="m", low=0.001, high=10.0)
    step2_tolerance_bins: int = setting(1, "step 2: a pose holds a hit within this many bins", low=0, high=1000)
    use_idf: bool = setting(True, "step 2: idf weights (paper); false: plain counting")
    idf_log: bool = setting(False, "step 2: log(N / df) instead of the paper's N / df")
    no_return_terms: bool = setting(True, "step 2: no-return readings are hits of their own bin")
    neutral_unknown: bool = setting(True, "end points in unknown cells or off the map score at the map's chance "
                                    "level in step 2, the ranking and the tracker; false: as misses (paper)")
    rank_score: str = setting("likelihood_ratio", "refined candidates ranked by their end points' mean log "
                              "likelihood ratio against chance, or by the mean end-point weight (before 2026-12)",
                              choices=("likelihood_ratio", "mean_weight"))
    outlier_share: float = setting(0.05, "likelihood_ratio: share of beams the map does not explain (bounds what "
                                   "one such beam costs)", low=0.0, low_open=True, high=1.0)
    see_through_margin: float = setting(0.3, "likelihood_ratio: a hit longer than the range ray-cast on the map at "
                                        "the pose by more than this passed through a mapped obstacle and scores as a "
                                        "beam the map does not explain; 0: off (end points only)", unit="m",
                                        low=0.0, high=100.0)
    refine_candidates: int = setting(300, "best step-2 poses aligned to the map and re-ranked; 0: paper's list",
                                     low=0, high=1_000_000)
    refine_iterations: int = setting(8, "Gauss-Newton iterations of the refinement", low=0, high=1000)
    refine_sigma: float = setting(0.15, "end-point likelihood width of the refinement", unit="m",
                                  low=0.0, low_open=True, high=10.0)
    refine_max_shift: float = setting(0.3, "refinement moves a pose at most this far", unit="m", low=0.0, high=10.0)
    refine_max_turn: float = setting(math.radians(10.0), "refinement turns a pose at most this much", unit="rad",
                                     low=0.0, high=math.pi)
    nms_distance: float = setting(0.3, "candidates this close to a better one are dropped; 0: keep all, whatever nms_angle", unit="m",
                                  low=0.0, high=100.0)
    nms_angle: float = setting(math.radians(15.0), "... and within this heading", unit="rad", low=0.0, high=math.pi)
    max_candidates: int = setting(100, "candidates returned by an initialisation", low=1, high=10_000_000)
    fallback_positions: int = setting(3000, "a scan with hits but no delimited pattern is matched against a coarse "
                                      "lattice of about this many positions; 0: no candidates (paper)",
                                      low=0, high=10_000_000)
    wide_search_below: float = setting(0.9, "when the best candidate has fewer than this share of its end points "
                                       "near a mapped obstacle, step 2 also runs over the coarse lattice of "
                                       "fallback_positions (step 1 may have missed the place on a partial map), "
                                       "if that lattice is at most 2 x refine_max_shift apart; 0: never (paper)",
                                       low=0.0, high=1.0)
    # tracking (IV-C, IV-D)
    particle_count: int = setting(100, "particles tracked after an initialisation (paper 100)", low=1, high=10_000_000)
    initial_particles: str = setting("rank", "particles of an initialisation: drawn from the candidates with "
                                     "probability 1 / rank (ours), or one per candidate, in rank order and again "
                                     "from the first when there are fewer candidates than particles (paper IV-D)",
                                     choices=("rank", "one_per_candidate"))
    update_min_d: float = setting(1.0, "translation before a filter update (paper 1 m)", unit="m", low=0.0, high=1e3)
    update_min_a: float = setting(math.radians(20.0), "rotation before a filter update (paper 20 deg)", unit="rad",
                                  low=0.0, high=7.0)
    motion_model: str = setting("odometry", "the tracker's motion model: nav2's odometry model (ours) or the "
                                "velocity model of the paper (IV-D; Thrun et al. table 5.3, the odometry step read as "
                                "one arc), both with alpha1..4", choices=("odometry", "velocity"))
    alpha1: float = setting(0.02, "rotation noise from rotation (nav2 name and meaning)", low=0.0, high=100.0)
    alpha2: float = setting(0.02, "rotation noise from translation", low=0.0, high=100.0)
    alpha3: float = setting(0.02, "translation noise from translation", low=0.0, high=100.0)
    alpha4: float = setting(0.02, "translation noise from rotation", low=0.0, high=100.0)
    max_beams: int = setting(90, "end-points scored per update (nav2 name)", low=1, high=100_000)
    endpoint_tolerance: float = setting(0.1, "an end-point within this of an occupied cell scores; 0: the cell "
                                        "(paper)", unit="m", low=0.0, high=10.0)
    score_exponent: float = setting(4.0, "particle weight = end-point score ** this (paper 1)", low=0.0, high=1000.0)
    lost_score_threshold: float = setting(0.3, "best end-point score below this counts towards LOST",
                                          low=0.0, high=1.0)
    lost_score_ratio: float = setting(0.6, "... or below this fraction of its running average over good updates",
                                      low=0.0, high=1.0)
    lost_update_count: int = setting(3, "updates in a row below the threshold before reinitialising",
                                     low=1, high=1_000_000)
    global_check_updates: int = setting(2, "every this many updates, restart from a global fix that fits clearly "
                                        "better; 0: never (paper)", low=0, high=1_000_000)
    global_check_margin: float = setting(0.01, "... better by this much of the mean end-point likelihood",
                                         low=0.0, high=1.0)
    global_check_confirmations: int = setting(1, "... and is not clearly worse, moved by the odometry, on the scans "
                                              "of this many following updates; 0: restart on one check", low=0,
                                              high=1000)
    localized_max_std_xy: float = setting(0.25, "LOCALIZED when the cloud's position standard deviation along its "
                                          "widest axis is at most this (mcl_baseline's setting and default)", unit="m",
                                          low=0.0, low_open=True, high=1e3)
    seed: int = setting(0, "seed of the filter's random numbers", low=0, high=2**31 - 1)
    # cache
    cache_dir: str = setting("", "index cache directory; empty: $RLS_CACHE_DIR or ~/.cache/robot_localization_suite",
                             read_only=True)
    use_cache: bool = setting(True, "load and save the precomputed index on disk", read_only=True)
    progress: bool = setting(True, "show a progress bar while precomputing")
    index_memory_mb: float = setting(256.0, "an index whose cache file is larger is memory-mapped from it (only what "
                                     "the queries touch stays resident); 0: always", unit="MB", low=0.0, high=1e9)
    cache_budget_mb: float = setting(0.0, "after writing an index, delete the least recently used ones beyond this; "
                                     "0: $RLS_CACHE_BUDGET_MB or 2048", unit="MB", low=0.0, high=1e9)

    def validate(self) -> None:
        for name in ("pattern_range_bin", "step2_range_bin"):
            if getattr(self, name) < self.range_resolution:
                raise SettingsError(
                    f"IRSettings.{name} must be >= range_resolution {self.range_resolution!r}, "
                    f"got {getattr(self, name)!r}"
                )

    def index_settings(self) -> IndexSettings:
        """The precomputation settings (and so the cache key) taken from the fields of the same names.

        :class:`~.index.IndexSettings` has no defaults of its own: these are the only ones.
        """
        from .index import IndexSettings

        return IndexSettings(**{f.name: getattr(self, f.name) for f in fields(IndexSettings)})

    @property
    def heading_count(self) -> int:
        return max(1, int(round(2.0 * math.pi / self.heading_step)))

    @property
    def scanner_configured(self) -> bool:
        """Whether the settings give the scanner (``beam_count``, ``field_of_view``, ``max_range``)."""
        return self.beam_count > 1 and self.field_of_view > 0.0 and self.max_range > 0.0

    def configured_fan_model(self) -> FanModel:
        """The fan for the scanner the settings describe (:attr:`scanner_configured`): its beams
        ``field_of_view / (beam_count - 1)`` apart, as a LaserScan's ``angle_increment``.

        Raises:
            SettingsError: the settings do not describe the scanner.
        """
        if not self.scanner_configured:
            raise SettingsError(
                "IRSettings: beam_count (> 1), field_of_view and max_range must all be given to build the index "
                f"before the first scan, got {self.beam_count!r}, {self.field_of_view!r}, {self.max_range!r}"
            )
        return self.fan_model(self.field_of_view / (self.beam_count - 1), self.max_range)

    def fan_model(self, increment: float, range_max: float) -> FanModel:
        """The fan for a scanner with this angular ``increment`` [rad] and ``range_max`` [m]."""
        from .index import FanModel

        increment = abs(increment)
        if not (math.isfinite(increment) and increment > 0.0):
            raise ScanError(f"scan angle increment {increment!r} is unusable for the IR precomputation")
        # a scanner 2 % finer than the resolution is a scanner at it (361 beams over 360 deg take every beam,
        # not every other one, as 359 or 360 do): the stride does not jump for a beam more or less
        stride = max(1, int(math.ceil(self.angular_resolution / increment - 0.02)))
        rays = max(8, int(round(2.0 * math.pi / (stride * increment))))
        cap = MAX_HIT_CODE * self.range_resolution
        limit = self.max_range if self.max_range > 0.0 else range_max
        return FanModel(rays=rays, max_range=float(min(limit, range_max, cap)), range_resolution=self.range_resolution)
