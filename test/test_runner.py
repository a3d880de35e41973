"""The runner (launch/runner.py, ``rls_run``) and the demo (launch/demo.py) with real nodes over DDS on loopback."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import yaml

from robot_localization_suite.launch.demo_monitor import DemoMonitor
from robot_localization_suite.launch.runner import (
    NodeSpec,
    RunError,
    format_parameter,
    load_runfile,
)

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "config" / "scenarios" / "office_kidnap.yaml"


class Output:
    """Collects a process's output lines in a thread; wait_for() blocks until a pattern shows up."""

    def __init__(self, process: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._changed = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(process,), daemon=True)
        self._thread.start()

    def _read(self, process: subprocess.Popen) -> None:
        for line in process.stdout:
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self._changed.notify_all()

    def text(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, pattern: str, timeout: float) -> re.Match:
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                match = re.search(pattern, self.text(), re.MULTILINE)
                if match:
                    return match
                remaining = deadline - time.monotonic()
                assert remaining > 0, f"no {pattern!r} within {timeout} s in:\n{self.text()}"
                self._changed.wait(remaining)

    def close(self, timeout: float = 5.0) -> None:
        self._thread.join(timeout)


def start_rls_run(runfile: Path, *extra: str) -> tuple[subprocess.Popen, Output]:
    process = subprocess.Popen(
        [sys.executable, "-m", "robot_localization_suite.launch.runner", str(runfile), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    return process, Output(process)


def node_pids(output: Output) -> dict[str, int]:
    return {name: int(pid) for name, pid in re.findall(r"started (\w+) \(pid (\d+)\)", output.text())}


def write_runfile(tmp_path: Path, nodes: list[dict]) -> Path:
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump({"nodes": nodes}))
    return path


def sim_node(name: str) -> dict:
    """A renamed scan_sim: config/scan_sim.yaml is keyed "scan_sim:", so its parameters come with -p only."""
    return {
        "executable": "scan_sim",
        "name": name,
        "parameters": {"scenario": str(SCENARIO)},
        # Each simulator in its own namespace of topics, as two robots would be.
        "remaps": {topic: f"/{name}/{topic}" for topic in ("scan", "odom", "ground_truth", "map")},
    }


def test_two_nodes_start_and_stop_cleanly_on_sigint(tmp_path: Path) -> None:
    nodes = [sim_node("sim_a"), sim_node("sim_b")]
    process, output = start_rls_run(write_runfile(tmp_path, nodes))
    try:
        # Both are up and talking: each logs its start, prefixed with its own name.
        output.wait_for(r"^\[sim_a\] .*simulating 'office_kidnap'", 60)
        output.wait_for(r"^\[sim_b\] .*simulating 'office_kidnap'", 60)
        pids = node_pids(output)
        assert set(pids) == {"sim_a", "sim_b"}
        assert all(psutil.pid_exists(pid) for pid in pids.values())
        process.send_signal(signal.SIGINT)  # what Ctrl-C does
        code = process.wait(timeout=30)
        output.close()
        assert code == 0, output.text()
    finally:
        if process.poll() is None:
            process.kill()
    output.close()
    text = output.text()
    assert re.search(r"sim_a stopped \((exit code 0|killed by SIGINT)\)", text), text
    assert re.search(r"sim_b stopped \((exit code 0|killed by SIGINT)\)", text), text
    assert "SIGTERM" not in text and "SIGKILL" not in text
    for pid in pids.values():
        assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE


def test_a_node_that_dies_stops_the_others(tmp_path: Path) -> None:
    nodes = [sim_node("sim_ok"), sim_node("sim_broken")]
    nodes[1]["parameters"]["scenario"] = str(tmp_path / "no_such_scenario.yaml")
    process, output = start_rls_run(write_runfile(tmp_path, nodes))
    try:
        code = process.wait(timeout=90)
    finally:
        if process.poll() is None:
            process.kill()
    output.close()
    text = output.text()
    assert code == 1, text
    # The runner names the node that died and its (non-zero) exit code, then stops the healthy one.
    match = re.search(r"sim_broken exited by itself \(exit code (\d+)\): stopped the other nodes", text)
    assert match and int(match.group(1)) != 0, text
    assert re.search(r"^\[sim_broken\] .*no_such_scenario", text, re.MULTILINE), text
    assert re.search(r"sim_ok stopped \((exit code 0|killed by SIGINT)\)", text), text
    assert not psutil.pid_exists(node_pids(output)["sim_ok"]) or (
        psutil.Process(node_pids(output)["sim_ok"]).status() == psutil.STATUS_ZOMBIE
    )


def test_node_command_line() -> None:
    spec = NodeSpec(
        "scan_sim",
        "robot1_sim",
        params_file="config/scan_sim.yaml",
        parameters={"scenario": "office", "speed": 2.0, "exit_at_end": False, "seed": 3, "label": "1.5"},
        remaps={"scan": "/robot1/scan"},
        arguments=["--record", "out"],
    )
    assert spec.command(python="python3") == [
        "python3", "-m", "robot_localization_suite.nodes.scan_sim", "--record", "out",
        "--ros-args", "-r", "__node:=robot1_sim", "--params-file", "config/scan_sim.yaml",
        "-p", "scenario:=office", "-p", "speed:=2.0", "-p", "exit_at_end:=false", "-p", "seed:=3",
        "-p", "label:='1.5'", "-r", "scan:=/robot1/scan",
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (True, "true"),
        (3, "3"),
        (0.25, "0.25"),
        ("plain/path.yaml", "plain/path.yaml"),
        ("2.0", "'2.0'"),  # would otherwise be read as a double
        ("true", "'true'"),
        ("", "''"),
        ("a: b", "'a: b'"),
        ([1.0, 2.5], "[1.0, 2.5]"),
    ],
)
def test_parameter_values_parse_back_to_their_type(value, text: str) -> None:
    assert format_parameter(value) == text
    assert yaml.safe_load(text) == value


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("nodes: []", "at least one node"),
        ("- {name: x}", "no field 'executable'"),
        ("- {executable: scan_sim, nmae: x}", r"unknown field\(s\) \['nmae'\]"),
        ("speed: 2\nnodes: [{executable: scan_sim}]", r"unknown field\(s\) \['speed'\]"),
        ("domain_id: 500\nnodes: [{executable: scan_sim}]", "domain_id .* got 500"),
        ("- {executable: scan_sim, parameters: [a, b]}", r"bad\.yaml': node #0: parameters must be a mapping, got \['a', 'b'\]"),
        ("- {executable: scan_sim, remaps: 'scan:front'}", r"node #0: remaps must be a mapping, got 'scan:front'"),
        ("- {executable: scan_sim, arguments: --foo}", r"node #0: arguments must be a list, got '--foo'"),
    ],
)
def test_runfile_errors_name_the_field(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(content)
    with pytest.raises(RunError, match=message):
        load_runfile(path)


def test_a_binary_runfile_is_refused_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "binary.yaml"
    path.write_bytes(bytes([0xFC, 0x4B, 0x70, 0x39, 0xDF]))
    with pytest.raises(RunError, match=r"binary\.yaml' is not valid YAML: 'utf-8' codec can't decode byte 0xfc"):
        load_runfile(path)


def test_node_validation_refuses_what_ros_would_ignore(tmp_path: Path) -> None:
    with pytest.raises(RunError, match="executable 'no_such_node' does not exist"):
        NodeSpec("no_such_node", "x").validate()
    with pytest.raises(RunError, match="valid ROS name.*'bad-name'"):
        NodeSpec("scan_sim", "bad-name").validate()
    with pytest.raises(RunError, match="params_file .*missing.yaml' does not exist"):
        NodeSpec("scan_sim", "sim", params_file=str(tmp_path / "missing.yaml")).validate()
    # scan_sim.yaml is keyed "scan_sim:": a node renamed "sim_a" would silently get none of it.
    with pytest.raises(RunError, match=r"no section for node 'sim_a' \(nor '/\*\*'\): ROS would ignore it"):
        NodeSpec("scan_sim", "sim_a", params_file=str(ROOT / "config" / "scan_sim.yaml")).validate()
    NodeSpec("scan_sim", "scan_sim", params_file=str(ROOT / "config" / "scan_sim.yaml")).validate()


def test_example_runfiles_are_valid() -> None:
    runfiles = sorted((ROOT / "config" / "runs").glob("*.yaml"))
    assert runfiles
    for path in runfiles:
        runfile = load_runfile(path)
        assert runfile.nodes, path
        for spec in runfile.nodes:
            assert "$(" not in " ".join(spec.command()), "unresolved substitution"
            spec.validate()


def test_monitor_scores_estimates_against_interpolated_truth() -> None:
    monitor = DemoMonitor(["loc"])
    # Truth moves along x at 1 m/s; a kidnapping at t = 3 jumps it to (10, 10).
    for t in np.arange(0.0, 3.0, 0.1):
        monitor.on_truth(100.0 + t, np.array([t, 0.0, 0.0]))
    for t in np.arange(3.0, 4.0, 0.1):
        monitor.on_truth(100.0 + t, np.array([10.0, 10.0, 0.0]))
    monitor.on_estimate("loc", 101.05, np.array([1.05, 0.3, 0.1]))  # 0.3 m, 0.1 rad off: correct
    monitor.on_estimate("loc", 102.0, np.array([2.0, 0.4, 1.0]))  # 0.4 m but 57 deg off: not correct
    monitor.on_estimate("loc", 103.5, np.array([10.0, 10.0, 0.0]))  # exact, after the jump
    monitor.on_estimate("loc", 200.0, np.array([0.0, 0.0, 0.0]))  # no truth that late: not scored
    monitor.on_diagnostics("loc", "LOCALIZED", 4.0)
    monitor.on_diagnostics("loc", "LOCALIZED", 6.0)
    monitor.on_diagnostics("other", "LOST", 1.0)  # not a monitored node
    lines = monitor.progress_lines()
    assert "*** kidnapping at t = 3.0 s ***" in lines
    assert any(line.startswith("t =    3.9 s") for line in lines)
    (row,) = monitor.summary_rows()
    assert row["outputs"] == 4 and row["scored"] == 3
    assert row["correct_rate"] == pytest.approx(2 / 3)
    assert row["median_error_m"] == pytest.approx(0.3, abs=1e-9)  # of 0.3, 0.4 and 0 m
    assert row["median_update_ms"] == pytest.approx(5.0)
    assert "ground truth: 40 poses over 3.9 s of scenario time, 1 kidnapping(s)" in monitor.summary_table()
    # Once scan_sim's /map (stamped at its t = 0) is in, times count from there, not from the first truth received.
    monitor.on_map_stamp(99.5)
    assert any(line.startswith("t =    4.4 s") for line in monitor.progress_lines())


def test_demo_runs_the_simulator_and_prints_the_summary(tmp_path: Path) -> None:
    env = dict(os.environ)
    result = subprocess.run(
        [sys.executable, "-m", "robot_localization_suite.launch.demo", "--localizers", "none",
         "--speed", "4", "--duration", "8", "--period", "0.5", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120, env=env,
    )  # fmt: skip
    text = result.stdout + result.stderr
    assert result.returncode == 0, text
    assert "localizers: none (simulator only)" in text
    truth = re.findall(r"\[demo\] t = +([\d.]+) s +truth +x +([-\d.]+) +y +([-\d.]+)", text)
    assert len(truth) >= 3, text
    # The robot starts at the scenario's start (1.5, 9.0) and the reported time advances.
    times = [float(t) for t, _x, _y in truth]
    assert times[-1] > times[0]
    assert "(no localizer ran: simulator only)" in text
    poses = int(re.search(r"ground truth: (\d+) poses", text).group(1))
    assert poses >= 20
    # The nodes' and the runner's lines go to the run's logs/, not the terminal.
    (run_dir,) = tmp_path.iterdir()
    assert f"run directory {run_dir}" in text and "[scan_sim]" not in text
    runner_log = (run_dir / "logs" / "rls_run.log").read_text()
    assert re.search(r"scan_sim stopped \((exit code 0|killed by SIGINT)\)", runner_log), runner_log
    assert (run_dir / "logs" / "scan_sim.log").is_file()


def localizer_node(**parameters) -> dict:  # noqa: ANN003
    return {
        "executable": "mcl_baseline",
        "params_file": str(ROOT / "config" / "mcl_baseline.yaml"),
        "parameters": {"map_yaml": str(ROOT / "config" / "maps" / "office.yaml"), "max_particles": 2000,
                       **parameters},
    }


def test_autostart_configures_then_activates_the_localizers_and_a_failure_stops_the_run(tmp_path: Path) -> None:
    runfile = tmp_path / "run.yaml"
    runfile.write_text(yaml.safe_dump({"nodes": [sim_node("sim"), localizer_node()]}))
    process, output = start_rls_run(runfile)
    try:
        output.wait_for(r"^\[rls_run\] mcl_baseline: configure done in [\d.]+ s", 120)
        output.wait_for(r"^\[rls_run\] mcl_baseline: activate done", 30)
        output.wait_for(r"^\[rls_run\] active: mcl_baseline", 10)
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=30) == 0, output.text()
    finally:
        if process.poll() is None:
            process.kill()
    output.close()
    # a localizer that cannot configure (no such map) stops the run: exit code 1
    runfile.write_text(yaml.safe_dump({"nodes": [localizer_node(map_yaml=str(tmp_path / "missing.yaml"))]}))
    process, output = start_rls_run(runfile)
    try:
        assert process.wait(timeout=120) == 1, output.text()
    finally:
        if process.poll() is None:
            process.kill()
    output.close()
    text = output.text()
    assert re.search(r"\[mcl_baseline\] .*configure failed: .*missing\.yaml", text), text
    assert "mcl_baseline: configure FAILED" in text and "a node did not come up: stopping the run" in text


def test_without_autostart_the_localizers_wait_for_another_manager(tmp_path: Path) -> None:
    runfile = tmp_path / "run.yaml"
    runfile.write_text(yaml.safe_dump({"autostart": False, "nodes": [localizer_node()]}))
    process, output = start_rls_run(runfile, "--duration", "8")
    try:
        assert process.wait(timeout=60) == 0
    finally:
        if process.poll() is None:
            process.kill()
    output.close()
    text = output.text()
    assert "mcl_baseline unconfigured: waiting for the configure transition" in text
    assert "configure done" not in text and "configured in" not in text
