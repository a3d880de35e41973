"""From a run's record to its ``summary.json`` fields: the metrics of ``core/metrics.py``.

:func:`summarize_run` for a replay (also the per-output arrays the plots draw),
:func:`summarize_global_fixes` for single-scan global fixes. Field definitions:
``docs/benchmark.md``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core import metrics
from .global_fixes import GlobalFixRecord
from .reference import BagReference
from .replay import RunRecord

__all__ = ["summarize_run", "summarize_global_fixes"]


def _recovery_fields(reference: BagReference) -> dict[str, Any]:
    """``recovered: true`` and how much, for a run on what was read back from a damaged bag."""
    recovery = reference.recovery
    undecodable = {"undecodable_messages": reference.undecodable} if reference.undecodable else {}
    if reference.truth_not_finite:
        undecodable["ground_truth_not_finite"] = reference.truth_not_finite
    if recovery is None:
        return undecodable
    last = recovery.last_log_time_ns
    return {"recovered": True, "recovered_messages": recovery.messages,
            "recovered_until_s": round(last * 1e-9, 3) if last is not None else None, **undecodable}


def _rate(values: list[bool] | None) -> float | None:
    if not values:
        return None
    return round(float(np.mean(values)), 4)


def _after_events(record: RunRecord, reference: BagReference, correct: np.ndarray) -> list[dict[str, Any]]:
    """Per map change and reinitialization request of the bag, the outputs from it to the next event:
    how many, ``correct_rate`` and the status fields (``false_localized_rate``: is LOCALIZED honest there?)."""
    events = sorted([(float(t), "map_change") for t in reference.map_change_stamps]
                    + [(float(t), "reinitialization") for t in reference.reinitialize_stamps])
    out = []
    bounds = [t for t, _ in events[1:]] + [np.inf]
    for (start, kind), stop in zip(events, bounds, strict=True):
        inside = (record.stamps >= start - 1e-9) & (record.stamps < stop - 1e-9)
        statuses = [s for s, keep in zip(record.statuses, inside, strict=True) if keep]
        out.append({"event": kind, "time_s": round(start, 3), "outputs": int(inside.sum()),
                    "correct_rate": _rate(list(correct[inside])),
                    **metrics.status_fields(statuses, correct[inside])})
    return out


def summarize_run(record: RunRecord, reference: BagReference) -> tuple[dict[str, Any], dict[str, Any]]:
    """``summary.json`` fields of one run, and per-output arrays for the plots."""
    fields: dict[str, Any] = {"mode": record.mode}
    series: dict[str, Any] = {}
    truth = reference.ground_truth
    if truth is not None:
        evaluation = metrics.evaluate_outputs(
            record.stamps, record.poses, truth,
            first_input_stamp=record.first_input_stamp, kidnap_indices=reference.kidnap_indices,
            candidates=record.candidates,
        )
        fields["correct"] = int(np.count_nonzero(evaluation["correct"]))
        fields["fine"] = int(np.count_nonzero(evaluation["fine"]))
        for key in ("time_to_first_fix_s", "kidnap_recovery_s", "kidnap_recovery_updates",
                    "kidnap_at_destination_before", "kidnap_candidate_recovery_updates", "correct_rate",
                    "fine_rate", "rmse_xy_m", "rmse_theta_rad"):
            fields[key] = evaluation[key]
        series = {key: evaluation[key] for key in ("correct", "fine", "position_error_m", "heading_error_rad",
                                                   "recovering", "rmse_excluded")}
        fields.update(metrics.status_fields(record.statuses, evaluation["correct"],
                                            evaluation["recovering"] if reference.kidnap_indices.size else None))
        if reference.map_change_stamps.size or reference.reinitialize_stamps.size:
            fields["after_events"] = _after_events(record, reference, np.asarray(evaluation["correct"], dtype=bool))
    else:
        fields.update(correct=None, fine=None, time_to_first_fix_s=None, kidnap_recovery_s=[],
                      kidnap_recovery_updates=[], kidnap_at_destination_before=[],
                      kidnap_candidate_recovery_updates=None, correct_rate=None, fine_rate=None, rmse_xy_m=None,
                      rmse_theta_rad=None)
    fields.update(metrics.timing_fields(record.update_ms))
    fields["peak_rss_mb"] = record.peak_rss_mb
    fields["outputs"] = int(record.stamps.size)
    # Beyond the list: what the reader needs to trust the numbers.
    fields["inputs"] = record.inputs
    fields["ground_truth"] = truth is not None
    fields["kidnappings"] = int(reference.kidnap_indices.size)
    fields["map_changes"] = int(reference.map_change_stamps.size)
    fields["reinitializations"] = int(reference.reinitialize_stamps.size)
    fields["map_setup_s"] = record.map_setup_s
    if record.containment is not None:
        fields["containment_rate"] = _rate(record.containment)
        # A kidnapping breaks the odometry bound the guarantee rests on: the promise holds
        # again once the method has restarted (an empty box list, reported LOST).
        after_restart = metrics.outside_kidnap_until_restart(
            np.asarray(record.containment_stamps), np.asarray(record.containment_lost), reference.kidnap_stamps
        )
        fields["containment_rate_after_restart"] = _rate(list(np.asarray(record.containment)[after_restart]))
    if record.box_hull_widths:
        widths = np.median(np.asarray(record.box_hull_widths), axis=0)
        fields["box_hull_median"] = {"x_m": round(float(widths[0]), 3), "y_m": round(float(widths[1]), 3),
                                     "theta_deg": round(float(np.rad2deg(widths[2])), 2)}
    if record.place_correct is not None:
        fields["correct_place_rate"] = _rate(record.place_correct)
    if record.corrected_heading_error_deg is not None:
        errors = record.corrected_heading_error_deg
        fields["heading_error_when_corrected_deg"] = {
            "median": round(float(np.median(errors)), 3) if errors else None,
            "max": round(float(np.max(errors)), 3) if errors else None,
            "count": len(errors),
        }
    if record.update_errors:
        fields["update_errors"] = record.update_errors
    if record.truncated:
        fields["truncated"] = True
    if record.odometry_from:
        fields["odometry_from"] = record.odometry_from
    fields.update(_recovery_fields(reference))
    if truth is None:
        fields["note"] = ("bag has no /ground_truth: timing only" if not reference.truth_messages else
                          f"none of the {reference.truth_messages} /ground_truth poses is finite: timing only")
    return fields, series



def summarize_global_fixes(record: GlobalFixRecord, reference: BagReference, *, every: int,
                           map_source: str) -> dict[str, Any]:
    """``summary.json`` fields of the global fixes of one localizer on one bag."""
    fields: dict[str, Any] = {"mode": "global_fixes", "every": every}
    fields.update(metrics.evaluate_global_fixes(record.estimates, record.truths, record.fix_ms, record.recalls))
    fields["failures"] = record.failures
    fields["peak_rss_mb"] = record.peak_rss_mb
    fields["map_setup_s"] = record.map_setup_s
    fields["map"] = map_source
    fields["ground_truth"] = reference.ground_truth is not None
    if record.truncated:
        fields["truncated"] = True
    fields.update(_recovery_fields(reference))
    return fields
