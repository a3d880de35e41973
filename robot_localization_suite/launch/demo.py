"""``make demo``: the simulated office with every localizer that exists, live, side by side.

Starts ``scan_sim`` on a scenario (default ``config/scenarios/office_kidnap.yaml``,
real time or ``--speed`` times faster) and each available localizer node
(``registry.PLUGINS``) with its ``config/<name>.yaml`` and the
scenario's map (``-p map_yaml:=...``), all through :mod:`.runner` with DDS on
loopback. Each run gets a directory (``--out``, printed at the start): the nodes' output goes
to its ``logs/`` (``--verbose``: inline too). A monitor node in this process subscribes to
``/ground_truth``, each ``/<localizer>/pose`` and ``/diagnostics`` and shows, per localizer, its
state, its error against the ground truth at the estimate's stamp and its update time
(:func:`row_text`; redrawn in place on a terminal, :class:`MonitorDisplay`). A second node
records the run into ``recording/`` (:mod:`..ros.recording`), and with ``--foxglove`` serves
it live (:mod:`..ros.foxglove_live`). When the scenario ends (or after ``--duration``
seconds, or on Ctrl-C) it stops every node and prints a summary table: outputs, correct rate
(within 0.5 m and 25 degrees, ``core.metrics``), median position error, and
median update time as the localizers report it on ``/diagnostics``; it writes
``trajectories.png`` (:func:`write_picture`) and ``foxglove_layout.json`` next to the recording.

With no localizer installed it runs the simulator alone, which still shows the
ground truth and kidnappings.
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from ..core import metrics
from ..registry import PLUGINS, config_dir
from .dds import use_loopback
from .foxglove_layout import LAYOUT_FILE, demo_layout
from .runner import NodeSpec, RunError, install_stop_handlers, run_nodes

__all__ = ["DemoMonitor", "LocalizerTrack", "MonitorDisplay", "NodeLogs", "SummaryRow", "row_text", "write_picture",
           "build_specs", "default_domain_id", "resolve_scenario", "main"]

DEFAULT_SCENARIO = "office_kidnap"


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
    elif track.last_error is not None and _finite(*track.last_error):
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


def default_domain_id() -> int:
    if os.environ.get("ROS_DOMAIN_ID", "").isdigit():
        return int(os.environ["ROS_DOMAIN_ID"])
    # A domain of this run's own (101..232, clear of the test runs' 1..100) so that two demos on one
    # machine do not see each other.
    return 101 + os.getpid() % 132


def resolve_scenario(value: str) -> Path:
    path = Path(value)
    if path.is_file():
        return path.resolve()
    named = config_dir() / "scenarios" / f"{value}.yaml"
    if named.is_file():
        return named
    raise RunError(f"scenario {value!r} is neither a file nor a name in {config_dir() / 'scenarios'}")


def build_specs(scenario_path: Path, map_yaml: Path, localizers: Sequence[str], speed: float) -> list[NodeSpec]:
    """scan_sim on the scenario, and each localizer with its config file and the scenario's map."""
    sim_params = config_dir() / "scan_sim.yaml"
    specs = [
        NodeSpec(
            "scan_sim",
            "scan_sim",
            params_file=str(sim_params) if sim_params.is_file() else None,
            parameters={"scenario": str(scenario_path), "speed": float(speed)},
        )
    ]
    for name in localizers:
        params = config_dir() / f"{name}.yaml"
        specs.append(
            NodeSpec(
                name,
                name,
                params_file=str(params) if params.is_file() else None,
                parameters={"map_yaml": str(map_yaml)},
            )
        )
    return specs


def _start_recording(run_dir: Path, monitor: DemoMonitor, localizers: Sequence[str], camera: bool,
                     sinks: list[Any]) -> tuple[Any, Any]:
    """A node tapping the run's topics into ``<run>/recording`` (MCAP) and into ``sinks`` (the live server).

    The monitor's scored errors go the same way, on :func:`..ros.recording.error_topic`.
    """
    from rclpy.node import Node

    from ..ros.recording import ERROR_TYPE, RunRecording, RunTap, error_message, error_topic, run_topics

    recording = RunRecording(run_dir / "recording")
    node = Node("rls_demo_recorder")
    tap = RunTap(node, run_topics(localizers, camera=camera), [recording, *sinks])

    def scored(name: str, stamps: np.ndarray, dxy: np.ndarray, dtheta: np.ndarray) -> None:
        for stamp, error_xy, error_theta in zip(stamps, dxy, dtheta, strict=True):
            tap.emit(error_topic(name), ERROR_TYPE, error_message(stamp, error_xy, error_theta), int(stamp * 1e9))

    monitor.on_scored = scored
    return node, recording


def _start_live_server(localizers: Sequence[str], camera: bool, port: int) -> Any:
    """The Foxglove WebSocket server of the recorded topics and the scored errors (:mod:`..ros.foxglove_live`)."""
    from ..ros.foxglove_live import LiveServer
    from ..ros.recording import ERROR_TYPE, error_topic, run_topics

    topics = [(topic.name, topic.type_name) for topic in run_topics(localizers, camera=camera)]
    return LiveServer(topics + [(error_topic(name), ERROR_TYPE) for name in localizers], port=port)


def run_directory(out: str | os.PathLike[str], scenario_name: str) -> Path:
    """A new directory of this run under ``out``: ``<UTC time>_<scenario>`` (``_2``, ``_3`` ... if taken)."""
    base = Path(out) / f"{time.strftime('%Y%m%d-%H%M%S', time.gmtime())}_{scenario_name}"
    path, n = base, 1
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}_{n}")
    path.mkdir(parents=True)
    return path


class NodeLogs:
    """Each node's output into ``<run>/logs/<node>.log`` (the runner's own into ``rls_run.log``)."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        self._files: dict[str, Any] = {}
        self._lock = threading.Lock()

    def path(self, name: str) -> Path:
        return self.directory / f"{name}.log"

    def write(self, name: str, line: str) -> None:
        with self._lock:
            handle = self._files.get(name)
            if handle is None:
                handle = self._files[name] = open(self.path(name), "a", buffering=1, encoding="utf-8")  # noqa: SIM115
            handle.write(line + "\n")

    def close(self) -> None:
        with self._lock:
            for handle in self._files.values():
                handle.close()
            self._files.clear()


# Runner lines shown even without --verbose: the localizers came up, or a node did not.
_RUNNER_HEADLINES = ("active:", "did not come up", "still running")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="rls_demo",
        description=(
            "Run scan_sim on a scenario with every available localizer (DDS on loopback), show each one's "
            "state, error and update time, and a summary table when the scenario ends. The nodes' output "
            "goes to the run's directory (printed at the start)."
        ),
    )
    parser.add_argument(
        "--scenario", default=DEFAULT_SCENARIO, help=f"scenario YAML, or a name in config/scenarios ({DEFAULT_SCENARIO})"
    )
    parser.add_argument("--speed", type=float, default=1.0, help="simulation speed as a multiple of real time (1)")
    parser.add_argument(
        "--localizers",
        help="comma-separated localizers to run (default: every available one; 'none' for the simulator alone)",
    )
    parser.add_argument("--duration", type=float, help="stop after this many wall-clock seconds (default: scenario end)")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID or one of this run's own)")
    parser.add_argument("--period", type=float,
                        help="seconds between monitor reports (default 1 on a terminal, where the report is "
                             "redrawn in place; 10 otherwise)")
    parser.add_argument("--out", default="results/demo",
                        help="directory under which each run gets its own: the nodes' logs, the recording, "
                             "its Foxglove layout and the picture (results/demo)")
    parser.add_argument("--verbose", action="store_true",
                        help="show the nodes' own output inline too (it always goes to the run's logs/)")
    parser.add_argument("--foxglove", action="store_true",
                        help="serve the recorded topics live over the Foxglove WebSocket protocol on loopback "
                             "(needs foxglove-sdk: the 'viz' extra, which make installs)")
    parser.add_argument("--foxglove-port", type=int, default=8765,
                        help="port of the --foxglove server on 127.0.0.1 (8765; 0: a free one)")
    args = parser.parse_args(argv)
    if not args.speed > 0.0:
        parser.error(f"--speed must be > 0, got {args.speed!r}")
    available = list(PLUGINS)
    if args.localizers is None:
        localizers = available
    elif args.localizers.strip().lower() in ("", "none"):
        localizers = []
    else:
        localizers = [name.strip() for name in args.localizers.split(",") if name.strip()]
        missing = [name for name in localizers if name not in available]
        if missing:
            parser.error(f"not available: {', '.join(missing)} (available: {', '.join(available) or 'none'})")

    from ..core.errors import ScenarioError
    from ..core.sim.scenario_yaml import load_scenario

    try:
        scenario_path = resolve_scenario(args.scenario)
        scenario = load_scenario(scenario_path)
    except (RunError, ScenarioError) as exc:
        print(f"rls_demo: {exc}", file=sys.stderr)
        return 2
    map_yaml = Path(scenario.map_path) if scenario.map_path else config_dir() / "maps" / "office.yaml"
    end_time = scenario.end_time
    if scenario.camera is None and args.localizers is None:
        # Camera localizers would wait for images this scenario never publishes.
        blind = [name for name in localizers if PLUGINS[name].uses_camera]
        localizers = [name for name in localizers if name not in blind]
        if blind:
            print(f"[demo] left out (the scenario has no camera): {', '.join(blind)}", flush=True)
    domain_id = args.domain_id if args.domain_id is not None else default_domain_id()
    # The monitor in this process talks DDS on loopback too, on the nodes' domain.
    use_loopback(domain_id)

    display = MonitorDisplay()
    say = display.message
    run_dir = run_directory(args.out, scenario_path.stem)
    logs = NodeLogs(run_dir / "logs")
    period = args.period if args.period is not None else (1.0 if display.redraw else 10.0)

    def node_output(name: str, line: str) -> None:
        logs.write(name, line)
        if args.verbose:
            display.message(f"[{name}] {line}")

    def runner_log(text: str) -> None:
        logs.write("rls_run", text)
        if args.verbose or any(key in text for key in _RUNNER_HEADLINES):
            say(text)

    duration = args.duration
    if duration is None and math.isfinite(end_time):
        duration = end_time / args.speed + 60.0  # a backstop only: the scenario's end normally stops the run
    say(
        f"scenario {scenario_path.name} ({end_time:.0f} s at {args.speed:g}x), map {map_yaml.name}, "
        f"ROS_DOMAIN_ID {domain_id}, localizers: {', '.join(localizers) or 'none (simulator only)'}"
    )
    say(f"run directory {run_dir} (node logs in {run_dir / 'logs'}"
        + (")" if args.verbose else "; --verbose shows them here)"))

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    monitor = DemoMonitor(localizers)
    sinks: list[Any] = []
    server = None
    if args.foxglove:
        try:
            server = _start_live_server(localizers, scenario.camera is not None, args.foxglove_port)
        except (ImportError, RuntimeError) as exc:
            print(f"rls_demo: --foxglove: {exc}", file=sys.stderr)
            return 2
        sinks.append(server)
        url = server.app_url()
        say(f"Foxglove: open connection {server.address}" + (f" (or {url})" if url else ""))
    stop = threading.Event()
    install_stop_handlers(stop)
    # Our handlers stop the nodes in order; rclpy must not take SIGINT over.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    monitor_node = MonitorNode(monitor, display, period)
    executor = SingleThreadedExecutor()
    executor.add_node(monitor_node.node)
    recorder_node, recording = _start_recording(run_dir, monitor, localizers, scenario.camera is not None,
                                                 sinks)
    executor.add_node(recorder_node)
    say(f"recording into {recording.path}")
    spinner = threading.Thread(target=executor.spin, daemon=True, name="monitor")
    spinner.start()

    try:
        result = run_nodes(
            build_specs(scenario_path, map_yaml, localizers, args.speed),
            domain_id=domain_id,
            duration=duration,
            stop=stop,
            output=node_output,
            log=runner_log,
        )
    except RunError as exc:
        print(f"rls_demo: {exc}", file=sys.stderr)
        return 2
    finally:
        logs.close()
        # Stop spinning and wait for the thread before tearing rclpy down: a spinning thread left
        # behind at exit aborts the interpreter ("terminate called without an active exception").
        executor.shutdown(timeout_sec=2.0)
        spinner.join(timeout=5.0)
        monitor_node.node.destroy_node()
        recorder_node.destroy_node()
        # The last report scores what is left, and its errors still reach the recording.
        display.update(monitor.new_events(), monitor.status_lines())
        display.finish()
        recording_size = recording.close()
        if server is not None:
            server.close()
        rclpy.try_shutdown()

    if result.first_exit == ("scan_sim", 0):
        say("scenario finished")  # scan_sim exits with 0 at the scenario's end (exit_at_end)
    elif result.reason == "exited" and result.first_exit is not None:
        say(f"{result.first_exit[0]} ended the run (exit code {result.first_exit[1]})")
    elif result.reason == "duration":
        say(f"stopped after {duration:.0f} s")
    else:
        say("stopped")
    for line in monitor.summary_table().splitlines():
        say(line)
    from ..core.grid_map import load_map_yaml

    picture = write_picture(monitor, load_map_yaml(map_yaml), run_dir / "trajectories.png",
                            f"{scenario_path.stem}: the demo's estimates")
    if picture is not None:
        say(f"picture: {picture}")
    layout_path = run_dir / "foxglove_layout.json"
    try:
        layout_path.write_text(json.dumps(demo_layout(localizers, camera=scenario.camera is not None), indent=2) + "\n")
        layout_note = f"; open it in Foxglove with the layout {layout_path}"
    except ImportError:
        layout_note = f"; no layout for it without foxglove-sdk (the 'viz' extra): {config_dir() / LAYOUT_FILE} fits"
    say(f"recording: {recording.path} ({recording_size / 1e6:.1f} MB)" + layout_note)
    failed = [name for name, code in result.exit_codes.items() if code not in (0, -signal.SIGINT)]
    if failed:
        say(f"nodes that failed: {', '.join(f'{n} ({result.exit_codes[n]})' for n in failed)}; "
            f"their output: {logs.directory}")
    return 0 if not failed and not result.escalated else 1


if __name__ == "__main__":
    raise SystemExit(main())
