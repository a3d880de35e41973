"""The demo's monitor: each localizer's state and error against the truth, on one line each.

:class:`DemoMonitor` keeps the truth and every localizer's estimates and scores each
estimate against the truth at its stamp (``core.metrics``); :func:`row_text` formats a
localizer's line (a LOST one or one without a scored estimate shows no numbers);
:class:`MonitorDisplay` redraws the block in place on a terminal and prints plain lines
otherwise; :class:`MonitorNode` feeds the monitor from ``/ground_truth``, the poses and
``/diagnostics``; :func:`write_picture` draws the run's paths at the end.
"""

from __future__ import annotations

import bisect
import math
import shutil
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from ..core import metrics

__all__ = ["DemoMonitor", "LocalizerTrack", "MonitorDisplay", "MonitorNode", "SummaryRow", "header_text", "row_text",
           "write_picture"]


class SummaryRow(TypedDict):
    """One localizer's line of the final summary (None: nothing to measure)."""

    localizer: str
    outputs: int
    scored: int
    correct_rate: float | None
    median_error_m: float | None  # [m]
    median_update_ms: float | None  # [ms]


@dataclass
class LocalizerTrack:
    """What the monitor knows about one localizer."""

    name: str
    pending: list[tuple[float, np.ndarray]] = field(default_factory=list)  # estimates waiting for truth
    stamps: list[float] = field(default_factory=list)
    errors_xy: list[float] = field(default_factory=list)
    errors_theta: list[float] = field(default_factory=list)
    outputs: int = 0
    last_pose: np.ndarray | None = None
    last_error: tuple[float, float] | None = None
    last_error_stamp: float | None = None  # the stamp of the estimate last_error belongs to
    status: str = "-"
    progress: str = ""  # what an INITIALIZING node prepares, and how far it is
    update_ms: list[float] = field(default_factory=list)
    path: list[np.ndarray] = field(default_factory=list)  # every finite estimate, for the picture


class DemoMonitor:
    """Matches estimates to ground truth and keeps per-localizer statistics (no ROS in here).

    Estimates are compared with the ground truth interpolated at their stamp
    (:func:`core.metrics.interpolate_poses`, never across a kidnapping); an estimate
    waits until ground truth at or after its stamp has arrived.
    """

    def __init__(self, localizers: Sequence[str],
                 on_scored: Callable[[str, np.ndarray, np.ndarray, np.ndarray], None] | None = None) -> None:
        """``on_scored(name, stamps [s], position errors [m], heading errors [rad])`` sees each batch scored."""
        self.tracks = {name: LocalizerTrack(name) for name in localizers}
        self.on_scored = on_scored
        self.truth_stamps: list[float] = []
        self.truth_poses: list[np.ndarray] = []
        self.kidnappings: list[float] = []
        self.time_origin: float | None = None  # the simulator's t = 0 (the stamp of its /map)
        self._lock = threading.Lock()
        self._announced_kidnaps = 0

    # -- inputs (called from the ROS executor thread) -------------------------------------
    def on_truth(self, stamp: float, pose: np.ndarray) -> None:
        with self._lock:
            if self.truth_stamps and stamp <= self.truth_stamps[-1]:
                return
            if self.truth_poses:
                previous = self.truth_poses[-1]
                if math.hypot(pose[0] - previous[0], pose[1] - previous[1]) > metrics.KIDNAP_JUMP_M:
                    self.kidnappings.append(stamp)
            self.truth_stamps.append(stamp)
            self.truth_poses.append(np.asarray(pose, dtype=np.float64))

    def on_map_stamp(self, stamp: float) -> None:
        """scan_sim stamps its map with its clock at t = 0: scenario times are counted from there."""
        with self._lock:
            self.time_origin = stamp

    def _origin(self) -> float:
        return self.time_origin if self.time_origin is not None else self.truth_stamps[0]

    def on_estimate(self, name: str, stamp: float, pose: np.ndarray) -> None:
        with self._lock:
            track = self.tracks.setdefault(name, LocalizerTrack(name))
            track.outputs += 1
            pose = np.asarray(pose, dtype=np.float64)
            if not np.all(np.isfinite(pose)):  # counted, never shown nor scored
                return
            track.last_pose = pose
            track.path.append(pose)
            track.pending.append((stamp, pose))

    def on_diagnostics(self, name: str, status: str, update_ms: float | None, progress: str = "") -> None:
        with self._lock:
            track = self.tracks.get(name)
            if track is None:
                return
            track.status = status
            track.progress = progress
            if update_ms is not None and math.isfinite(update_ms):
                track.update_ms.append(update_ms)

    # -- evaluation -----------------------------------------------------------------------
    def match_pending(self, final: bool = False) -> None:
        """Score the estimates whose ground truth has arrived (all of them when ``final``)."""
        with self._lock:
            if not self.truth_stamps:
                return
            trajectory = metrics.Trajectory(np.array(self.truth_stamps), np.array(self.truth_poses))
            breaks = [bisect.bisect_left(self.truth_stamps, t) for t in self.kidnappings]
            latest = self.truth_stamps[-1]
            for track in self.tracks.values():
                ready = [(s, p) for s, p in track.pending if final or s <= latest]
                if not ready:
                    continue
                track.pending = [(s, p) for s, p in track.pending if not (final or s <= latest)]
                stamps = np.array([s for s, _ in ready])
                truth = metrics.interpolate_poses(trajectory, stamps, breaks=breaks)
                dxy, dtheta = metrics.pose_errors(np.array([p for _, p in ready]), truth)
                known = np.isfinite(dxy)
                track.stamps.extend(stamps[known].tolist())
                track.errors_xy.extend(dxy[known].tolist())
                track.errors_theta.extend(dtheta[known].tolist())
                if known.any():
                    track.last_error = (float(dxy[known][-1]), float(dtheta[known][-1]))
                    track.last_error_stamp = float(stamps[known][-1])
                    if self.on_scored is not None:
                        self.on_scored(track.name, stamps[known], dxy[known], dtheta[known])

    def new_events(self) -> list[str]:
        """Announcements not yet made (kidnappings), each once: they stay above the redrawn block."""
        with self._lock:
            if not self.truth_stamps:
                return []
            start = self._origin()
            lines = []
            while self._announced_kidnaps < len(self.kidnappings):
                lines.append(f"*** kidnapping at t = {self.kidnappings[self._announced_kidnaps] - start:.1f} s ***")
                self._announced_kidnaps += 1
            return lines

    def status_lines(self) -> list[str]:
        """The block the monitor redraws: the truth, a header, one row per localizer (:func:`row_text`)."""
        self.match_pending()
        with self._lock:
            if not self.truth_stamps:
                return ["waiting for /ground_truth ..."]
            # Stamps are the simulator's clock; times are shown from its start.
            start = self._origin()
            stamp, truth = self.truth_stamps[-1], self.truth_poses[-1]
            width = max([20, *(len(name) for name in self.tracks)])
            lines = [f"t = {stamp - start:6.1f} s  {'truth':<{width}} {_pose_text(truth)}"]
            if self.tracks:
                lines.append(header_text(width))
            lines += [row_text(track, start, width) for track in self.tracks.values()]
            return lines

    def progress_lines(self) -> list[str]:
        """New announcements, then the status block (what a plain, non-redrawing report prints)."""
        events = self.new_events()
        return events + self.status_lines()

    def paths(self) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]] | None:
        """The true path ``(N, 3)``, the indices in it where kidnappings landed, each localizer's estimates ``(M, 3)``.

        None before any ground truth.
        """
        with self._lock:
            if not self.truth_poses:
                return None
            kidnaps = np.array([bisect.bisect_left(self.truth_stamps, t) for t in self.kidnappings], dtype=np.int64)
            estimates = {name: np.array(track.path).reshape(-1, 3) for name, track in self.tracks.items()}
            return np.array(self.truth_poses), kidnaps, estimates

    def summary_rows(self) -> list[SummaryRow]:
        self.match_pending(final=True)
        rows: list[SummaryRow] = []
        with self._lock:
            for track in self.tracks.values():
                dxy, dtheta = np.array(track.errors_xy), np.array(track.errors_theta)
                correct = metrics.correct_mask(dxy, dtheta)
                rows.append(
                    {
                        "localizer": track.name,
                        "outputs": track.outputs,
                        "scored": int(dxy.size),
                        "correct_rate": float(correct.mean()) if dxy.size else None,
                        "median_error_m": float(np.median(dxy)) if dxy.size else None,
                        "median_update_ms": float(np.median(track.update_ms)) if track.update_ms else None,
                    }
                )
        return rows

    def summary_table(self) -> str:
        header = f"{'localizer':<20} {'outputs':>8} {'correct (0.5 m, 25 deg)':>24} {'median err [m]':>15} {'median update [ms]':>19}"
        lines = [header, "-" * len(header)]
        for row in self.summary_rows():
            rate = "-" if row["correct_rate"] is None else f"{100.0 * row['correct_rate']:.1f} %"
            err = "-" if row["median_error_m"] is None else f"{row['median_error_m']:.3f}"
            upd = "-" if row["median_update_ms"] is None else f"{row['median_update_ms']:.2f}"
            lines.append(f"{row['localizer']:<20} {row['outputs']:>8} {rate:>24} {err:>15} {upd:>19}")
        if not self.tracks:
            lines.append("(no localizer ran: simulator only)")
        with self._lock:
            span = (self.truth_stamps[-1] - self.truth_stamps[0]) if len(self.truth_stamps) > 1 else 0.0
            lines.append(
                f"ground truth: {len(self.truth_stamps)} poses over {span:.1f} s of scenario time, "
                f"{len(self.kidnappings)} kidnapping(s)"
            )
        return "\n".join(lines)


def write_picture(monitor: DemoMonitor, grid_map: Any, path: Path, title: str) -> Path | None:
    """The run as one PNG: the map, the true path, kidnappings (stars), each localizer's estimates (dots).

    Drawn as the benchmark's trajectory plots are (:mod:`..tools.map_plots`); None when no truth came.
    """
    import matplotlib.pyplot as plt

    from ..tools.map_plots import draw_truth, finish_map_axes, save_figure, show_map

    paths = monitor.paths()
    if paths is None:
        return None
    truth, kidnaps, estimates = paths
    fig, axes = plt.subplots(figsize=(8, 8))
    show_map(axes, grid_map)
    draw_truth(axes, truth, kidnaps)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"][1:]  # blue is the truth's
    for index, (name, poses) in enumerate(estimates.items()):
        axes.plot(poses[:, 0], poses[:, 1], ".", ms=3, color=colours[index % len(colours)],
                  label=f"{name} ({len(poses)} estimates)")
    finish_map_axes(axes, title)
    return save_figure(fig, path)


def _pose_text(pose: np.ndarray) -> str:
    return f"x {pose[0]:7.2f}  y {pose[1]:7.2f}  yaw {math.degrees(pose[2]):7.1f} deg"


_ERROR_HEADER = "error vs truth at the estimate's stamp"


def header_text(width: int) -> str:
    """The column names above the localizer rows (the error column says against which truth)."""
    return f"{'':12}{'localizer':<{width}} {'state':<18} {_ERROR_HEADER:<38} {'update':>10}"


def _finite(*values: float | None) -> bool:
    return all(value is not None and math.isfinite(value) for value in values)


def row_text(track: LocalizerTrack, origin: float, width: int = 20) -> str:
    """One localizer's row: state, its last scored error with that estimate's time, its last update time.

    A LOST localizer has no numbers (its last pose is an older estimate's); a value that is not
    finite is shown as ``-``: a row never prints ``nan``.
    """
    state = track.status if track.status != "-" else "waiting"
    if track.progress and state == "INITIALIZING":
        state = f"{state} {track.progress}"
    error = "-"
    if state == "LOST":
        error = "- (no pose while lost)"
    elif track.last_error is not None and _finite(track.last_error[0], math.degrees(track.last_error[1])):
        error = f"{track.last_error[0]:6.2f} m {math.degrees(track.last_error[1]):6.1f} deg"
        since = None if track.last_error_stamp is None else track.last_error_stamp - origin
        if _finite(since):
            error += f"  (t = {since:6.1f} s)"
    elif track.last_pose is not None:
        error = "(waiting for truth)"
    update = f"{track.update_ms[-1]:7.1f} ms" if track.update_ms and _finite(track.update_ms[-1]) else "-"
    return f"{'':12}{track.name:<{width}} {state[:18]:<18} {error:<38} {update:>10}"


class MonitorDisplay:
    """Writes the monitor: on a terminal the status block is redrawn in place, elsewhere printed as lines.

    Messages (``say``) and announcements are printed above the block and stay; the block is
    the only part that is replaced (ANSI cursor-up and clear-to-end).
    """

    def __init__(self, stream: Any = None, redraw: bool | None = None, prefix: str = "[demo] ") -> None:
        self.stream = stream if stream is not None else sys.stdout
        self.redraw = bool(redraw if redraw is not None else getattr(self.stream, "isatty", lambda: False)())
        self.prefix = prefix
        self._block: list[str] = []
        self._lock = threading.Lock()

    def _erase(self) -> None:
        if self.redraw and self._block:
            self.stream.write(f"\x1b[{len(self._block)}F\x1b[J")

    def _draw(self) -> None:
        # On a terminal each line is cut to its width: a wrapped line would throw the cursor-up count off.
        width = shutil.get_terminal_size().columns - 1 if self.redraw else None
        for line in self._block:
            self.stream.write(f"{self.prefix}{line}"[:width] + "\n")

    def message(self, text: str) -> None:
        """A line that stays (printed above the block on a terminal)."""
        with self._lock:
            self._erase()
            self.stream.write(f"{self.prefix}{text}\n")
            if self.redraw:
                self._draw()
            self.stream.flush()

    def update(self, events: Sequence[str], block: Sequence[str]) -> None:
        """Print ``events`` (they stay), then show ``block`` in place of the previous one."""
        with self._lock:
            self._erase()
            for line in events:
                self.stream.write(f"{self.prefix}{line}\n")
            self._block = list(block)
            self._draw()
            self.stream.flush()

    def finish(self) -> None:
        """Leave the last block on screen; later messages print below it."""
        with self._lock:
            self._block = []


class MonitorNode:
    """The rclpy side of the monitor: subscriptions feeding :class:`DemoMonitor`, a 1 Hz report."""

    def __init__(self, monitor: DemoMonitor, display: MonitorDisplay, period_s: float = 1.0) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import OccupancyGrid, Odometry
        from rclpy.node import Node
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        from ..ros.conversions import odometry_from_msg, pose_from_pose_msg, stamp_to_seconds
        from ..ros.qos import MAP_QOS, RELIABLE_QOS

        self.monitor = monitor
        self.node = Node("rls_demo_monitor")
        # Best effort accepts both best-effort and reliable publishers of ground truth.
        truth_qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(
            Odometry, "/ground_truth", lambda msg: monitor.on_truth(*odometry_from_msg(msg)), truth_qos
        )

        # Typed callbacks: the message packages ship no types, so rclpy cannot infer the message type.
        def on_map(msg: Any) -> None:
            monitor.on_map_stamp(stamp_to_seconds(msg.header.stamp))

        def on_pose(name: str) -> Callable[[Any], None]:
            return lambda msg: monitor.on_estimate(
                name, stamp_to_seconds(msg.header.stamp), pose_from_pose_msg(msg.pose.pose)
            )

        self.node.create_subscription(OccupancyGrid, "/map", on_map, MAP_QOS)
        for name in monitor.tracks:
            self.node.create_subscription(PoseWithCovarianceStamped, f"/{name}/pose", on_pose(name), RELIABLE_QOS)
        diagnostics_qos = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, diagnostics_qos)
        self.node.create_timer(period_s, lambda: display.update(monitor.new_events(), monitor.status_lines()))

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            try:
                update_ms = float(values["update_ms"]) if "update_ms" in values else None
            except ValueError:
                update_ms = None
            progress = values.get("progress_percent", "")
            progress = f"{float(progress):.0f} %" if _is_number(progress) else ""
            self.monitor.on_diagnostics(status.hardware_id, status.message, update_ms, progress)


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
