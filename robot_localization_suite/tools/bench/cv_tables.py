"""The ``--cv`` run's files: ``summary.json`` and ``summary.md`` (per mode a pooled table, then per block).

Each cell shows the honest map's figure, then the whole-log map's: ``0.62 / 0.97``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ...core import metrics
from .tables import _fmt

__all__ = ["cv_tables", "write_cv_summary", "append_cv_section"]

COVERED = f"coverage >= {metrics.COVERED_FRACTION}"
_POOLED_REPLAY = (
    ("outputs", "outputs"),
    ("correct_rate", "correct rate"),
    ("correct_rate_covered", f"correct rate, {COVERED}"),
    ("outputs_covered", "outputs covered"),
    ("map_coverage_median", "map coverage median"),
    ("false_localized_rate", "false LOCALIZED rate"),
)
_POOLED_FIXES = (
    ("fixes", "fixes"),
    ("global_correct_rate", "correct rate"),
    ("global_correct_rate_covered", f"correct rate, {COVERED}"),
    ("recall_at_10", "recall@10"),
    ("fixes_covered", "fixes covered"),
    ("map_coverage_median", "map coverage median"),
)
_BLOCK_REPLAY = (
    ("outputs", "outputs"),
    ("correct_rate", "correct rate"),
    ("correct_rate_covered", f"correct rate, {COVERED}"),
    ("map_coverage_median", "map coverage median"),
    ("false_localized_rate", "false LOCALIZED rate"),
    ("time_to_first_fix_s", "first fix [s]"),
    ("rmse_xy_m", "RMSE xy [m]"),
)
_BLOCK_FIXES = (
    ("fixes", "fixes"),
    ("global_correct_rate", "correct rate"),
    ("global_correct_rate_covered", f"correct rate, {COVERED}"),
    ("recall_at_10", "recall@10"),
    ("map_coverage_median", "map coverage median"),
    ("fix_ms_median", "fix median [ms]"),
)
_TITLES = {
    "global": "Global mode (no prior)",
    "tracking": "Tracking mode (the first true pose on initialpose)",
    "global_fixes": "Single-scan global fixes (every {every}th scan, no prior)",
}


def _value(fields: Mapping[str, Any], key: str) -> Any:
    if key == "recall_at_10":
        return (fields.get("recall_at_k") or {}).get("10")
    return fields.get(key)


def _pair(entry: Mapping[str, Any], key: str) -> str:
    return " / ".join(_fmt(_value(entry.get(kind) or {}, key)) for kind in ("honest", "same_map"))


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _header(first: list[str], columns: tuple[tuple[str, str], ...]) -> list[str]:
    titles = [*first, *(title for _, title in columns), "notes"]
    return [_row(titles), "|" + "---|" * len(titles)]


def _containment_notes(entry: Mapping[str, Any]) -> list[str]:
    """A set method's containment, all outputs and those with the map covering the scan (honest / same map)."""
    if not any("containment_rate" in (entry.get(kind) or {}) for kind in ("honest", "same_map")):
        return []
    notes = [f"containment {_pair(entry, 'containment_rate')}, {COVERED} {_pair(entry, 'containment_rate_covered')}"]
    if any("containment_rate_bound_held" in (entry.get(kind) or {}) for kind in ("honest", "same_map")):
        notes.append(f"where the scan meets the set's bound {_pair(entry, 'containment_rate_bound_held')} "
                     f"({_pair(entry, 'containment_outputs_bound_held')} outputs)")
    return notes


def _run_notes(entry: Mapping[str, Any]) -> list[str]:
    notes = _containment_notes(entry)
    for kind in ("honest", "same_map"):
        fields = entry.get(kind) or {}
        if "error" in fields:
            notes.append(f"{kind}: error: {fields['error']}")
        if fields.get("truncated"):
            notes.append(f"{kind}: truncated by --max-seconds")
        if fields.get("mode") in ("global", "tracking") and "error" not in fields and fields.get("correct_rate") is None:
            notes.append(f"{kind}: no fix")
    return notes


def _pooled_table(pooled: Mapping[str, Mapping[str, Any]], columns: tuple[tuple[str, str], ...]) -> list[str]:
    lines = _header(["log", "localizer", "blocks"], columns)
    for log, localizers in pooled.items():
        for name, entry in localizers.items():
            if "skipped" in entry:
                lines.append(_row([log, name, "–", *("" for _ in columns), f"skipped: {entry['skipped']}"]))
                continue
            notes = _containment_notes(entry)
            notes += [f"left out {block} ({why})" for block, why in entry.get("left_out", {}).items()]
            without_fix = [f"{kind} {entry[kind]['runs_without_fix']}" for kind in ("honest", "same_map")
                           if (entry.get(kind) or {}).get("runs_without_fix")]
            if without_fix:
                notes.append("blocks without a fix (all their outputs counted): " + ", ".join(without_fix))
            if entry.get("truncated_runs"):
                notes.append(f"{entry['truncated_runs']} runs truncated by --max-seconds")
            lines.append(_row([log, name, str(entry.get("blocks")), *(_pair(entry, key) for key, _ in columns),
                               "; ".join(notes)]))
    return lines


def _block_table(blocks: Mapping[str, Mapping[str, Any]], columns: tuple[tuple[str, str], ...],
                 skipped_everywhere: set[str]) -> list[str]:
    """A row per block and localizer, leaving out localizers the pooled table shows skipped on every block."""
    lines = _header(["block", "localizer"], columns)
    for block, localizers in blocks.items():
        for name, entry in localizers.items():
            if "skipped" in entry and name in skipped_everywhere:
                continue
            if "skipped" in entry:
                lines.append(_row([block, name, *("" for _ in columns), f"skipped: {entry['skipped']}"]))
                continue
            lines.append(_row([block, name, *(_pair(entry, key) for key, _ in columns), "; ".join(_run_notes(entry))]))
    return lines


def cv_tables(summary: Mapping[str, Any], *, level: int = 2) -> str:
    """Markdown: per mode, the pooled table (log x localizer), then the per-block table."""
    heading = "#" * level
    text: list[str] = []
    for mode in summary.get("modes", []):
        fixes = mode == "global_fixes"
        title = _TITLES[mode].format(every=summary.get("every"))
        pooled = summary[mode]["pooled"]
        skipped_everywhere = {name for localizers in pooled.values() for name, entry in localizers.items()
                              if "skipped" in entry}
        skipped_everywhere -= {name for localizers in pooled.values() for name, entry in localizers.items()
                               if "skipped" not in entry}
        text += [f"{heading} {title}: pooled per log", "",
                 *_pooled_table(pooled, _POOLED_FIXES if fixes else _POOLED_REPLAY), "",
                 f"{heading} {title}: per block", "",
                 *_block_table(summary[mode]["blocks"], _BLOCK_FIXES if fixes else _BLOCK_REPLAY, skipped_everywhere),
                 ""]
    return "\n".join(text)


def write_cv_summary(out_dir: Path, summary: Mapping[str, Any]) -> None:
    """``summary.json`` (the whole summary) and ``summary.md`` (the tables and what they mean)."""
    out_dir = Path(out_dir)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=False) + "\n")
    explanation = (
        "Each cell: honest / same map. Honest: the block's own map, built from the other blocks' scans only; "
        "same map: the whole-log map, built from every scan including the block's own. Both runs replay the same "
        "block bag. Pooled: the outputs of all blocks together (not a mean of rates): each block's outputs from "
        "its own first fix on, a block without a fix with all its outputs; global fixes: every fix. Only blocks "
        "where both runs scored are pooled. Coverage: the share of an output's scan end points within 2 cells of "
        f"an occupied cell at the true pose; the covered rate counts outputs whose scan has {COVERED}. "
        "Definitions: docs/benchmark.md."
    )
    text = ["# rls_bench --cv: honest maps (from the other blocks) vs the whole-log map", "",
            cv_tables(summary), explanation, ""]
    (out_dir / "summary.md").write_text("\n".join(text))


def append_cv_section(out: Path, sub: str = "cv") -> None:
    """Append ``out/sub/summary.md`` to ``out/summary.md``, every heading one level down."""
    lines = (out / sub / "summary.md").read_text().splitlines()
    demoted = ["#" + line if line.startswith("#") else line for line in lines]
    with open(out / "summary.md", "a") as stream:
        stream.write("\n" + "\n".join(demoted) + "\n")
