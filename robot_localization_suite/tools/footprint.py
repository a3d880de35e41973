"""``rls_footprint`` (``make footprint``): memory, CPU and start-up time of each localizer alone and all composed.

For each localizer alone (one process) and for all of them in one container (``nodes/container.py``):

* start-up to ready with a cold cache (an empty ``RLS_CACHE_DIR``: every numba kernel compiled, PIL's
  learning and IR's index built), then again with the cache that run left (warm): seconds from
  starting the process(es) to the answer of the last ``activate`` (configure with the office map from
  ``map_yaml``, as ``rls_run`` brings them up);
* idle RSS (and USS, the memory that is the process's own) after ``configure``, on the warm run;
* the bag (default ``bags/office_kidnap``, its first ``--seconds``) played over DDS at real time,
  ``/scan`` best effort and ``/odom`` reliable, every localizer started from the first ground-truth pose
  (tracking): RSS at its peak and CPU [% of one core] over the replay after ``--warmup`` seconds
  (PIL and IR load or build their scanner's precomputation on the first scan), and CPU per scan.

``mcl_baseline`` runs with 2,000 particles (``min_particles`` = ``max_particles``) and 60 beams, the issue's
reference point; the others with their packaged parameters. Every figure comes with the 1-minute load
average before and after it: the machine is shared. Nothing here is a test; docs/footprint.md has the
figures and the command.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ..launch.dds import loopback_environment, use_loopback
from ..launch.runner import NodeGroup, NodeSpec

__all__ = ["Footprint", "measure", "main"]

_CONFIGURED = re.compile(r"\]: configured in ([0-9.]+) s")

#: The issue's reference setting of the MCL baseline: a fixed cloud of 2,000 particles, 60 beams.
MCL_REFERENCE = {"min_particles": 2000, "max_particles": 2000, "max_beams": 60}


@dataclass
class Footprint:
    """What one configuration (one localizer alone, or several in one container) costs."""

    configuration: str
    nodes: list[str]
    cold_ready_s: float | None  # start of the process(es) -> every node up, configured and active, empty cache [s]
    warm_ready_s: float | None  # the same with the cache of the cold run [s]
    warm_ready_dds_s: float | None  # start -> last activate answered to a lifecycle manager over DDS, warm [s]
    idle_rss_mb: float | None  # after configure, warm run [MB]
    idle_uss_mb: float | None  # its own pages (not shared with other processes) [MB]
    replay_peak_rss_mb: float | None  # while the bag plays [MB]
    cpu_percent: float | None  # mean over the replay after the warm-up [% of one core]
    cpu_ms_per_scan: float | None  # CPU time over the replay after the warm-up / scans published then [ms]
    first_pose_s: dict[str, float | None]  # replay start -> first ~/pose of each node, warm [s]
    cold_first_pose_s: dict[str, float | None]  # the same on the cold run (kernels compiled at first use) [s]
    compiled_while_replaying: int  # kernels compiled during the warm replay (0 when the cache was warm)
    load: list[float]  # 1-minute load average before the cold run, before the replay, after it


def _specs(names: Sequence[str], map_yaml: Path, start: Any, container: str | None,
           config: Path) -> list[NodeSpec]:
    specs = []
    for name in names:
        parameters: dict[str, Any] = {"map_yaml": str(map_yaml), "set_initial_pose": True,
                                      "initial_pose.x": float(start[0]), "initial_pose.y": float(start[1]),
                                      "initial_pose.yaw": float(start[2])}
        if name == "mcl_baseline":
            parameters.update(MCL_REFERENCE)
        params_file = config / f"{name}.yaml"
        specs.append(NodeSpec(name, name, params_file=str(params_file) if params_file.is_file() else None,
                              parameters=parameters, container=container))
    return specs


class _Run:
    """The nodes of one configuration started, brought up, optionally fed the bag, then stopped."""

    def __init__(self, specs: list[NodeSpec], cache_dir: Path, domain_id: int, log: Any) -> None:
        self.specs, self.names = specs, [spec.name for spec in specs]
        self.lines: list[str] = []
        self.timed: list[tuple[float, str]] = []  # (monotonic time received, line) of the nodes' output

        def output(name: str, line: str) -> None:
            self.lines.append(f"[{name}] {line}")
            self.timed.append((time.monotonic(), line))

        self.group = NodeGroup(specs, domain_id=domain_id, output=output, log=self.lines.append)
        env = loopback_environment(domain_id)
        env.pop("NUMBA_CACHE_DIR", None)  # this process set it from its own cache directory
        env["RLS_CACHE_DIR"] = str(cache_dir)
        env["PYTHONUNBUFFERED"] = "1"
        self.group.environment = lambda: env  # type: ignore[method-assign]
        self.domain_id = domain_id
        self.log = log
        self.node_log: Path | None = None

    def _node_side_ready(self, started: float) -> float:
        """Start -> the last node constructed, plus every configure and activation as the nodes time them [s].

        Leaves out how long the lifecycle manager (another process here) took to discover the nodes over
        DDS: a manager in the same container would not wait for that.
        """
        up = [t - started for t, line in self.timed if "unconfigured: waiting for the configure transition" in line]
        configure = [float(m.group(1)) for _, line in self.timed if (m := _CONFIGURED.search(line))]
        active = [t for t, line in self.timed if line.endswith("]: active")]
        if len(up) < len(self.names) or len(configure) < len(self.names) or len(active) < len(self.names):
            raise RuntimeError("a node did not report its start-up:\n" + "\n".join(self.lines[-40:]))
        return max(up) + sum(configure)

    def bring_up(self, timeout_s: float) -> tuple[float, float, float, float]:
        """Start, configure, idle 2 s, activate: (seconds to ready on the nodes' side, over DDS, idle RSS [MB],
        idle USS [MB])."""
        import psutil

        from ..launch.lifecycle import LifecycleManager

        manager = LifecycleManager(self.names, domain_id=self.domain_id, log=self.lines.append)
        try:
            started = time.monotonic()
            self.group.start()
            for name in self.names:
                if not manager.change_state(name, "configure", timeout_s):
                    raise RuntimeError(f"{name} did not configure:\n" + "\n".join(self.lines[-40:]))
            configured = time.monotonic() - started
            time.sleep(2.0)
            rss = uss = 0.0
            for process in self.group.processes:
                info = psutil.Process(process.pid).memory_full_info()
                rss, uss = rss + info.rss / 2**20, uss + info.uss / 2**20
            activating = time.monotonic()
            for name in self.names:
                if not manager.change_state(name, "activate", timeout_s):
                    raise RuntimeError(f"{name} did not activate:\n" + "\n".join(self.lines[-40:]))
            over_dds = configured + time.monotonic() - activating
            time.sleep(0.5)  # the nodes' "active" lines
            return self._node_side_ready(started), over_dds, rss, uss
        finally:
            manager.close()

    def replay(self, messages: list[Any], seconds: float, warmup_s: float, until_posed: bool = False,
               until_posed_after_s: float = 0.0) -> dict[str, Any]:
        """Play ``messages`` at real time for ``seconds`` (with ``until_posed``: only until every node has
        published a pose and ``until_posed_after_s`` have been played); RSS and CPU of the node processes."""
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import LaserScan

        from ..ros.context_node import ContextNode
        from ..ros.qos import POSE_QOS, RELIABLE_QOS, SENSOR_QOS
        from .soak.probes import ProcessSampler

        player = ContextNode("rls_footprint_player")
        odom_pub = player.node.create_publisher(Odometry, "/odom", RELIABLE_QOS)
        scan_pub = player.node.create_publisher(LaserScan, "/scan", SENSOR_QOS)
        first_pose: dict[str, float | None] = {name: None for name in self.names}
        began = [0.0]

        def on_pose(name: str) -> Any:
            def record(_msg: Any) -> None:
                if first_pose[name] is None:
                    first_pose[name] = time.monotonic() - began[0]
            return record

        for name in self.names:
            player.node.create_subscription(PoseWithCovarianceStamped, f"/{name}/pose", on_pose(name), POSE_QOS)
        spinning = threading.Event()

        def spin() -> None:
            while not spinning.is_set():
                player.executor.spin_once(timeout_sec=0.05)

        spinner = threading.Thread(target=spin, daemon=True, name="footprint-player")
        player.spin_until(lambda: all(p.get_subscription_count() >= len(self.names) for p in (odom_pub, scan_pub)),
                          60.0)
        player.spin_for(0.5)
        sampler = ProcessSampler({process.name: process.pid for process in self.group.processes})
        spinner.start()
        t0 = messages[0].stamp_ns
        began[0] = time.monotonic()
        scans_after_warmup, cpu_start, last_second = 0, None, 0
        try:
            for message in messages:
                due = (message.stamp_ns - t0) * 1e-9
                posed = all(v is not None for v in first_pose.values())
                if due > seconds or (until_posed and posed and due > until_posed_after_s):
                    seconds = min(seconds, due)
                    break
                delay = began[0] + due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if message.topic == "/odom":
                    odom_pub.publish(message.msg)
                    continue
                if message.topic != "/scan":
                    continue
                if cpu_start is None and due >= warmup_s:
                    sampler.sample(due)
                    cpu_start = due
                elif int(due) > last_second:  # once a second: the RSS peak, the CPU by interval
                    sampler.sample(due)
                last_second = int(due)
                scan_pub.publish(message.msg)
                scans_after_warmup += int(cpu_start is not None)
            sampler.sample(seconds)
        finally:
            spinning.set()
            spinner.join(timeout=5.0)
            player.close()
        if cpu_start is None and until_posed:
            return {"first_pose_s": first_pose}
        if cpu_start is None:
            raise ValueError(f"the warm-up ({warmup_s:g} s) is not shorter than the replay ({seconds:g} s)")
        rss_peak = cpu_s = 0.0
        for series in sampler.series.values():
            rss_peak += max(series.rss_mb)
            # CPU over [warm-up, end]: the samples after the warm-up one, weighted by their interval.
            t = [cpu_start, *[s for s in series.t if s > cpu_start]]
            percents = [p for s, p in zip(series.t, series.cpu_percent, strict=True) if s > cpu_start]
            cpu_s += sum((b - a) * p / 100.0 for a, b, p in zip(t, t[1:], percents, strict=False))
        window = seconds - cpu_start
        return {"replay_peak_rss_mb": rss_peak, "cpu_percent": 100.0 * cpu_s / window,
                "cpu_ms_per_scan": 1000.0 * cpu_s / max(scans_after_warmup, 1), "first_pose_s": first_pose}

    def stop(self) -> None:
        _codes, escalated = self.group.stop()
        if escalated:
            self.log(f"stopping needed {escalated}")
        if self.node_log is not None:
            with open(self.node_log, "a") as stream:
                stream.write("\n".join(self.lines) + "\n")


def measure(configuration: str, names: Sequence[str], *, container: str | None, bag: Path, map_yaml: Path,
            seconds: float, warmup_s: float, cold: bool, domain_id: int, log: Any = print,
            timeout_s: float = 900.0, cold_replay_s: float = 150.0, node_log: Path | None = None) -> Footprint:
    """One configuration: a cold start (if ``cold``), then a warm start with idle RSS and the replay."""
    from ..registry import config_dir
    from ..ros.bag import read_bag
    from ..ros.conversions import odometry_from_msg

    messages = list(read_bag(bag, ["/odom", "/scan", "/ground_truth"]))
    start = odometry_from_msg(next(m.msg for m in messages if m.topic == "/ground_truth"))[1]
    feed = [m for m in messages if m.topic in ("/odom", "/scan")]
    specs = _specs(names, map_yaml, start, container, config_dir())
    from ..core.cache import default_cache_dir

    # Cold: an empty cache of the run's own. Without the cold run, the user's cache (warm if used before).
    cache_dir = Path(tempfile.mkdtemp(prefix="rls_footprint_cache_")) if cold else default_cache_dir()
    load = [os.getloadavg()[0]]
    cold_ready: float | None = None
    cold_first_pose: dict[str, float | None] = {name: None for name in names}
    try:
        if cold:
            run = _Run(specs, cache_dir, domain_id, log)
            run.node_log = node_log
            try:
                cold_ready = run.bring_up(timeout_s)[0]
                # What is compiled or built at the first scan (IAL's kernels, PIL's and IR's precomputation),
                # until every node has a pose and the warm run's stretch has been played: the warm run then
                # finds all of it in the cache (kernels compile at their first use, some scans in).
                cold_first_pose = run.replay(feed, cold_replay_s, min(warmup_s, 1.0), until_posed=True,
                                             until_posed_after_s=seconds)["first_pose_s"]
            finally:
                run.stop()
            log(f"{configuration}: cold start-up to ready {cold_ready:.2f} s, first poses {cold_first_pose}")
        run = _Run(specs, cache_dir, domain_id, log)
        run.node_log = node_log
        try:
            warm_ready, warm_ready_dds, idle_rss, idle_uss = run.bring_up(timeout_s)
            log(f"{configuration}: warm start-up to ready {warm_ready:.2f} s ({warm_ready_dds:.2f} s over DDS), "
                f"idle RSS {idle_rss:.0f} MB (USS {idle_uss:.0f} MB)")
            load.append(os.getloadavg()[0])
            replay_start = len(run.timed)
            replay = run.replay(feed, seconds, warmup_s)
            load.append(os.getloadavg()[0])
            compiled = [line for _, line in run.timed[replay_start:] if "]: compiling " in line]
            if compiled:
                log(f"{configuration}: {len(compiled)} kernel(s) compiled during the warm replay: its CPU figures "
                    f"include compilation")
        finally:
            run.stop()
    finally:
        if cold:
            shutil.rmtree(cache_dir, ignore_errors=True)
    result = Footprint(configuration, list(names), cold_ready, warm_ready, warm_ready_dds, idle_rss, idle_uss, load=load,
                       cold_first_pose_s=cold_first_pose, compiled_while_replaying=len(compiled), **replay)
    log(f"{configuration}: replay peak RSS {result.replay_peak_rss_mb:.0f} MB, CPU {result.cpu_percent:.1f} % "
        f"({result.cpu_ms_per_scan:.1f} ms per scan), load {', '.join(f'{x:.1f}' for x in load)}")
    return result


def table(results: Sequence[Footprint]) -> str:
    """The markdown table of docs/footprint.md."""
    def number(value: float | None, digits: int = 0) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    lines = ["| configuration | idle RSS after configure [MB] | idle USS [MB] | peak RSS replaying [MB] | "
             "CPU replaying [% of one core] | CPU per scan [ms] | ready, cold cache [s] | ready, warm cache [s] | "
             "ready over DDS, warm [s] | first pose after the first scan, cold / warm [s] | "
             "load (1 min) before / replay / after |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in results:
        lines.append(f"| {r.configuration} | {number(r.idle_rss_mb)} | {number(r.idle_uss_mb)} | "
                     f"{number(r.replay_peak_rss_mb)} | {number(r.cpu_percent, 1)} | {number(r.cpu_ms_per_scan, 1)} | "
                     f"{number(r.cold_ready_s, 1)} | {number(r.warm_ready_s, 2)} | {number(r.warm_ready_dds_s, 2)} | "
                     f"{_slowest(r.cold_first_pose_s)} / {_slowest(r.first_pose_s)} | "
                     f"{' / '.join(f'{x:.1f}' for x in r.load)} |")
    return "\n".join(lines)


def _slowest(first_poses: dict[str, float | None]) -> str:
    """The last node's first pose [s]; "none" when one never published a pose."""
    if not first_poses or any(value is None for value in first_poses.values()):
        return "none"
    return f"{max(value for value in first_poses.values() if value is not None):.1f}"


def main(argv: Sequence[str] | None = None) -> int:
    from ..registry import PLUGINS, config_dir

    laser = [name for name, plugin in PLUGINS.items() if not plugin.uses_camera]
    parser = argparse.ArgumentParser(prog="rls_footprint", description=__doc__.split("\n\n")[0])
    parser.add_argument("--localizers", nargs="+", default=laser, choices=laser, help="default: every laser localizer")
    parser.add_argument("--bag", default=str(config_dir().parent / "bags" / "office_kidnap"), help="bag to replay")
    parser.add_argument("--map", default=str(config_dir() / "maps" / "office.yaml"), help="map_yaml of the nodes")
    parser.add_argument("--seconds", type=float, default=24.0,
                        help="seconds of the bag played (24: office_kidnap before its kidnapping)")
    parser.add_argument("--warmup", type=float, default=4.0, help="seconds of the replay left out of the CPU figures")
    parser.add_argument("--no-cold", action="store_true",
                        help="skip the cold-cache start-ups: the warm runs then use $RLS_CACHE_DIR (warm if used before)")
    parser.add_argument("--no-alone", action="store_true", help="only the composed configuration")
    parser.add_argument("--no-composed", action="store_true", help="only each localizer alone")
    parser.add_argument("--out", default="results/footprint",
                        help="directory for footprint.md, footprint.json and nodes.log (every node's output)")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: 101 + pid %% 132)")
    options = parser.parse_args(argv)
    domain_id = options.domain_id if options.domain_id is not None else 101 + os.getpid() % 132
    use_loopback(domain_id)
    out = Path(options.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "nodes.log").write_text("")
    common = {"node_log": out / "nodes.log", "bag": Path(options.bag), "map_yaml": Path(options.map), "seconds": options.seconds,
              "warmup_s": options.warmup, "cold": not options.no_cold, "domain_id": domain_id}
    results = []
    if not options.no_alone:
        for name in options.localizers:
            results.append(measure(name, [name], container=None, **common))
    if not options.no_composed and len(options.localizers) > 1:
        results.append(measure(f"{len(options.localizers)} composed ({', '.join(options.localizers)})",
                               options.localizers, container="localizers", **common))
    text = table(results)
    (out / "footprint.md").write_text(text + "\n")
    (out / "footprint.json").write_text(json.dumps([asdict(r) for r in results], indent=1))
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
