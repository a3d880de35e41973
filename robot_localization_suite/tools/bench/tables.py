"""The benchmark's files: ``summary.json`` and ``summary.md`` (a markdown table per run kind).

:func:`summary_table` makes one row per (bag, localizer) from the fields of
``summary.py``; :func:`write_summary` writes both files.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...core import metrics

__all__ = ["summary_table", "write_summary", "append_section", "one_line", "comparison_tables"]


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}g}" if abs(value) < 1e4 else f"{value:.0f}"
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v, digits) for v in value) + "]" if value else "–"
    if isinstance(value, dict):
        return ", ".join(f"{k} {_fmt(v, digits)}" for k, v in value.items())
    return str(value)


def _cell(fields: Mapping[str, Any], key: str) -> str:
    """A table cell; a kidnapping the method was already at (wrongly, before the jump) is marked "there before"."""
    if key != "kidnap_recovery_s" or not fields.get(key):
        return _fmt(fields.get(key))
    there = fields.get("kidnap_at_destination_before") or []
    marks = [" (there before)" if k < len(there) and there[k] else "" for k in range(len(fields[key]))]
    return "[" + ", ".join(_fmt(value) + mark for value, mark in zip(fields[key], marks, strict=True)) + "]"


def one_line(fields: dict[str, Any]) -> str:
    """A run's main figures on one line, for the progress output."""
    return (f"outputs {fields.get('outputs')}, correct_rate {_fmt(fields.get('correct_rate'))}, "
            f"first fix {_fmt(fields.get('time_to_first_fix_s'))} s, rmse {_fmt(fields.get('rmse_xy_m'))} m, "
            f"update {_fmt(fields.get('update_ms_median'))} ms")


_REPLAY_COLUMNS = (
    ("outputs", "outputs"),
    ("correct_rate", "correct rate"),
    ("fine_rate", "fine rate"),
    ("correct_rate_covered", f"correct rate, coverage >= {metrics.COVERED_FRACTION}"),
    ("map_coverage_median", "map coverage median"),
    ("localized_rate", "LOCALIZED rate"),
    ("false_localized_rate", "false LOCALIZED rate"),
    ("false_localized_rate_outside_kidnaps", "false LOCALIZED rate outside kidnappings"),
    ("time_to_first_fix_s", "first fix [s]"),
    ("kidnap_recovery_s", "kidnap recovery [s]"),
    ("kidnap_recovery_updates", "kidnap recovery [updates]"),
    ("kidnap_candidate_recovery_updates", f"truth in top {metrics.CANDIDATE_K} [updates]"),
    ("rmse_xy_m", "RMSE xy [m]"),
    ("rmse_theta_rad", "RMSE θ [rad]"),
    ("rmse_xy_m_shared", "RMSE xy, shared outputs [m]"),
    ("update_ms_median", "update median [ms]"),
    ("update_ms_p95", "update p95 [ms]"),
    ("peak_rss_mb", "peak RSS [MB]"),
)
_GLOBAL_COLUMNS = (
    ("fixes", "fixes"),
    ("global_correct_rate", "correct rate"),
    ("global_fine_rate", "fine rate"),
    ("recall_at_k", "recall@k"),
    ("global_correct_rate_covered", f"correct rate, coverage >= {metrics.COVERED_FRACTION}"),
    ("map_coverage_median", "map coverage median"),
    ("fix_ms_median", "fix median [ms]"),
    ("fix_ms_p95", "fix p95 [ms]"),
    ("peak_rss_mb", "peak RSS [MB]"),
)
_SPECIFIC = ("containment_rate", "containment_rate_after_restart", "containment_rate_covered",
             "containment_rate_bound_held", "box_hull_median", "correct_place_rate", "heading_error_when_corrected_deg")


def _is_global_fixes(summary: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> bool:
    return any(f.get("mode") == "global_fixes" for runs in summary.values() for f in runs.values())


def summary_table(summary: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> str:
    """One markdown table: a row per (bag, localizer)."""
    columns = _GLOBAL_COLUMNS if _is_global_fixes(summary) else _REPLAY_COLUMNS
    header = ["bag", "localizer", *(title for _, title in columns), "notes"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for bag, runs in summary.items():
        if not runs:
            lines.append(f"| {bag} | – |" + " |" * len(columns) + " no localizer ran |")
        for name, fields in runs.items():
            notes = []
            if "skipped" in fields:
                notes.append(f"skipped: {fields['skipped']}")
            if "error" in fields:
                notes.append(f"error: {fields['error']}")
            for key in _SPECIFIC:
                if key in fields:
                    notes.append(f"{key} {_fmt(fields[key])}")
            if fields.get("params"):
                notes.append(f"params {fields['params']}")
            if fields.get("odometry_noise"):
                notes.append(f"odometry noise {fields['odometry_noise']}")
            if fields.get("laser_mount"):
                notes.append(f"laser mount from {fields['laser_mount']}")
            if fields.get("odometry_from"):
                notes.append(f"odometry from {fields['odometry_from']}")
            if fields.get("truncated"):
                notes.append("truncated by --max-seconds")
            if fields.get("recovered"):
                notes.append(f"recovered from a damaged bag ({fields.get('recovered_messages')} messages, "
                             f"to {_fmt(fields.get('recovered_until_s'))} s)")
            if fields.get("undecodable_messages"):
                notes.append(f"{fields['undecodable_messages']} damaged messages of its truth, odometry or map "
                             "skipped")
            if fields.get("ground_truth_not_finite"):
                notes.append(f"{fields['ground_truth_not_finite']} ground-truth poses not finite, left out")
            if fields.get("ground_truth") is False:
                notes.append("no ground truth")
            if fields.get("update_errors"):
                notes.append(f"{fields['update_errors']} update errors")
            for event in fields.get("after_events") or []:
                notes.append(f"after the {event['event'].replace('_', ' ')} at {_fmt(event['time_s'])} s: correct "
                             f"{_fmt(event['correct_rate'])}, LOCALIZED {_fmt(event['localized_rate'])}, false "
                             f"LOCALIZED {_fmt(event['false_localized_rate'])}")
            if "skipped" in fields or ("error" in fields and "outputs" not in fields):
                cells = ["" for _ in columns]
            else:
                cells = [_cell(fields, key) for key, _ in columns]
            lines.append("| " + " | ".join([bag, name, *cells, "; ".join(notes)]) + " |")
    return "\n".join(lines)


def write_summary(out_dir: Path, summary: Mapping[str, Any], *, title: str) -> None:
    """``summary.json`` (bag -> localizer -> fields) and ``summary.md`` (the table and the definitions)."""
    out_dir = Path(out_dir)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=False) + "\n")
    criteria = (f"correct: |dxy| <= {metrics.CORRECT_XY_M} m and |dθ| <= "
                f"{np.rad2deg(metrics.CORRECT_THETA_RAD):.0f} deg; fine: <= {metrics.FINE_XY_M} m and <= "
                f"{metrics.FINE_THETA_RAD} rad.")
    if _is_global_fixes(summary):
        explanation = ("Each fix is the best candidate of global_fix(scan) for one scan alone, with no prior; "
                       "recall@k: a correct candidate among the first k.")
    else:
        explanation = (f"A fix is a correct output followed by {metrics.FIX_FOLLOWERS} more. Rates and RMSE count "
                       f"outputs from the first fix on; RMSE (the tracking error) leaves out each kidnapping's "
                       f"recovery, from the jump to its recovery fix (at least {metrics.KIDNAP_EXCLUSION_S:.0f} s; "
                       "to the next kidnapping if never recovered); the shared RMSE counts only the outputs "
                       "that no run on the bag leaves out, so the runs compare over the same stretch.")
    text = [f"# {title}", "", summary_table(summary), "",
            f"{criteria} {explanation} Definitions: README, section Benchmark.", ""]
    (out_dir / "summary.md").write_text("\n".join(text))


def append_section(out: Path, sub: str) -> None:
    """Append ``out/sub/summary.md`` to ``out/summary.md``, its title one level down."""
    extra = (out / sub / "summary.md").read_text().replace("# ", "## ", 1)
    with open(out / "summary.md", "a") as stream:
        stream.write("\n" + extra)


_COMPARED = ("correct_rate", "false_localized_rate", "time_to_first_fix_s", "kidnap_recovery_s", "rmse_xy_m",
             "update_ms_median", "peak_rss_mb")


def comparison_tables(runs: Mapping[str, Mapping[str, Mapping[str, Mapping[str, Any]]]]) -> str:
    """A markdown table per localizer of the first run: a row per bag and run (``runs``: label -> summary),
    so that two settings of one method (its paper profile and ours) read side by side."""
    titles = dict(_REPLAY_COLUMNS)
    labels = list(runs)
    first = runs[labels[0]]
    names = list(dict.fromkeys(name for bag_runs in first.values() for name in bag_runs))
    parts = []
    for name in names:
        header = ["bag", "run", *(titles[key] for key in _COMPARED)]
        lines = [f"### {name}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for bag in first:
            for label in labels:
                fields = runs[label].get(bag, {}).get(name)
                if fields is None or "outputs" not in fields:
                    why = "not run" if fields is None else fields.get("skipped") or fields.get("error") or "no output"
                    lines.append("| " + " | ".join([bag, label, why, *([""] * (len(_COMPARED) - 1))]) + " |")
                else:
                    lines.append("| " + " | ".join([bag, label, *(_cell(fields, key) for key in _COMPARED)]) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts)
