"""Map coverage of each output's scan, the rates over well-covered outputs, and pooling runs.

A run's outputs become :class:`OutputScores` (per output: counted, correct, fine, the map
coverage of its scan); :func:`pooled_fields` turns one or several of them (the blocks of a
cross-validation split) into rates over all their outputs together. Definitions:
``docs/benchmark.md``, "Map coverage".
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ...core import metrics
from ...core.errors import LocalizationSuiteError
from ...core.grid_map import GridMap
from ...core.scan import LaserMount
from .global_fixes import GlobalFixRecord
from .reference import BagReference
from .replay import RunRecord

if TYPE_CHECKING:
    from ..scan_coverage import ScanCoverage

__all__ = [
    "CoverageCache",
    "OutputScores",
    "replay_scores",
    "global_fix_scores",
    "pooled_fields",
    "run_coverage_fields",
]

LOG = logging.getLogger("rls_bench")


class CoverageCache:
    """``bag_scan_coverage`` once per (bag, map, laser mount), whatever the number of localizers."""

    def __init__(self) -> None:
        self._done: dict[tuple[str, str, LaserMount], ScanCoverage | None] = {}

    def get(self, reference: BagReference, grid_map: GridMap | None, map_key: str,
            mount: LaserMount) -> ScanCoverage | None:
        """Coverage of every scan of the bag on ``grid_map`` (``map_key`` names it); None without
        scans, ground truth or map."""
        key = (str(reference.path), map_key, mount)
        if key not in self._done:
            self._done[key] = None
            if grid_map is not None and reference.has_scan and reference.ground_truth is not None:
                from ..scan_coverage import bag_scan_coverage  # reads bags: ROS modules load here

                try:
                    self._done[key] = bag_scan_coverage(reference.path, grid_map, mount=mount, remap=reference.remap)
                except LocalizationSuiteError as exc:
                    LOG.warning("bag %s: no map coverage: %s", reference.name, exc)
        return self._done[key]


@dataclass(frozen=True)
class OutputScores:
    """Per output of one run, what its rates count; concatenated over runs, they pool them.

    Attributes:
        kind: ``replay`` or ``global_fixes``.
        counted: outputs the rates count. Replays: from the run's first fix on, with truth
            (``correct_rate``'s convention); a run without a fix: all its outputs with truth.
            Global fixes: the fixes with truth.
        correct, fine: per output.
        coverage: map coverage of the output's scan (NaN: unknown).
        fixed: a replay reached a fix.
        recall: global fixes, ``(F, len(RECALL_KS))``: a correct candidate among the first k.
        localized: replays, per output: reported LOCALIZED.
        rmse: replays, the errors and left-out intervals for ``metrics.shared_rmse``.
        contained, contained_coverage: replays of a set method (IAL's boxes), per output with
            boxes: the set holds the truth, and the map coverage of that output's scan.
        contained_needed: the share of the scan the set's bound assumes the map explains (NaN: not declared).
    """

    kind: str
    counted: NDArray[np.bool_]
    correct: NDArray[np.bool_]
    fine: NDArray[np.bool_]
    coverage: NDArray[np.float64]
    fixed: bool = True
    recall: NDArray[np.bool_] | None = None
    localized: NDArray[np.bool_] | None = None
    rmse: metrics.RmseSample | None = None
    contained: NDArray[np.bool_] | None = None
    contained_coverage: NDArray[np.float64] | None = None
    contained_needed: NDArray[np.float64] | None = None


def _coverage_at(coverage: ScanCoverage | None, stamps: NDArray[np.float64]) -> NDArray[np.float64]:
    return coverage.at(stamps) if coverage is not None else np.full(stamps.shape, np.nan)


def replay_scores(record: RunRecord, series: dict[str, Any], coverage: ScanCoverage | None) -> OutputScores | None:
    """The scores of a replay from ``summarize_run``'s per-output series; None without ground truth."""
    if "correct" not in series:
        return None
    correct = np.asarray(series["correct"], dtype=bool)
    has_truth = np.isfinite(np.asarray(series["position_error_m"], dtype=np.float64))
    fix = metrics.first_fix_index(record.stamps, correct)
    counted = has_truth & (np.arange(correct.size) >= (fix if fix is not None else 0))
    contained = contained_coverage = contained_needed = None
    if record.containment is not None and record.containment_stamps is not None:
        contained = np.asarray(record.containment, dtype=bool)
        contained_coverage = _coverage_at(coverage, np.asarray(record.containment_stamps, dtype=np.float64))
        if record.containment_needed is not None:
            contained_needed = np.asarray(record.containment_needed, dtype=np.float64)
    return OutputScores("replay", counted, correct, np.asarray(series["fine"], dtype=bool),
                        _coverage_at(coverage, record.stamps), fixed=fix is not None,
                        localized=np.asarray([s == "LOCALIZED" for s in record.statuses], dtype=bool),
                        rmse=metrics.RmseSample(record.stamps, np.asarray(series["position_error_m"]),
                                                np.asarray(series["heading_error_rad"]), series["rmse_excluded"]),
                        contained=contained, contained_coverage=contained_coverage,
                        contained_needed=contained_needed)


def global_fix_scores(record: GlobalFixRecord, coverage: ScanCoverage | None) -> OutputScores:
    """The scores of single-scan global fixes (a failed fix is not correct)."""
    with_truth = np.all(np.isfinite(record.truths), axis=1)
    dxy, dtheta = metrics.pose_errors(record.estimates, record.truths)
    recall = np.array([[r[k] for k in metrics.RECALL_KS] for r in record.recalls], dtype=bool)
    return OutputScores("global_fixes", with_truth, metrics.correct_mask(dxy, dtheta) & with_truth,
                        metrics.fine_mask(dxy, dtheta) & with_truth, _coverage_at(coverage, record.stamps),
                        recall=recall.reshape(-1, len(metrics.RECALL_KS)))


def _rate(values: NDArray[np.bool_]) -> float | None:
    return round(float(np.mean(values)), 4) if values.size else None


def pooled_fields(runs: Sequence[OutputScores]) -> dict[str, Any]:
    """Rates over the outputs of ``runs`` together (not a mean of their rates).

    Replays: ``outputs`` (counted), ``correct_rate``, ``fine_rate``, ``outputs_covered``,
    ``correct_rate_covered``, ``map_coverage_median`` (over all outputs with a coverage),
    ``runs_without_fix``; a set method's runs also ``containment_rate``, ``containment_rate_covered``
    and ``containment_outputs_covered`` (every output with a set, from the first), and where it declares
    the share of the scan its bound assumes explained, ``containment_rate_bound_held`` and
    ``containment_outputs_bound_held``: over the outputs whose scan the map explains that well at the truth.
    Global fixes: ``fixes``, ``global_correct_rate``, ``global_fine_rate``, ``recall_at_k``, ``fixes_covered``,
    ``global_correct_rate_covered``, ``map_coverage_median``.
    """
    if not runs:
        return {}
    counted = np.concatenate([r.counted for r in runs])
    correct = np.concatenate([r.correct for r in runs])[counted]
    fine = np.concatenate([r.fine for r in runs])[counted]
    coverage = np.concatenate([r.coverage for r in runs])
    known = coverage[np.isfinite(coverage)]
    rates = metrics.coverage_rates(correct, coverage[counted])
    median = round(float(np.median(known)), 4) if known.size else None
    if runs[0].kind == "global_fixes":
        recall = np.concatenate([r.recall if r.recall is not None else np.zeros((0, len(metrics.RECALL_KS)), bool)
                                 for r in runs])[counted]
        return {
            "fixes": int(counted.sum()),
            "global_correct_rate": _rate(correct),
            "global_fine_rate": _rate(fine),
            "recall_at_k": {str(k): _rate(recall[:, i]) for i, k in enumerate(metrics.RECALL_KS)},
            "fixes_covered": rates["outputs_covered"],
            "global_correct_rate_covered": rates["correct_rate_covered"],
            "map_coverage_median": median,
        }
    all_correct = np.concatenate([r.correct for r in runs])
    localized = np.concatenate([r.localized if r.localized is not None else np.zeros(r.correct.size, bool)
                                for r in runs])
    fields = {
        "outputs": int(counted.sum()),
        "correct_rate": _rate(correct),
        "localized_rate": _rate(localized),
        "false_localized_rate": _rate(~all_correct[localized]),
        "fine_rate": _rate(fine),
        "outputs_covered": rates["outputs_covered"],
        "correct_rate_covered": rates["correct_rate_covered"],
        "map_coverage_median": median,
        "runs_without_fix": sum(not r.fixed for r in runs),
    }
    set_runs = [r for r in runs if r.contained is not None and r.contained_coverage is not None]
    if set_runs:
        contained = np.concatenate([r.contained for r in set_runs if r.contained is not None])
        set_coverage = np.concatenate([r.contained_coverage for r in set_runs if r.contained_coverage is not None])
        sets = metrics.coverage_rates(contained, set_coverage)
        fields.update(containment_rate=sets["correct_rate"], containment_rate_covered=sets["correct_rate_covered"],
                      containment_outputs_covered=sets["outputs_covered"])
        needed = np.concatenate([r.contained_needed if r.contained_needed is not None
                                 else np.full(len(r.contained), np.nan) for r in set_runs if r.contained is not None])
        if np.isfinite(needed).any():  # the method declares what its bound assumes
            held = np.isfinite(needed) & np.isfinite(set_coverage) & (set_coverage >= needed - 1e-9)
            fields.update(containment_rate_bound_held=_rate(contained[held]),
                          containment_outputs_bound_held=int(held.sum()))
    return fields


def run_coverage_fields(scores: OutputScores) -> dict[str, Any]:
    """The coverage fields of one run: ``map_coverage_median`` and the rates over covered outputs
    (``correct_rate_covered`` and ``outputs_covered``, null without a fix, as ``correct_rate``;
    ``containment_rate_covered`` and ``containment_outputs_covered`` for a set method; for global fixes ``global_correct_rate_covered`` and ``fixes_covered``)."""
    pooled = pooled_fields([scores])
    if scores.kind == "global_fixes":
        keys = ("map_coverage_median", "fixes_covered", "global_correct_rate_covered")
        return {key: pooled[key] for key in keys}
    fields = {
        "map_coverage_median": pooled["map_coverage_median"],
        "outputs_covered": pooled["outputs_covered"] if scores.fixed else None,
        "correct_rate_covered": pooled["correct_rate_covered"] if scores.fixed else None,
    }
    if "containment_rate_covered" in pooled:  # a set method: every output, fix or not
        fields.update({key: pooled[key] for key in ("containment_rate_covered", "containment_outputs_covered",
                                                    "containment_rate_bound_held", "containment_outputs_bound_held")
                       if key in pooled})
    return fields
