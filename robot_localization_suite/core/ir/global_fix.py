"""The IR global fix of Aycard & Brouard (seed 001, section IV-B): ranked poses from one scan, no prior.

The scan the robot should perceive is precomputed at every position of a grid over the map
(IV-A-2, :mod:`.index`); a live scan's patterns find the positions whose patterns share the most
hits (step 1, IV-B-3) and the poses of those positions are ranked by the idf-weighted hits they
share (step 2, IV-B-4, :mod:`.query`). Beyond the paper, each a switch: refinement and duplicate
suppression of the ranked poses, and a coarse fallback for scans with no delimited pattern.
Notes: docs/ir.md.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ScanError
from ..filter.particles import weighted_pose_statistics
from ..filter.refinement import DistanceField, refine_poses
from ..grid_map import GridMap
from ..localizer import Estimate, LocalizerStatus
from ..raycast import RayCaster
from ..scan import Scan
from .evidence import MapEvidence
from .index import FanModel, IRIndex
from .query import live_pattern_terms, resample_scan, step1_positions, step2_poses, suppress_duplicates
from .settings import IRSettings

__all__ = ["IRGlobalFixer", "COVARIANCE_FLOOR"]

_LOG = logging.getLogger(__name__)
# Added to reported covariances so that a collapsed cloud still gives a positive-definite one.
COVARIANCE_FLOOR = np.diag([1e-6, 1e-6, 1e-8])


class IRGlobalFixer:
    """The index over a map and the global fix from it (a :class:`~..localizer.GlobalFixer`).

    Args:
        settings: the method's settings (precomputation, query and refinement).
    """

    def __init__(self, settings: IRSettings) -> None:
        self.settings = settings
        self.grid_map: GridMap | None = None
        self.index: IRIndex | None = None
        self._field: DistanceField | None = None
        self._evidence: MapEvidence | None = None
        self._caster: RayCaster | None = None
        self._coarse: tuple[IRIndex, NDArray[np.int64], float] | None = None

    def set_map(self, grid_map: GridMap) -> None:
        """Use this map; builds (or loads) the index now when the scanner model is given by the settings."""
        self.grid_map = grid_map
        self.index = None
        self._field = self._evidence = self._caster = None
        s = self.settings
        if s.scanner_configured:
            self._build_index(s.configured_fan_model())

    # The map's distance field and evidence are made on first use, after the index: a large map's
    # precomputation then does not hold them too (4 and 9 bytes a cell).
    @property
    def field(self) -> DistanceField | None:
        """The map's distance field for the refinement (compact: the float32 distances only), made on first use."""
        if self._field is None and self.grid_map is not None:
            self._field = DistanceField(self.grid_map, compact=True)
        return self._field

    @field.setter
    def field(self, value: DistanceField | None) -> None:
        self._field = value

    @property
    def evidence(self) -> MapEvidence | None:
        """The map as the scores read it (:mod:`.evidence`), made on first use."""
        if self._evidence is None and self.grid_map is not None:
            s = self.settings
            self._evidence = MapEvidence.from_map(self.grid_map, sigma=s.refine_sigma, tolerance=s.endpoint_tolerance)
        return self._evidence

    @evidence.setter
    def evidence(self, value: MapEvidence | None) -> None:
        self._evidence = value

    @property
    def caster(self) -> RayCaster | None:
        """Ray casting on the map to the index's range, for beams seen through walls; made on first use."""
        if self._caster is None and self.grid_map is not None and self.index is not None:
            self._caster = RayCaster(self.grid_map, max_range=self.index.fan.max_range)
        return self._caster

    def variant(self, settings: IRSettings) -> IRGlobalFixer:
        """A fixer with other query settings sharing this one's map, distance field and index.

        Raises:
            ValueError: ``settings`` would build another index (a precomputation setting differs).
        """
        if settings.index_settings() != self.settings.index_settings():
            raise ValueError("an IR variant must share the index settings of the fixer it comes from")
        other = IRGlobalFixer(settings)
        other.grid_map, other.field, other.index = self.grid_map, self.field, self.index
        other._caster = self.caster
        if (settings.refine_sigma, settings.endpoint_tolerance) == (
            self.settings.refine_sigma, self.settings.endpoint_tolerance
        ):
            other.evidence = self.evidence
        return other

    def prepare(self, scan: Scan) -> IRIndex:
        """The index for this scan's geometry, built (or loaded from the cache) on first use.

        Raises:
            ScanError: a scan of fewer than two beams, or a geometry the precomputation cannot use.
        """
        if scan.beam_count < 2:
            raise ScanError(f"IR needs scans of at least 2 beams to learn the scanner, got {scan.beam_count}")
        if self.grid_map is None:
            raise ScanError("IR needs a map before it can prepare its index")
        fan = self.settings.fan_model(float(scan.angles[1] - scan.angles[0]), scan.range_max)
        if self.index is None or not self.index.fan.serves(fan):
            if self.index is not None:
                _LOG.warning(
                    "IR index was built for a %d-ray fan to %.2f m, the scans need %d rays to %.2f m: building "
                    "it again (set beam_count, field_of_view and max_range to the scanner's)",
                    self.index.fan.rays, self.index.fan.max_range, fan.rays, fan.max_range,
                )
            self._build_index(fan)
        assert self.index is not None
        return self.index

    def prepared_for(self, scan: Scan) -> bool:
        """Whether the index serves this scan's scanner (its fan: the angular step and range, not the beam count)."""
        if self.grid_map is None or self.index is None:
            return False
        if scan.beam_count < 2:
            return True  # prepare would refuse it, as on_scan does
        try:
            return self.index.fan.serves(
                self.settings.fan_model(float(scan.angles[1] - scan.angles[0]), scan.range_max))
        except ScanError:
            return True

    def refined_scores(self, scan: Scan, poses: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Scores of ``poses`` after refinement, as the ranking scores its poses (``rank_score``)."""
        if self.field is None or self.index is None:
            return None
        live = resample_scan(scan, self.index.fan)
        hits = live.hit_mask
        _, scores = self._refine(poses, live.angles[hits], live.ranges[hits])
        return scores

    def _refine(
        self, poses: NDArray[np.float64], angles: NDArray[np.float64], ranges: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Gauss-Newton alignment of ``poses`` to the map, and their ranking scores (docs/ir.md)."""
        assert self.field is not None
        s = self.settings
        refined, likelihood = refine_poses(
            self.field, poses, angles, ranges, iterations=s.refine_iterations, sigma=s.refine_sigma,
            max_shift=s.refine_max_shift, max_turn=s.refine_max_turn,
        )
        if s.rank_score == "likelihood_ratio" and self.evidence is not None:
            through = None
            if s.see_through_margin > 0.0 and self.caster is not None and len(refined):
                # Beams that reached past a mapped wall, which no end-point score sees (docs/ir.md, "Seen through").
                through = ranges[None, :] > self.caster.cast(refined, angles) + s.see_through_margin
            likelihood = self.evidence.likelihood_ratios(
                refined, angles, ranges, outlier_share=s.outlier_share, neutral_unknown=s.neutral_unknown,
                through=through,
            )
        return refined, likelihood

    def global_fix(self, scan: Scan) -> Estimate:
        """Ranked candidate poses of the laser from this scan alone (best first).

        Returns an estimate with no candidates and ``details["reason"]`` when the
        scan holds no usable pattern.

        Raises:
            ScanError: no map yet, or a scanner geometry the precomputation cannot use.
        """
        if self.grid_map is None:
            raise ScanError("IR global fix needs a map first")
        s = self.settings
        index = self.prepare(scan)
        timings: dict[str, float] = {}
        start = time.perf_counter()
        live = resample_scan(scan, index.fan)
        details: dict[str, Any] = {"phase": "initialization", "positions": 0, "live_patterns": 0}
        if not live.valid.any():
            return self._no_candidates(scan.stamp, "no valid reading in the scan", details)
        terms, anchors = live_pattern_terms(live, index)
        details["live_patterns"] = len(terms)
        if not live.hit_mask.any():
            return self._no_candidates(scan.stamp, "no pattern: every reading is a no-return", details)
        fallback = None
        if terms:
            position_ids, _ = step1_positions(
                index,
                terms,
                patterns_per_live_pattern=s.patterns_per_live_pattern,
                positions=s.step1_positions,
                soft_weight=s.soft_bin_weight,
                weight_by_length=s.weight_patterns_by_length,
            )
            if len(position_ids) == 0:
                fallback = "no stored pattern shares a hit with the scan's patterns"
        elif len(anchors):
            fallback = "no pattern: the scan is one run of hits with no delimiting no-return or range jump"
        else:
            fallback = (
                f"no pattern: no run of at least {s.min_pattern_beams} hits within {index.pattern_range:g} m"
            )
        if fallback is not None:
            if s.fallback_positions <= 0:
                return self._no_candidates(scan.stamp, fallback, details)
            # Step 1 cannot place the scan: step 2 over a coarse lattice of all positions instead.
            details["fallback"] = fallback
            position_ids = self._coarse_lattice(index)[0]
        timings["step1_ms"] = (time.perf_counter() - start) * 1e3
        details["positions"] = len(position_ids)
        details["step1_xy"] = index.positions[position_ids]
        poses, scores = self._ranked_poses(index, live, position_ids, timings)
        if len(poses) and fallback is None and self._explains_too_little(index, live, poses[0]):
            # Step 1 found no place that explains the scan: look over the coarse lattice too (docs/ir.md).
            lattice = np.setdiff1d(self._coarse_lattice(index)[0], position_ids)
            details["wide_search_positions"] = len(lattice)
            wide_poses, wide_scores = self._ranked_poses(index, live, lattice, timings)
            poses, scores = self._merge(np.vstack([poses, wide_poses]), np.concatenate([scores, wide_scores]))
        if len(poses) == 0:
            return self._no_candidates(scan.stamp, "step 2 found no pose sharing a hit with the scan", details)
        details["best_score"] = float(scores[0])
        timings["total_ms"] = (time.perf_counter() - start) * 1e3
        details.update(timings)
        weights = np.maximum(scores, 0.0)
        weights = weights / weights.sum() if weights.sum() > 0 else np.full(len(scores), 1.0 / len(scores))
        return Estimate(
            stamp=scan.stamp,
            pose=poses[0].copy(),
            covariance=_covariance(poses, weights),
            status=LocalizerStatus.AMBIGUOUS if len(poses) > 1 else LocalizerStatus.LOCALIZED,
            candidates=poses,
            candidate_weights=weights,
            details=details,
        )

    def _ranked_poses(
        self, index: IRIndex, live: Any, position_ids: NDArray[np.int64], timings: dict[str, float]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Step 2 over ``position_ids``, then the refinement and duplicate suppression; adds to ``timings``."""
        s = self.settings
        start = time.perf_counter()
        poses, scores = step2_poses(
            index,
            live,
            position_ids,
            heading_count=s.heading_count,
            range_bin=s.step2_range_bin,
            tolerance_bins=s.step2_tolerance_bins,
            use_idf=s.use_idf,
            no_return_terms=s.no_return_terms,
            idf_log=s.idf_log,
            evidence=self.evidence if s.neutral_unknown else None,
            exact=s.refine_candidates + s.max_candidates,
        )
        mid = time.perf_counter()
        timings["step2_ms"] = timings.get("step2_ms", 0.0) + (mid - start) * 1e3
        if len(poses):
            poses, scores = self._rerank(live, poses, scores)
        timings["refine_ms"] = timings.get("refine_ms", 0.0) + (time.perf_counter() - mid) * 1e3
        return poses, scores

    def _explains_too_little(self, index: IRIndex, live: Any, pose: NDArray[np.float64]) -> bool:
        """Whether fewer than ``wide_search_below`` of the scan's end points at ``pose`` lie near a mapped obstacle
        and the coarse lattice is fine enough for the refinement to reach any place from it (docs/ir.md)."""
        s = self.settings
        if s.wide_search_below <= 0.0 or s.fallback_positions <= 0 or self.evidence is None:
            return False
        if self._coarse_lattice(index)[1] > 2.0 * s.refine_max_shift:
            return False  # a lattice coarser than the refinement closes would cost without finding the place
        hits = live.hit_mask
        share = self.evidence.hit_fractions(pose[None, :], live.angles[hits], live.ranges[hits],
                                            neutral_unknown=s.neutral_unknown)[0]
        return bool(share < s.wide_search_below)

    def _merge(
        self, poses: NDArray[np.float64], scores: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Two ranked lists as one: best score first, duplicates of a better pose dropped, ``max_candidates`` kept."""
        s = self.settings
        order = np.argsort(-scores, kind="stable")
        poses, scores = poses[order], scores[order]
        keep = suppress_duplicates(poses, distance=s.nms_distance, angle=s.nms_angle, limit=s.max_candidates)
        return poses[keep], scores[keep]

    def _coarse_lattice(self, index: IRIndex) -> tuple[NDArray[np.int64], float]:
        """About ``fallback_positions`` positions evenly spread over the map (every n-th lattice row and column),
        and their spacing [m]."""
        if self._coarse is None or self._coarse[0] is not index:
            lattice = np.rint((index.positions - index.positions.min(axis=0)) / index.grid_step).astype(np.int64)
            stride = max(1, int(math.ceil(math.sqrt(len(index.positions) / self.settings.fallback_positions))))
            chosen = np.flatnonzero((lattice[:, 0] % stride == 0) & (lattice[:, 1] % stride == 0))
            spacing, reach = stride * index.grid_step, 2.0 * self.settings.refine_max_shift
            self._coarse = (index, chosen, spacing)
            if self.settings.wide_search_below > 0.0 and spacing > reach:
                _LOG.info(
                    "IR wide search off on this map: %d coarse positions lie %.2f m apart, farther than the "
                    "refinement closes (2 x refine_max_shift = %.2f m); fallback_positions %d would allow it",
                    len(chosen), spacing, reach, int(math.ceil(len(index.positions) * (index.grid_step / reach) ** 2)),
                )
        return self._coarse[1], self._coarse[2]

    def _build_index(self, fan: FanModel) -> None:
        assert self.grid_map is not None
        s = self.settings
        self._caster = None  # cast to the new fan's range
        self.index = IRIndex.load_or_build(
            self.grid_map,
            fan,
            s.index_settings(),
            cache_dir=Path(s.cache_dir).expanduser() if s.cache_dir else None,
            use_cache=s.use_cache,
            progress=s.progress,
            cache_budget_mb=s.cache_budget_mb,
            memory_budget_mb=s.index_memory_mb,
        )
        _LOG.info("IR index ready: %s", self.index.describe())

    def _rerank(
        self, live: Any, poses: NDArray[np.float64], scores: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Refinement and duplicate suppression of the step-2 ranking (beyond the paper; docs/ir.md)."""
        s = self.settings
        count = min(s.refine_candidates, len(poses))
        if count > 0 and self.field is not None and live.hit_mask.any():
            hits = live.hit_mask
            refined, likelihood = self._refine(poses[:count], live.angles[hits], live.ranges[hits])
            order = np.argsort(-likelihood, kind="stable")
            head, head_scores = refined[order], likelihood[order]
            keep = suppress_duplicates(head, distance=s.nms_distance, angle=s.nms_angle, limit=s.max_candidates)
            head, head_scores = head[keep], head_scores[keep]
            if len(head) < s.max_candidates and count < len(poses):
                # The unrefined rest follows, ranked by step 2, scores below every refined one.
                tail = poses[count:]
                tail_keep = suppress_duplicates(
                    tail, distance=s.nms_distance, angle=s.nms_angle, limit=s.max_candidates - len(head)
                )
                tail_scores = scores[count:][tail_keep] / max(float(scores.max()), 1e-12)
                if s.rank_score == "mean_weight":
                    tail_scores = tail_scores * float(head_scores.min(initial=1.0)) * 0.5
                else:  # log ratios may be negative: below the worst refined one, in step 2's order
                    tail_scores = float(head_scores.min(initial=0.0)) - 1.0 + 0.5 * tail_scores
                head = np.vstack([head, tail[tail_keep]])
                head_scores = np.concatenate([head_scores, tail_scores])
            return head, head_scores
        keep = suppress_duplicates(poses, distance=s.nms_distance, angle=s.nms_angle, limit=s.max_candidates)
        return poses[keep], scores[keep]

    def _no_candidates(self, stamp: float, reason: str, details: dict[str, Any]) -> Estimate:
        details = {**details, "reason": reason}
        return Estimate(
            stamp=stamp,
            pose=np.full(3, np.nan),
            covariance=np.full((3, 3), np.nan),
            status=LocalizerStatus.LOST,
            candidates=np.zeros((0, 3)),
            candidate_weights=np.zeros(0),
            details=details,
        )


def _covariance(poses: NDArray[np.float64], weights: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weighted covariance of (x, y, theta) (heading wrapped around the mean), with a small floor."""
    return weighted_pose_statistics(poses, weights)[1] + COVARIANCE_FLOOR
