"""``rls_soak``: scan_sim and the localizers live for a while, their memory, CPU and pose latency measured.

Starts ``scan_sim`` (a looping tour of the scenario, :mod:`.tour`) and each localizer as ``make demo``
does (:mod:`...launch.demo`, DDS on loopback), samples every process's RSS and CPU every
``--sample-period`` seconds, records each pose's latency (receive time minus its stamp, the input's
stamp) and how many inputs each localizer handled, and writes ``soak.md``, ``soak.json`` and
``soak.png`` into ``--out``. docs/soak.md explains the figures and holds the measured ones.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...core.errors import LocalizationSuiteError
from ...core.settings import read_params_file
from ...core.sim.scenario_yaml import load_scenario
from ...launch.dds import use_loopback
from ...launch.demo import build_specs, default_domain_id, resolve_scenario
from ...launch.runner import NodeGroup, RunError, install_stop_handlers, run_nodes
from ...registry import PLUGINS, NodeSettings, config_dir
from .probes import ProcessSampler, StampMonitor
from .report import (
    GROWTH_RATIO,
    GROWTH_SLACK_MS,
    RSS_SLOPE_TARGET,
    InputCounts,
    ProcessSeries,
    expected_inputs,
    fmt_number,
    markdown_table,
    rss_slope_mb_per_h,
    summarise_latency,
    write_json,
    write_plot,
)
from .tour import write_tour

__all__ = ["main"]

DEFAULT_SCENARIO = "lab_camera"  # a scenario with a camera and its topological map: every localizer, ima_topo_localizer too
MONITOR = "rls_soak"  # this process (the monitor) in the tables
# Inputs stamped this close to the newest scan are not counted: they may still be in a node's hands.
_COUNT_MARGIN_S = 2.0
# The tour lasts this much longer than the measured minutes, for start-up (configure, index building).
_TOUR_MARGIN_S = 300.0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rls_soak",
        description=(
            "Soak benchmark: run scan_sim and the localizers live (DDS on loopback) for --minutes, sample each "
            "process's RSS and CPU, measure each localizer's pose latency and the inputs it dropped, and write "
            "soak.md (table), soak.json (figures and samples) and soak.png (plots) into --out."
        ),
        epilog=(
            "The run: every node starts; once every localizer has published a pose (or after --ready-timeout)\n"
            "the clock of --minutes starts; figures cover that span minus its first --warmup seconds.\n"
            "Scan rate on the wall clock = the scenario's laser rate x --speed x --scan-rate-factor\n"
            "(lab_camera: 5 Hz; --speed 10 gives 10x the nominal rate).\n"
            "Examples:\n"
            "  rls_soak --minutes 3                      every localizer, scan_sim at 4x\n"
            "  rls_soak --minutes 5 --speed 10           10x the nominal scan rate\n"
            "  rls_soak --minutes 30 --out results/soak30\n"
            "  rls_soak --minutes 0.5 --warmup 5 --localizers mcl_baseline"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--minutes", type=float, default=3.0,
                        help="how long to measure, counted from when every localizer has published a pose (3)")
    parser.add_argument("--speed", type=float, default=4.0,
                        help="scan_sim's real-time factor: the robot, its scans, odometry and images run this "
                             "many times faster (4)")
    parser.add_argument("--scan-rate-factor", type=float, default=1.0,
                        help="multiply the scenario's laser (and odometry) rate by this on top of --speed, "
                             "the robot's own speed unchanged; camera images keep their rate (1)")
    parser.add_argument("--localizers",
                        help="comma-separated localizers (default: every one the scenario can feed; "
                             f"available: {', '.join(PLUGINS)})")
    parser.add_argument("--scenario", default=DEFAULT_SCENARIO,
                        help=f"scenario YAML or a name in config/scenarios ({DEFAULT_SCENARIO}); its route is driven "
                             "out and back in a loop, without kidnappings")
    parser.add_argument("--out", default="results/soak", help="directory for soak.md, soak.json, soak.png, "
                                                              "nodes.log and the tour scenario (results/soak)")
    parser.add_argument("--warmup", type=float, default=60.0,
                        help="seconds at the start of the measured span left out of every figure (60)")
    parser.add_argument("--sample-period", type=float, default=10.0,
                        help="seconds between RSS/CPU samples and progress lines (10)")
    parser.add_argument("--ready-timeout", type=float, default=600.0,
                        help="seconds to wait for every localizer's first pose before measuring anyway (600)")
    parser.add_argument("--domain-id", type=int,
                        help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID or one of this run's own)")
    parser.add_argument("--show-node-output", action="store_true",
                        help="print the nodes' output too (it always goes to OUT/nodes.log)")
    return parser


def _choose_localizers(parser: argparse.ArgumentParser, value: str | None, has_camera: bool) -> list[str]:
    if value is None:
        return [name for name in PLUGINS if has_camera or not PLUGINS[name].uses_camera]
    names = [name.strip() for name in value.split(",") if name.strip()]
    unknown = [name for name in names if name not in PLUGINS]
    if unknown or not names:
        parser.error(f"--localizers: unknown {', '.join(unknown) or '(none given)'} (available: {', '.join(PLUGINS)})")
    blind = [name for name in names if PLUGINS[name].uses_camera and not has_camera]
    if blind:
        parser.error(f"--localizers: {', '.join(blind)} need(s) a camera and the scenario has none")
    return names


def _transform_tolerance(name: str) -> float:
    """The localizer's ``transform_tolerance`` [s]: its ``map -> odom`` stamps lie this far after the input's."""
    params = config_dir() / f"{name}.yaml"
    value = read_params_file(params, name).get("transform_tolerance") if params.is_file() else None
    return float(NodeSettings().transform_tolerance if value is None else value)


class Soak:
    """The run's clock and its probes: what the sampler thread does while the nodes run."""

    def __init__(self, args: argparse.Namespace, localizers: list[str], monitor: StampMonitor,
                 stop: threading.Event, say: Any) -> None:
        self.args = args
        self.localizers = localizers
        self.monitor = monitor
        self.stop = stop
        self.say = say
        self.t0 = math.nan  # time.monotonic() when the nodes started
        self.t0_wall = math.nan
        self.ready_s: float | None = None
        self.end_s: float | None = None
        self.finished = False
        self.not_ready: list[str] = []
        self.load: list[tuple[float, float, float, float]] = []  # (t, 1, 5, 15 min load averages)
        self.sampler: ProcessSampler | None = None
        self._thread: threading.Thread | None = None

    def on_started(self, group: NodeGroup) -> None:
        self.t0 = time.monotonic()
        self.t0_wall = time.time()
        pids = {process.name: process.pid for process in group.processes}
        pids[MONITOR] = os.getpid()
        self.sampler = ProcessSampler(pids)
        self._thread = threading.Thread(target=self._run, daemon=True, name="soak-sampler")
        self._thread.start()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=self.args.sample_period + 10.0)

    def _run(self) -> None:
        period = self.args.sample_period
        next_sample = period
        while not self.stop.wait(0.5):
            t = time.monotonic() - self.t0
            if self.ready_s is None:
                waiting = [name for name in self.localizers if not self.monitor.poses[name][0]]
                if not waiting or t >= self.args.ready_timeout:
                    self.ready_s, self.not_ready = t, waiting
                    self.end_s = t + 60.0 * self.args.minutes
                    self.say(f"measuring from t = {t:.0f} s for {self.args.minutes:g} min (figures after "
                             f"{self.args.warmup:g} s of warm-up)"
                             + (f"; no pose yet from {', '.join(waiting)}" if waiting else ""))
            if t >= next_sample:
                next_sample += period
                self._sample(t)
            if self.end_s is not None and t >= self.end_s:
                self._sample(t)
                self.finished = True
                self.stop.set()

    def _sample(self, t: float) -> None:
        assert self.sampler is not None
        self.sampler.sample(t)
        self.load.append((t, *os.getloadavg()))
        self.say(self._progress_line(t))

    def _progress_line(self, t: float) -> str:
        if self.ready_s is None:
            phase = "starting"
        elif t < self.ready_s + self.args.warmup:
            phase = "warm-up"
        else:
            phase = f"measuring {_clock(t - self.ready_s)}/{_clock(60.0 * self.args.minutes)}"
        parts = [f"{_clock(t)} {phase}", f"load {self.load[-1][1]:.1f}"]
        assert self.sampler is not None
        now = time.time()
        for name, series in self.sampler.series.items():
            if not series.t or series.t[-1] != t:
                parts.append(f"{name} gone")
                continue
            text = f"{name} {series.rss_mb[-1]:.0f} MB {series.cpu_percent[-1]:.0f}%"
            if name in self.monitor.poses:
                received, stamps = self.monitor.poses[name]
                n = len(received)
                recent = [r - s for r, s in zip(received[-200:], stamps[-200:], strict=False)
                          if r >= now - self.args.sample_period]
                text += f" {n} poses"
                if recent:
                    text += f" p95 {np.percentile(recent, 95) * 1e3:.0f} ms"
            parts.append(text)
        return " | ".join(parts)

    # -- the figures --------------------------------------------------------------------------------
    def window(self) -> tuple[float, float]:
        """The measured span [s since start]: after the warm-up, until the end (or the last sample)."""
        last = max((s.t[-1] for s in self.series if s.t), default=0.0)
        ready = self.ready_s if self.ready_s is not None else last
        end = min(self.end_s, last) if self.end_s is not None else last
        return min(ready + self.args.warmup, end), end

    @property
    def series(self) -> list[ProcessSeries]:
        return list(self.sampler.series.values()) if self.sampler is not None else []

    def steps(self, stamps: Any, laser_period: float) -> NDArray[np.int64]:
        """Simulator step index of each stamp: scan_sim stamps step k at epoch + k x period / speed."""
        assert self.monitor.epoch is not None
        step_s = laser_period / self.args.speed  # wall-clock seconds between simulator steps
        return np.rint((np.asarray(stamps, dtype=np.float64) - self.monitor.epoch) / step_s).astype(np.int64)

    def input_counts(self, name: str, laser_period: float, camera_rate: float | None,
                     window: tuple[float, float]) -> dict[str, Any] | None:
        """Inputs stamped in the window: published (scan_sim's schedule) and processed (the node's ``map -> odom``)."""
        epoch, scans = self.monitor.epoch, self.monitor.scans[1]
        if epoch is None or not scans or not self.monitor.has_tf:
            return None
        start = self.t0_wall + window[0]
        end = min(self.t0_wall + window[1], scans[-1]) - _COUNT_MARGIN_S
        first, last = (int(k) for k in self.steps([start, end], laser_period))
        handled = self.steps(np.asarray(self.monitor.tf_stamps[name]) - _transform_tolerance(name), laser_period)
        counts = InputCounts(
            kind="image" if camera_rate is not None else "scan",
            published=expected_inputs(first, last, camera_rate_hz=camera_rate, laser_period_s=laser_period),
            processed=int(np.count_nonzero((handled >= first) & (handled <= last))),
        )
        return {"kind": counts.kind, "published": counts.published, "processed": counts.processed,
                "dropped": counts.dropped, "stamps_from_s": start - self.t0_wall, "stamps_to_s": end - self.t0_wall}

    def achieved_scan_rate(self, laser_period: float, start_wall: float, end_wall: float) -> float:
        """Simulator steps (scans) scan_sim published per wall-clock second in the window: below the
        asked rate when it cannot keep up (it then skips timer ticks and its stamps fall behind)."""
        received = np.asarray(self.monitor.scans[0], dtype=np.float64)
        inside = (received >= start_wall) & (received <= end_wall)
        if self.monitor.epoch is None or np.count_nonzero(inside) < 2:
            return math.nan
        steps = self.steps(np.asarray(self.monitor.scans[1])[inside], laser_period)
        return float((steps.max() - steps.min()) / (received[inside].max() - received[inside].min()))

    def scan_arrivals(self, name: str, laser_period: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(pose receive times, receive time of the scan of the same step) for the poses whose scan was seen."""
        received, stamps = (np.asarray(v, dtype=np.float64) for v in self.monitor.poses[name])
        scan_received = np.asarray(self.monitor.scans[0], dtype=np.float64)
        if self.monitor.epoch is None or not scan_received.size or not received.size:
            return np.zeros(0), np.zeros(0)
        scan_steps = self.steps(self.monitor.scans[1], laser_period)
        order = np.argsort(scan_steps, kind="stable")
        scan_steps, scan_received = scan_steps[order], scan_received[order]
        pose_steps = self.steps(stamps, laser_period)
        at = np.clip(np.searchsorted(scan_steps, pose_steps), 0, scan_steps.size - 1)
        seen = scan_steps[at] == pose_steps
        return received[seen], scan_received[at[seen]]


def _clock(seconds: float) -> str:
    seconds = max(int(seconds), 0)
    return f"{seconds // 60}:{seconds % 60:02d}"


def _latency_dict(summary: Any) -> dict[str, Any]:
    return {**summary.__dict__, "grows": summary.grows}


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    for option in ("minutes", "speed", "scan_rate_factor", "sample_period"):
        if not getattr(args, option) > 0.0:
            parser.error(f"--{option.replace('_', '-')} must be > 0, got {getattr(args, option)!r}")
    if not 0.0 <= args.warmup < 60.0 * args.minutes:
        parser.error(f"--warmup must be >= 0 and shorter than --minutes ({60.0 * args.minutes:g} s), got {args.warmup!r}")
    try:
        scenario_path = resolve_scenario(args.scenario)
        scenario = load_scenario(scenario_path)
    except (RunError, LocalizationSuiteError) as exc:
        print(f"rls_soak: {exc}", file=sys.stderr)
        return 2
    localizers = _choose_localizers(parser, args.localizers, scenario.camera is not None)
    laser_hz = scenario.laser.rate_hz * args.scan_rate_factor
    if args.speed > 100.0 or laser_hz > 1000.0:
        parser.error("scan_sim takes --speed up to 100 and a laser rate up to 1000 Hz")
    camera_rate = scenario.camera.rate_hz if scenario.camera is not None else None

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    domain_id = args.domain_id if args.domain_id is not None else default_domain_id()
    lock = threading.Lock()

    def say(text: str) -> None:
        with lock:
            print(f"[soak] {text}", flush=True)

    sim_seconds = (60.0 * args.minutes + args.warmup + _TOUR_MARGIN_S) * args.speed
    say(f"building the tour of {scenario_path.name} for {sim_seconds:.0f} s simulated ...")
    try:
        tour = write_tour(scenario_path, out / "scenario_tour.yaml", sim_seconds)
    except LocalizationSuiteError as exc:
        print(f"rls_soak: {exc}", file=sys.stderr)
        return 2
    map_yaml = Path(tour.map_path) if tour.map_path else config_dir() / "maps" / "office.yaml"
    specs = build_specs(out / "scenario_tour.yaml", map_yaml, localizers, args.speed)
    specs[0].parameters.update({"exit_at_end": False, "rate_hz": float(laser_hz)})
    for spec in specs[1:]:
        spec.remaps["/tf"] = f"/{spec.name}/tf"  # each one's map -> odom apart: one per input it handled
    say(f"scan_sim at {args.speed:g}x ({laser_hz * args.speed:g} scans/s on the wall clock, nominal "
        f"{scenario.laser.rate_hz:g} Hz), localizers: {', '.join(localizers)}, ROS_DOMAIN_ID {domain_id}, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")

    use_loopback(domain_id)  # the monitor in this process talks DDS on loopback too
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from ...ros.stopping import stopping

    log_file = (out / "nodes.log").open("w")

    def node_output(name: str, line: str) -> None:
        with lock:
            log_file.write(f"[{name}] {line}\n")
            if args.show_node_output:
                print(f"[{name}] {line}", flush=True)

    stop = threading.Event()
    install_stop_handlers(stop)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    monitor = StampMonitor(localizers)
    monitor.start()
    soak = Soak(args, localizers, monitor, stop, say)
    load_start = os.getloadavg()
    try:
        try:
            result = run_nodes(specs, domain_id=domain_id, stop=stop, output=node_output, log=say,
                               on_started=soak.on_started, transition_timeout=args.ready_timeout)
        except RunError as exc:
            print(f"rls_soak: {exc}", file=sys.stderr)
            return 2
        finally:
            stop.set()
            soak.join()
            monitor.stop()
            log_file.close()
        return _write_results(args, out, soak, monitor, localizers, scenario, tour, laser_hz, camera_rate,
                              load_start, result, say)
    finally:
        # The middleware's teardown last, once every result is on disk: it can hang (ros/stopping.py).
        with stopping():
            monitor.close()
            rclpy.try_shutdown()


def _write_results(args: argparse.Namespace, out: Path, soak: Soak, monitor: StampMonitor, localizers: list[str],
                   scenario: Any, tour: Any, laser_hz: float, camera_rate: float | None,
                   load_start: tuple[float, float, float], result: Any, say: Callable[[str], None]) -> int:
    """soak.md, soak.json, stamps.npz and soak.png, the table on stdout; 1 if the run did not reach its end."""
    summary = _summary(args, soak, localizers, scenario, tour, laser_hz, camera_rate, load_start, result)
    (out / "soak.md").write_text(_markdown(summary))
    write_json(out / "soak.json", summary, soak.series)
    monitor.save(out / "stamps.npz")
    window = soak.window()
    write_plot(out / "soak.png", soak.series, dict(monitor.poses), soak.t0_wall, window,
               f"rls_soak {summary['date']}: {summary['settings']['scenario']} at {args.speed:g}x, "
               f"{summary['rates']['scan_hz_wall']:g} scans/s, load {summary['machine']['load_average_mean']:.1f} "
               f"on {os.cpu_count()} CPUs")
    for line in markdown_table(summary).splitlines():
        say(line)
    say(f"wrote {out / 'soak.md'}, {out / 'soak.json'}, {out / 'soak.png'}")
    failed = {name: code for name, code in result.exit_codes.items() if code not in (0, -2)}
    if not soak.finished or failed:
        say("the run did not reach its end" + (f"; nodes that failed: {failed}" if failed else ""))
        return 1
    return 0


def _summary(args: argparse.Namespace, soak: Soak, localizers: list[str], scenario: Any, tour: Any, laser_hz: float,
             camera_rate: float | None, load_start: tuple[float, float, float], result: Any) -> dict[str, Any]:
    window = soak.window()
    processes: dict[str, Any] = {}
    for series in soak.series:
        t, rss, cpu = series.window(*window)
        processes[series.name] = {
            "pid": series.pid,
            "samples_in_window": int(t.size),
            "rss_start_mb": float(rss[0]) if rss.size else math.nan,
            "rss_end_mb": float(rss[-1]) if rss.size else math.nan,
            "rss_max_mb": float(max(series.rss_mb)) if series.rss_mb else math.nan,
            "rss_slope_mb_per_h": rss_slope_mb_per_h(t, rss),
            "cpu_percent_mean": float(np.nanmean(cpu)) if cpu.size else math.nan,
        }
    start_wall, end_wall = soak.t0_wall + window[0], soak.t0_wall + window[1]
    laser_period = 1.0 / laser_hz
    per_localizer = {}
    for name in localizers:
        received, stamps = soak.monitor.poses[name]
        latency = summarise_latency(received, stamps, start_wall, end_wall)
        after_scan = summarise_latency(*soak.scan_arrivals(name, laser_period), start_wall, end_wall)
        per_localizer[name] = {
            "poses": latency.count,
            "latency": _latency_dict(latency),
            "after_scan": _latency_dict(after_scan),
            "inputs": soak.input_counts(name, laser_period, camera_rate if PLUGINS[name].uses_camera else None, window),
        }
    scan_age = summarise_latency(*soak.monitor.scans, start_wall, end_wall)
    achieved = soak.achieved_scan_rate(laser_period, start_wall, end_wall)
    loads = [row[1] for row in soak.load if window[0] <= row[0] <= window[1]] or [row[1] for row in soak.load]
    sim_end_wall = soak.t0_wall + tour.end_time / args.speed
    return {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "command": " ".join(["rls_soak", *sys.argv[1:]]),
        "settings": {
            "minutes": args.minutes, "speed": args.speed, "scan_rate_factor": args.scan_rate_factor,
            "scenario": scenario.name, "tour_s": tour.end_time, "localizers": localizers,
            "warmup_s": args.warmup, "sample_period_s": args.sample_period,
        },
        "rates": {"laser_hz_nominal": scenario.laser.rate_hz, "scan_hz_wall": laser_hz * args.speed,
                  "scan_hz_achieved": achieved,
                  "camera_hz_wall": None if camera_rate is None else camera_rate * args.speed},
        "machine": {
            "cpus": os.cpu_count(), "load_average_start": list(load_start), "load_average_end": list(os.getloadavg()),
            "load_average_mean": float(np.mean(loads)) if loads else math.nan,
        },
        "window": {"ready_s": soak.ready_s, "start_s": window[0], "end_s": window[1],
                   "minutes": (window[1] - window[0]) / 60.0, "not_ready": soak.not_ready,
                   "tour_ended_inside": bool(sim_end_wall < soak.t0_wall + window[1])},
        "processes": processes,
        "localizers": per_localizer,
        "scan_age": {"scan_sim": _latency_dict(scan_age)},
        "run": {"finished": soak.finished, "reason": result.reason, "exit_codes": result.exit_codes},
    }


def _markdown(summary: dict[str, Any]) -> str:
    s, m, w = summary["settings"], summary["machine"], summary["window"]
    slow = [name for name, p in summary["processes"].items()
            if name != MONITOR and math.isfinite(p["rss_slope_mb_per_h"]) and p["rss_slope_mb_per_h"] > RSS_SLOPE_TARGET]
    growing = [name for name, loc in summary["localizers"].items() if loc["latency"]["grows"]]
    growing_after = [name for name, loc in summary["localizers"].items() if loc["after_scan"]["grows"]]
    lines = [
        f"# Soak {summary['date']}",
        "",
        f"`{summary['command']}`",
        "",
        f"Scenario {s['scenario']} as a tour ({s['tour_s']:.0f} s simulated), scan_sim at {s['speed']:g}x: "
        f"{summary['rates']['scan_hz_wall']:g} scans/s asked on the wall clock, "
        f"{fmt_number(summary['rates']['scan_hz_achieved'], 1)} achieved (nominal {summary['rates']['laser_hz_nominal']:g} Hz"
        + (f", images {summary['rates']['camera_hz_wall']:g}/s" if summary['rates']['camera_hz_wall'] else "") + "). "
        f"Measured {w['minutes']:.1f} min after {s['warmup_s']:g} s of warm-up (from t = {w['start_s']:.0f} s to "
        f"{w['end_s']:.0f} s; every localizer had published by t = {fmt_number(w['ready_s'])} s). "
        f"{m['cpus']} CPUs, load average {m['load_average_start'][0]:.1f} at the start, "
        f"{m['load_average_mean']:.1f} on average over the window, {m['load_average_end'][0]:.1f} at the end.",
        "",
        markdown_table(summary),
        "",
        "Latency: receive time here minus the pose's stamp (its input's stamp); *after the scan*: receive time of "
        "the pose minus that of its scan (the localizer's queueing and work, without scan_sim's lag). scan_sim's "
        "latency columns: the age of its scans when they reached this monitor (scan_sim's lag behind its own "
        f"stamps, transport, the monitor's delay). {MONITOR} is this monitor (it keeps every stamp: it grows by design).",
        f"RSS slope above {RSS_SLOPE_TARGET:g} MB/h: {', '.join(slow) or 'none'}"
        + (" (a window under 30 min extrapolates a few MB of noise: judge slopes on the 30-min run)"
           if w["minutes"] < 30 else "") + ".",
        f"p95 growing from the first to the last third (more than x{GROWTH_RATIO:g} and {GROWTH_SLACK_MS:g} ms): "
        f"latency {', '.join(growing) or 'none'}; after the scan {', '.join(growing_after) or 'none'}.",
    ]
    if w["not_ready"]:
        lines.append(f"No pose before measuring began: {', '.join(w['not_ready'])}.")
    if w["tour_ended_inside"]:
        lines.append("The tour ended inside the window: the robot stood still afterwards.")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
