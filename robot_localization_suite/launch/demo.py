"""``make demo``: the simulated office with every localizer that exists, live, side by side.

Starts ``scan_sim`` on a scenario (default ``config/scenarios/office_kidnap.yaml``,
real time or ``--speed`` times faster) and each available localizer node
(``registry.PLUGINS``) with its ``config/<name>.yaml`` and the
scenario's map (``-p map_yaml:=...``), all through :mod:`.runner` with DDS on
loopback. A monitor node in this process subscribes to ``/ground_truth``, each
``/<localizer>/pose`` and ``/diagnostics``, and prints once a second each
localizer's latest estimate and its error against the ground truth at the
estimate's stamp. When the scenario ends (or after ``--duration`` seconds, or on
Ctrl-C) it stops every node and prints a summary table: outputs, correct rate
(within 0.5 m and 25 degrees, ``core.metrics``), median position error, and
median update time as the localizers report it on ``/diagnostics``.

With no localizer installed it runs the simulator alone, which still shows the
ground truth and kidnappings.
"""

from __future__ import annotations

import argparse
import bisect
import math
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from ..core import metrics
from ..registry import PLUGINS, config_dir
from .dds import use_loopback
from .runner import NodeSpec, RunError, install_stop_handlers, run_nodes

__all__ = ["DemoMonitor", "LocalizerTrack", "SummaryRow", "build_specs", "default_domain_id", "resolve_scenario", "main"]

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
    status: str = "-"
    update_ms: list[float] = field(default_factory=list)


class DemoMonitor:
    """Matches estimates to ground truth and keeps per-localizer statistics (no ROS in here).

    Estimates are compared with the ground truth interpolated at their stamp
    (:func:`core.metrics.interpolate_poses`, never across a kidnapping); an estimate
    waits until ground truth at or after its stamp has arrived.
    """

    def __init__(self, localizers: Sequence[str]) -> None:
        self.tracks = {name: LocalizerTrack(name) for name in localizers}
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
            track.last_pose = np.asarray(pose, dtype=np.float64)
            track.pending.append((stamp, track.last_pose))

    def on_diagnostics(self, name: str, status: str, update_ms: float | None) -> None:
        with self._lock:
            track = self.tracks.get(name)
            if track is None:
                return
            track.status = status
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

    def progress_lines(self) -> list[str]:
        """Compact lines for the periodic report: truth, then each localizer's estimate and error."""
        self.match_pending()
        with self._lock:
            if not self.truth_stamps:
                return ["waiting for /ground_truth ..."]
            # Stamps are the simulator's clock; times are shown from its start.
            start = self._origin()
            stamp, truth = self.truth_stamps[-1], self.truth_poses[-1]
            lines = []
            while self._announced_kidnaps < len(self.kidnappings):
                lines.append(f"*** kidnapping at t = {self.kidnappings[self._announced_kidnaps] - start:.1f} s ***")
                self._announced_kidnaps += 1
            lines.append(f"t = {stamp - start:6.1f} s  {'truth':<20} {_pose_text(truth)}")
            width = max([20, *(len(name) for name in self.tracks)])
            for track in self.tracks.values():
                if track.last_pose is None:
                    lines.append(f"{'':12}{track.name:<{width}} (no estimate yet)  {track.status}")
                    continue
                error = "err    ?" if track.last_error is None else (
                    f"err {track.last_error[0]:5.2f} m {math.degrees(track.last_error[1]):5.1f} deg"
                )
                lines.append(f"{'':12}{track.name:<{width}} {_pose_text(track.last_pose)}  {error}  {track.status}")
            return lines

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


def _pose_text(pose: np.ndarray) -> str:
    return f"x {pose[0]:7.2f}  y {pose[1]:7.2f}  yaw {math.degrees(pose[2]):7.1f} deg"


class MonitorNode:
    """The rclpy side of the monitor: subscriptions feeding :class:`DemoMonitor`, a 1 Hz report."""

    def __init__(self, monitor: DemoMonitor, print_line, period_s: float = 1.0) -> None:
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
        self.node.create_timer(period_s, lambda: [print_line(line) for line in monitor.progress_lines()])

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            try:
                update_ms = float(values["update_ms"]) if "update_ms" in values else None
            except ValueError:
                update_ms = None
            self.monitor.on_diagnostics(status.hardware_id, status.message, update_ms)


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


def build_specs(scenario_path: Path, map_yaml: Path, localizers: Sequence[str], speed: float,
                container: str | None = None) -> list[NodeSpec]:
    """scan_sim on the scenario, and each localizer with its config file and the scenario's map (in ``container``)."""
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
                container=container,
            )
        )
    return specs


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="rls_demo",
        description=(
            "Run scan_sim on a scenario with every available localizer (DDS on loopback), print each one's "
            "estimate and error once a second, and a summary table when the scenario ends."
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
    parser.add_argument("--period", type=float, default=1.0, help="seconds between progress reports (1)")
    parser.add_argument("--quiet-nodes", action="store_true", help="hide the nodes' own output")
    parser.add_argument("--separate", action="store_true",
                        help="each localizer in a process of its own (default: all in one container, docs/footprint.md)")
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

    out_lock = threading.Lock()

    def say(text: str) -> None:
        with out_lock:
            print(f"[demo] {text}", flush=True)

    def node_output(name: str, line: str) -> None:
        if not args.quiet_nodes:
            with out_lock:
                print(f"[{name}] {line}", flush=True)

    duration = args.duration
    if duration is None and math.isfinite(end_time):
        duration = end_time / args.speed + 60.0  # a backstop only: the scenario's end normally stops the run
    say(
        f"scenario {scenario_path.name} ({end_time:.0f} s at {args.speed:g}x), map {map_yaml.name}, "
        f"ROS_DOMAIN_ID {domain_id}, localizers: {', '.join(localizers) or 'none (simulator only)'}"
    )

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    monitor = DemoMonitor(localizers)
    stop = threading.Event()
    install_stop_handlers(stop)
    # Our handlers stop the nodes in order; rclpy must not take SIGINT over.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    monitor_node = MonitorNode(monitor, say, args.period)
    executor = SingleThreadedExecutor()
    executor.add_node(monitor_node.node)
    spinner = threading.Thread(target=executor.spin, daemon=True, name="monitor")
    spinner.start()

    try:
        result = run_nodes(
            build_specs(scenario_path, map_yaml, localizers, args.speed, None if args.separate else "localizers"),
            domain_id=domain_id,
            duration=duration,
            stop=stop,
            output=node_output,
            log=say,
        )
    except RunError as exc:
        print(f"rls_demo: {exc}", file=sys.stderr)
        return 2
    finally:
        # Stop spinning and wait for the thread before tearing rclpy down: a spinning thread left
        # behind at exit aborts the interpreter ("terminate called without an active exception").
        executor.shutdown(timeout_sec=2.0)
        spinner.join(timeout=5.0)
        monitor_node.node.destroy_node()
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
    failed = [name for name, code in result.exit_codes.items() if code not in (0, -signal.SIGINT)]
    if failed:
        say(f"nodes that failed: {', '.join(f'{n} ({result.exit_codes[n]})' for n in failed)}")
    return 0 if not failed and not result.escalated else 1


if __name__ == "__main__":
    raise SystemExit(main())
