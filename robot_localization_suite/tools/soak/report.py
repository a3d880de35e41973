"""What a soak measured, summarised: RSS slope, CPU, pose latency and its trend, inputs dropped.

No ROS here: the monitor hands over plain series and this module turns them into the numbers,
the markdown table, ``soak.json`` and ``soak.png`` (docs/soak.md says what each column means).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ProcessSeries",
    "LatencySummary",
    "InputCounts",
    "rss_slope_mb_per_h",
    "summarise_latency",
    "expected_inputs",
    "fmt_number",
    "markdown_table",
    "write_json",
    "write_plot",
]

# "No growth": the last third's p95 at most this much above the first third's (ratio, and absolute [ms]).
GROWTH_RATIO = 1.25
GROWTH_SLACK_MS = 10.0
# The memory target [MB per hour].
RSS_SLOPE_TARGET = 1.0


@dataclass
class ProcessSeries:
    """One process sampled every period: seconds since the soak began, RSS [MB], CPU [% of one core]."""

    name: str
    pid: int
    t: list[float] = field(default_factory=list)
    rss_mb: list[float] = field(default_factory=list)
    cpu_percent: list[float] = field(default_factory=list)

    def window(self, start: float, end: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        t = np.asarray(self.t, dtype=np.float64)
        keep = (t >= start) & (t <= end)
        return t[keep], np.asarray(self.rss_mb)[keep], np.asarray(self.cpu_percent)[keep]


def rss_slope_mb_per_h(t_s: NDArray[np.float64], rss_mb: NDArray[np.float64]) -> float:
    """Least-squares slope of RSS over time [MB per hour]; NaN with fewer than 3 samples."""
    if len(t_s) < 3 or np.ptp(t_s) <= 0.0:
        return math.nan
    slope_per_s = np.polyfit(np.asarray(t_s, dtype=np.float64), np.asarray(rss_mb, dtype=np.float64), 1)[0]
    return float(slope_per_s * 3600.0)


@dataclass(frozen=True)
class LatencySummary:
    """Pose latency (receive time minus the input's stamp) over the measured window [ms]."""

    count: int
    p50_ms: float
    p95_ms: float
    max_ms: float
    p95_first_third_ms: float
    p95_last_third_ms: float

    @property
    def grows(self) -> bool:
        """Whether the last third's p95 exceeds the first third's by more than the allowed slack."""
        first, last = self.p95_first_third_ms, self.p95_last_third_ms
        if not (math.isfinite(first) and math.isfinite(last)):
            return False
        return last > max(first * GROWTH_RATIO, first + GROWTH_SLACK_MS)


def _p95(values: NDArray[np.float64]) -> float:
    return float(np.percentile(values, 95)) if values.size else math.nan


def summarise_latency(received: ArrayLike, sent: ArrayLike, start: float, end: float) -> LatencySummary:
    """Latencies ``received - sent`` of the messages received in ``[start, end]`` (wall clock [s]), thirds' p95.

    ``sent``: a message's stamp (the pose latency of the issue), or when its scan reached the monitor.
    """
    recv = np.asarray(received, dtype=np.float64)
    keep = (recv >= start) & (recv <= end)
    recv = recv[keep]
    latency_ms = (recv - np.asarray(sent, dtype=np.float64)[keep]) * 1e3
    if latency_ms.size == 0:
        return LatencySummary(0, math.nan, math.nan, math.nan, math.nan, math.nan)
    third = (end - start) / 3.0
    return LatencySummary(
        count=int(latency_ms.size),
        p50_ms=float(np.percentile(latency_ms, 50)),
        p95_ms=_p95(latency_ms),
        max_ms=float(latency_ms.max()),
        p95_first_third_ms=_p95(latency_ms[recv < start + third]),
        p95_last_third_ms=_p95(latency_ms[recv >= end - third]),
    )


@dataclass(frozen=True)
class InputCounts:
    """Inputs (scans or images) stamped inside the counting window: published by scan_sim, handled by the node."""

    kind: str
    published: int
    processed: int

    @property
    def dropped(self) -> int:
        return max(self.published - self.processed, 0)


def expected_inputs(first_step: int, last_step: int, *, camera_rate_hz: float | None = None,
                    laser_period_s: float = 0.1) -> int:
    """How many inputs scan_sim publishes at simulator steps ``first_step..last_step`` (both included).

    Every step has a scan; an image comes with the first step at or after each camera period
    (the rule of ``Simulator._render``), so it is replayed here from step 0.
    """
    if last_step < first_step:
        return 0
    if camera_rate_hz is None:
        return last_step - first_step + 1
    count, next_index = 0, 0
    for step in range(last_step + 1):
        time = step * laser_period_s
        if time + 1e-9 >= next_index / camera_rate_hz:
            next_index = int(math.floor(time * camera_rate_hz + 1e-9)) + 1
            count += step >= first_step
    return count


# -- output -------------------------------------------------------------------------------------
def fmt_number(value: float | None, digits: int = 0) -> str:
    """A table cell: the value rounded, or an en dash when there is none."""
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def markdown_table(summary: dict[str, Any]) -> str:
    """The soak table: one row per process, the localizers with their latency and inputs."""
    header = ("| process | RSS at window start → end [MB] | RSS slope [MB/h] | CPU [% of a core] "
              "| inputs published / processed / dropped | poses | latency p50 / p95 / max [ms] "
              "| p95 first → last third [ms] | after the scan: p50 / p95 [ms] | its p95 first → last third [ms] |")
    lines = [header, "|" + "---|" * 10]
    for name, proc in summary["processes"].items():
        loc = summary["localizers"].get(name)
        counts = poses = "–"
        if loc is not None:
            c = loc["inputs"]
            counts = "–" if c is None else f"{c['kind']}: {c['published']} / {c['processed']} / {c['dropped']}"
            poses = str(loc["poses"])
        latency = loc["latency"] if loc is not None else summary.get("scan_age", {}).get(name)
        after = loc["after_scan"] if loc is not None else None
        lines.append(
            f"| {name} | {fmt_number(proc['rss_start_mb'])} → {fmt_number(proc['rss_end_mb'])} | {fmt_number(proc['rss_slope_mb_per_h'], 1)} "
            f"| {fmt_number(proc['cpu_percent_mean'])} | {counts} | {poses} | {_spread(latency)} | {_trend(latency)} "
            f"| {_spread(after, with_max=False)} | {_trend(after)} |"
        )
    return "\n".join(lines)


def _spread(latency: dict[str, Any] | None, with_max: bool = True) -> str:
    if latency is None:
        return "–"
    text = f"{fmt_number(latency['p50_ms'])} / {fmt_number(latency['p95_ms'])}"
    return text + f" / {fmt_number(latency['max_ms'])}" if with_max else text


def _trend(latency: dict[str, Any] | None) -> str:
    if latency is None:
        return "–"
    text = f"{fmt_number(latency['p95_first_third_ms'])} → {fmt_number(latency['p95_last_third_ms'])}"
    return text + " (grows)" if latency.get("grows") else text


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    return value


def write_json(path: Path, summary: dict[str, Any], series: Sequence[ProcessSeries]) -> None:
    """``soak.json``: the summary and every process's samples (NaN written as null)."""
    content = dict(summary, samples={s.name: asdict(s) for s in series})
    path.write_text(json.dumps(_jsonable(content), indent=1) + "\n")


def write_plot(path: Path, series: Sequence[ProcessSeries], latencies: dict[str, tuple[list[float], list[float]]],
               t0_wall: float, window: tuple[float, float], title: str) -> None:
    """``soak.png``: RSS and CPU per process over time, pose latency over time and its distribution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(14, 9))
    (ax_rss, ax_cpu), (ax_lat, ax_cdf) = axes
    for s in series:
        ax_rss.plot(np.asarray(s.t) / 60.0, s.rss_mb, marker=".", label=s.name)
        ax_cpu.plot(np.asarray(s.t) / 60.0, s.cpu_percent, marker=".", label=s.name)
    for name, (received, stamps) in latencies.items():
        recv = np.asarray(received, dtype=np.float64)
        if recv.size == 0:
            continue
        latency_ms = np.maximum((recv - np.asarray(stamps, dtype=np.float64)) * 1e3, 1e-3)
        ax_lat.plot((recv - t0_wall) / 60.0, latency_ms, ".", markersize=2, alpha=0.5, label=name)
        inside = np.sort(latency_ms[(recv - t0_wall >= window[0]) & (recv - t0_wall <= window[1])])
        if inside.size:
            ax_cdf.step(inside, np.arange(1, inside.size + 1) / inside.size, where="post", label=name)
    for ax in (ax_rss, ax_cpu, ax_lat):
        ax.axvspan(window[0] / 60.0, window[1] / 60.0, color="0.9", zorder=0)
        ax.set_xlabel("time since start [min] (shaded: measured window)")
    ax_rss.set_ylabel("RSS [MB]")
    ax_cpu.set_ylabel("CPU [% of one core]")
    ax_lat.set_ylabel("pose latency [ms]")
    ax_lat.set_yscale("log")
    ax_cdf.set_xscale("log")
    ax_cdf.set_xlabel("pose latency [ms] (measured window)")
    ax_cdf.set_ylabel("fraction of poses")
    ax_cdf.axvline(1e3, color="0.7", linestyle=":")
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
