"""``make demo``: the simulated office with every localizer that exists, live, side by side.

Starts ``scan_sim`` on a scenario (default ``config/scenarios/office_kidnap.yaml``,
real time or ``--speed`` times faster) and each available localizer node
(``registry.PLUGINS``) with its ``config/<name>.yaml`` and the
scenario's map (``-p map_yaml:=...``), all through :mod:`.runner` with DDS on
loopback. Each run gets a directory (``--out``, printed at the start): the nodes' output goes
to its ``logs/`` (``--verbose``: inline too). A monitor node in this process subscribes to
``/ground_truth``, each ``/<localizer>/pose`` and ``/diagnostics`` and shows, per localizer, its
state, its error against the ground truth at the estimate's stamp and its update time
(:mod:`.demo_monitor`; redrawn in place on a terminal). A second node
records the run into ``recording/`` (:mod:`..ros.recording`), and with ``--foxglove`` serves
it live (:mod:`..ros.foxglove_live`). When the scenario ends (or after ``--duration``
seconds, or on Ctrl-C) it stops every node and prints a summary table: outputs, correct rate
(within 0.5 m and 25 degrees, ``core.metrics``), median position error, and
median update time as the localizers report it on ``/diagnostics``; it writes
``trajectories.png`` (:func:`.demo_monitor.write_picture`) and ``foxglove_layout.json`` next to the recording.

With no localizer installed it runs the simulator alone, which still shows the
ground truth and kidnappings.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..registry import PLUGINS, config_dir
from .dds import use_loopback
from .demo_monitor import DemoMonitor, MonitorDisplay, MonitorNode, write_picture
from .foxglove_layout import LAYOUT_FILE, demo_layout
from .runner import NodeSpec, RunError, install_stop_handlers, run_nodes

__all__ = ["NodeLogs", "build_specs", "default_domain_id", "resolve_scenario", "main"]

DEFAULT_SCENARIO = "office_kidnap"


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
            build_specs(scenario_path, map_yaml, localizers, args.speed, None if args.separate else "localizers"),
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
