"""Localizer nodes live over DDS against the replay of the same scenario, and their start-up time.

    python -m robot_localization_suite.tools.live_check [--scenario office_kidnap] [--seconds 40]
        [--localizers ial_localizer ...] [--speed 1.0] [--together] [--tracking NAME ...] [--no-replay]
        [--sim-first]
    python -m robot_localization_suite.tools.live_check --startup [--localizers ...] [--cache-dir DIR]

Live: the node runs as a process with its packaged params file (``config/<name>.yaml``) and the
scenario's map as ``map_yaml`` (precomputed at ``configure``), is configured and activated through
its ``lifecycle_msgs`` services, then ``scan_sim`` plays the scenario in real time (times
``--speed``); its ``~/pose`` is scored against the ``/ground_truth`` received over DDS. Replay: the
same scenario recorded with ``scan_sim``'s recorder is replayed through the same adapter as
``rls_bench`` does (global mode). Both are scored by ``core/metrics.py`` over the first ``--seconds``.
``--startup``: with ``scan_sim`` already running and the map from ``/map`` (nav2's bring-up), the time
from the ``configure`` request to the first ``map -> odom`` on ``/tf``. Everything on loopback DDS.
Options and measured figures: docs/benchmark.md, "Live and replay".
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core import metrics
from ..launch.dds import use_loopback
from ..ros.context_node import ContextNode

__all__ = ["LiveResult", "NodeProcess", "Probe", "live_runs", "main", "record_scenario", "replay_rate", "startup_time"]


class NodeProcess:
    """A node's ``python -m MODULE ARGS`` process whose output lines are collected; ``wait_for`` a pattern."""

    def __init__(self, *args: str, env: dict[str, str] | None = None) -> None:
        env = dict(os.environ if env is None else env)
        env["PYTHONUNBUFFERED"] = "1"
        env["RCUTILS_LOGGING_BUFFERED_STREAM"] = "0"
        self.process = subprocess.Popen([sys.executable, "-m", *args], env=env, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self._changed = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self._changed.notify_all()

    def text(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, pattern: str, timeout: float) -> re.Match[str]:
        """The first match of ``pattern`` in the output; AssertionError after ``timeout`` [s] or an exit."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                match = re.search(pattern, self.text())
                if match:
                    return match
                remaining = deadline - time.monotonic()
                assert remaining > 0, f"no {pattern!r} within {timeout} s in:\n{self.text()}"
                assert self.process.poll() is None, f"exited ({self.process.returncode}) without {pattern!r}:\n{self.text()}"
                self._changed.wait(min(remaining, 1.0))

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
        try:
            self.process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=15)


class Probe(ContextNode):
    """What a tf2 listener and RViz see of one localizer: its ``~/pose``, ``map -> odom``, ground truth, odometry."""

    def __init__(self, node_names: Sequence[str]) -> None:
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from ..ros.qos import TF_QOS
        from ..ros.tf import TFMessage

        super().__init__("rls_live_probe")
        self.poses: dict[str, list[tuple[float, np.ndarray]]] = {name: [] for name in node_names}
        self.first_tf_at: float | None = None  # monotonic time of the first map -> odom
        self.truth: list[tuple[float, np.ndarray]] = []
        self.odometry: list[tuple[float, np.ndarray]] = []
        # Volatile and deep: every pose of the run (the publisher is transient local, depth 1).
        pose_qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        for name in node_names:
            self.node.create_subscription(PoseWithCovarianceStamped, f"/{name}/pose",
                                          functools.partial(self._on_pose, name), pose_qos)
        self.node.create_subscription(Odometry, "/ground_truth", self._on_truth, QoSProfile(depth=200))
        self.node.create_subscription(Odometry, "/odom", self._on_odom, QoSProfile(depth=200))
        if TFMessage is not None:
            self.node.create_subscription(TFMessage, "/tf", self._on_tf, TF_QOS)

    def _on_pose(self, name: str, msg: Any) -> None:
        from ..ros.conversions import initial_pose_from_msg, stamp_to_seconds

        pose, _ = initial_pose_from_msg(msg)
        self.poses[name].append((stamp_to_seconds(msg.header.stamp), pose))

    def _on_truth(self, msg: Any) -> None:
        from ..ros.conversions import odometry_from_msg

        self.truth.append(odometry_from_msg(msg))

    def _on_odom(self, msg: Any) -> None:
        from ..ros.conversions import odometry_from_msg

        self.odometry.append(odometry_from_msg(msg))

    def _on_tf(self, msg: Any) -> None:
        if self.first_tf_at is None and any(
            (t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/")) == ("map", "odom") for t in msg.transforms
        ):
            self.first_tf_at = time.monotonic()


def _trajectory(samples: Sequence[tuple[float, np.ndarray]]) -> metrics.Trajectory:
    return metrics.Trajectory(np.array([s for s, _ in samples]), np.array([p for _, p in samples]).reshape(-1, 3))


@dataclass
class LiveResult:
    """One localizer's live run: its scores over the first ``seconds`` and what it did meanwhile."""

    localizer: str
    correct_rate: float | None
    outputs: int
    scans: int
    configure_s: float
    fields: dict[str, Any]


def scenario_path(name: str) -> Path:
    """A scenario file as given, else ``config/scenarios/<name>.yaml``."""
    from ..registry import resolve_scenario_path

    path = resolve_scenario_path(name)
    if path is None:
        raise ValueError("no scenario given")
    return path


def record_scenario(scenario: Path, bag_dir: Path, seconds: float) -> Path:
    """The first ``seconds`` [s] of ``scenario`` recorded by ``scan_sim``'s recorder into ``bag_dir``."""
    from ..core.sim.settings import ScanSimSettings
    from ..ros.sim_messages import make_simulator, record

    settings = ScanSimSettings(scenario=str(scenario))
    simulator = make_simulator(settings)
    steps = [0]
    limit = int(round(seconds * simulator.scenario.laser.rate_hz)) + 1

    def enough() -> str | None:
        steps[0] += 1
        return f"the {seconds:g} s limit" if steps[0] >= limit else None

    record(bag_dir, simulator, settings, log=lambda _line: None, stop_requested=enough)
    return bag_dir


def replay_rate(bag_dir: Path, localizer: str, mode: str = "global") -> dict[str, Any]:
    """``rls_bench``'s replay of ``bag_dir`` through ``localizer`` in ``mode`` (global, tracking): its summary fields."""
    from .bench import load_reference, registry_spec, replay_localizer, resolve_map, summarize_run

    reference = load_reference(bag_dir)
    grid_map, _ = resolve_map(reference, None)
    spec = registry_spec(localizer).for_bag(reference.name, laser_mounts=reference.laser_mounts)
    record = replay_localizer(reference, spec, grid_map, mode=mode, sample_rss=False)
    fields, _ = summarize_run(record, reference)
    return fields


def _params_args(localizer: str, scenario: Path) -> list[str]:
    """``--params-file`` arguments: the packaged file, then the benchmark's file for this scenario's bag if the
    plugin has one (as the replay reads it: ``bench_params``, e.g. the hybrid's camera_topomap)."""
    from ..registry import config_dir, plugin
    from .bench.specs import bench_params_file

    files = [config_dir() / f"{localizer}.yaml"]
    extra = bench_params_file(plugin(localizer), scenario.stem)
    if extra is not None:
        files.append(config_dir() / extra)
    return [arg for path in files for arg in ("--params-file", str(path))]


def live_runs(localizers: Sequence[str], scenario: Path, seconds: float, *, speed: float = 1.0,
              sim_first: bool = False, tracking: Sequence[str] = (), env: dict[str, str] | None = None,
              log: Callable[[str], None] = print) -> list[LiveResult]:
    """``localizers`` (together) configured and activated with the scenario's map, then ``scan_sim`` live.

    Each node is scored over the first ``seconds`` of simulated time. ``sim_first``: ``scan_sim`` runs
    first and the nodes take the map from ``/map`` (nav2's bring-up); scored from their activation on
    (not comparable to the replay, which starts with the scenario). ``tracking``: nodes given the
    scenario's start pose (``initial_pose.*``, applied at activation), as the replay's tracking mode.
    """
    from ..core.sim.settings import ScanSimSettings, build_scenario
    from ..launch.lifecycle import LifecycleManager

    world = build_scenario(ScanSimSettings(scenario=str(scenario)), scenario)
    map_yaml = world.map_path

    def start_sim() -> NodeProcess:
        return NodeProcess("robot_localization_suite.nodes.scan_sim", "--ros-args", "-p", f"scenario:={scenario}",
                           "-p", f"speed:={speed}", "-p", "exit_at_end:=false", env=env)

    sim = start_sim() if sim_first else None
    nodes: dict[str, NodeProcess] = {}
    for name in localizers:
        args = ["--ros-args", *_params_args(name, scenario)]
        if map_yaml and not sim_first:
            args += ["-p", f"map_yaml:={map_yaml}"]
        if name in tracking:
            x, y, yaw = (float(v) for v in world.start)
            args += ["-p", "set_initial_pose:=true", "-p", f"initial_pose.x:={x!r}", "-p", f"initial_pose.y:={y!r}",
                     "-p", f"initial_pose.yaw:={yaw!r}"]
        nodes[name] = NodeProcess(f"robot_localization_suite.nodes.{name}", *args, env=env)
    probe = Probe(list(localizers))
    manager = LifecycleManager(list(localizers), log=lambda _line: None)
    configure_s: dict[str, float] = {}
    try:
        for node in nodes.values():
            node.wait_for(r"unconfigured", 120)
        if sim is not None:
            sim.wait_for(r"simulating", 180)
        for name, node in nodes.items():
            started = time.monotonic()
            assert manager.change_state(name, "configure", 600.0), node.text()
            configure_s[name] = time.monotonic() - started
        for name, node in nodes.items():
            assert manager.change_state(name, "activate", 60.0), node.text()
        truth_before = len(probe.truth)
        if sim is None:
            sim = start_sim()

        def covered() -> bool:
            return len(probe.truth) > truth_before and probe.truth[-1][0] - probe.truth[truth_before][0] >= (
                seconds / speed + 1.0)

        probe.spin_until(covered, 60.0 + 3.0 * seconds / speed)
        probe.spin_until(lambda: False, 1.0)  # the last updates
    finally:
        if sim is not None:
            sim.stop()
        manager.close()
        probe.close()
        for node in nodes.values():
            node.stop()
    assert len(probe.truth) > truth_before, "no ground truth received:\n" + "\n".join(n.text() for n in nodes.values())
    truth = _trajectory(probe.truth[truth_before:])
    start = truth.stamps[0]
    end = start + seconds / speed
    in_time = truth.stamps <= end
    truth = metrics.Trajectory(truth.stamps[in_time], truth.poses[in_time])
    odometry = _trajectory(probe.odometry) if probe.odometry else None
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    results = []
    for name, node in nodes.items():
        poses = [(s, p) for s, p in probe.poses[name] if start <= s <= end]
        evaluation = metrics.evaluate_outputs(np.array([s for s, _ in poses]),
                                              np.array([p for _, p in poses]).reshape(-1, 3), truth,
                                              first_input_stamp=start, kidnap_indices=kidnaps)
        fields = {key: evaluation[key] for key in ("correct_rate", "fine_rate", "time_to_first_fix_s", "rmse_xy_m")}
        fields["first_output_s"] = round(poses[0][0] - start, 2) if poses else None
        warnings = sorted({re.sub(r"[-\d.]+", "#", line.split("]: ", 1)[-1]) for line in node.lines if "WARN" in line})
        for line in warnings:
            log(f"{name}: node warned: {line}")
        log(f"{name}: live {len(poses)} outputs for {len(truth)} scans, correct_rate {fields['correct_rate']}, "
            f"first output at +{fields['first_output_s']} s, configure {configure_s[name]:.2f} s")
        results.append(LiveResult(name, fields["correct_rate"], len(poses), len(truth), configure_s[name], fields))
    return results


def startup_time(localizer: str, scenario: Path, *, env: dict[str, str] | None = None,
                 timeout_s: float = 600.0) -> dict[str, float | None]:
    """With ``scan_sim`` publishing (map on ``/map``): seconds from the configure request to its answer,
    to the activate answer, and to the first ``map -> odom`` on ``/tf``."""
    from ..launch.lifecycle import LifecycleManager

    sim = NodeProcess("robot_localization_suite.nodes.scan_sim", "--ros-args", "-p", f"scenario:={scenario}",
                      "-p", "exit_at_end:=false", env=env)
    node = NodeProcess(f"robot_localization_suite.nodes.{localizer}", "--ros-args",
                       *_params_args(localizer, scenario), env=env)
    probe = Probe([localizer])
    manager = LifecycleManager([localizer], log=lambda _line: None)
    try:
        sim.wait_for(r"simulating", 180)
        node.wait_for(r"unconfigured", 120)
        started = time.monotonic()
        assert manager.change_state(localizer, "configure", timeout_s), node.text()
        configured = time.monotonic() - started
        assert manager.change_state(localizer, "activate", timeout_s), node.text()
        activated = time.monotonic() - started
        probe.spin_until(lambda: probe.first_tf_at is not None, timeout_s)
        first_tf = None if probe.first_tf_at is None else probe.first_tf_at - started
    finally:
        manager.close()
        probe.close()
        node.stop()
        sim.stop()
    return {"configure_s": configured, "activate_s": activated, "first_tf_s": first_tf}


def main(argv: Sequence[str] | None = None) -> int:
    from ..registry import PLUGINS

    parser = argparse.ArgumentParser(prog="python -m robot_localization_suite.tools.live_check",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="office_kidnap", help="scenario file or name in config/scenarios")
    parser.add_argument("--localizers", nargs="+", default=None, help="node names (default: every laser localizer)")
    parser.add_argument("--seconds", type=float, default=40.0, help="simulated seconds scored (live and replay)")
    parser.add_argument("--speed", type=float, default=1.0, help="scan_sim's real-time factor in the live runs")
    parser.add_argument("--no-replay", action="store_true", help="live runs only")
    parser.add_argument("--sim-first", action="store_true",
                        help="live: scan_sim first, the map from /map, scored from activation (implies --no-replay)")
    parser.add_argument("--together", action="store_true", help="live: every localizer at once on one scan_sim")
    parser.add_argument("--tracking", nargs="*", default=[],
                        help="localizers started from the scenario's start pose (live and replay: tracking mode)")
    parser.add_argument("--startup", action="store_true",
                        help="time from configure to the first map -> odom instead (scan_sim already running)")
    parser.add_argument("--cache-dir", default=None, help="RLS_CACHE_DIR of the nodes (an empty dir: cold cache)")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: 1 + pid %% 100)")
    options = parser.parse_args(argv)
    use_loopback(options.domain_id if options.domain_id is not None else 1 + os.getpid() % 100)
    env = dict(os.environ)
    if options.cache_dir is not None:
        env["RLS_CACHE_DIR"] = str(Path(options.cache_dir).resolve())
    scenario = scenario_path(options.scenario)
    names = options.localizers or [name for name, plugin in PLUGINS.items() if not plugin.uses_camera]
    if options.startup:
        print("| localizer | configure answered [s] | activate answered [s] | first map -> odom [s] |")
        print("| --- | --- | --- | --- |")
        for name in names:
            times = startup_time(name, scenario, env=env)
            cells = ["-" if v is None else f"{v:.2f}" for v in times.values()]
            print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
        return 0
    rows = []
    with tempfile.TemporaryDirectory(prefix="rls_live_") as folder:
        bag = record_scenario(scenario, Path(folder) / scenario.stem, options.seconds) if not (options.no_replay or options.sim_first) else None
        def run(chosen: list[str]) -> list[LiveResult]:
            return live_runs(chosen, scenario, options.seconds, speed=options.speed, sim_first=options.sim_first,
                             tracking=options.tracking, env=env)

        together = run(names) if options.together else None
        for index, name in enumerate(names):
            live = together[index] if together is not None else run([name])[0]
            mode = "tracking" if name in options.tracking else "global"
            replay = replay_rate(bag, name, mode) if bag is not None else {}
            rows.append((name, live, replay))
            print(f"{name}: replay correct_rate {replay.get('correct_rate')} over {replay.get('outputs')} outputs",
                  flush=True)
        print("| localizer | live correct | live outputs / scans | replay correct | replay outputs |")
    print("| --- | --- | --- | --- | --- |")
    for name, live, replay in rows:
        print(f"| {name} | {live.correct_rate} | {live.outputs} / {live.scans} | {replay.get('correct_rate')} | "
              f"{replay.get('outputs')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
