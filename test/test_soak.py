"""rls_soak: its arithmetic on known inputs, and one short live run that writes every output (no timing targets)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot_localization_suite.core.sim.scenario_yaml import load_scenario
from robot_localization_suite.core.sim.simulator import Simulator
from robot_localization_suite.tools.soak.report import expected_inputs, rss_slope_mb_per_h, summarise_latency
from robot_localization_suite.tools.soak.tour import tour_route, write_tour

ROOT = Path(__file__).resolve().parent.parent


def test_rss_slope_recovers_a_known_growth_per_hour() -> None:
    t = np.arange(0.0, 1800.0, 10.0)  # 30 min, a sample every 10 s
    rss = 300.0 + 2.0 * t / 3600.0 + np.where(np.arange(t.size) % 2, 0.2, -0.2)  # 2 MB/h under +-0.2 MB noise
    assert rss_slope_mb_per_h(t, rss) == pytest.approx(2.0, abs=0.05)
    assert math.isnan(rss_slope_mb_per_h(t[:2], rss[:2]))  # two samples: no slope to speak of


def test_latency_summary_keeps_the_window_and_compares_its_thirds() -> None:
    received = np.arange(0.0, 90.0, 0.1)
    latency = np.where(received < 30.0, 0.010, np.where(received < 60.0, 0.020, 0.100))  # 10, 20, then 100 ms
    summary = summarise_latency(received, received - latency, 0.0, 90.0)
    assert summary.count == received.size
    assert summary.p50_ms == pytest.approx(20.0)
    assert summary.max_ms == pytest.approx(100.0)
    assert summary.p95_first_third_ms == pytest.approx(10.0)
    assert summary.p95_last_third_ms == pytest.approx(100.0)
    assert summary.grows
    steady = summarise_latency(received, received - 0.010, 30.0, 60.0)
    assert steady.count == 301 and not steady.grows  # 30.0 .. 60.0 s inclusive
    assert summarise_latency([], [], 0.0, 1.0).count == 0


def test_expected_inputs_follow_the_simulators_camera_schedule() -> None:
    scenario = load_scenario(ROOT / "config" / "scenarios" / "lab_camera.yaml")
    simulator = Simulator(scenario)
    images = [step.image is not None for step in (simulator.step() for _ in range(40))]
    period, rate = scenario.laser.period, scenario.camera.rate_hz
    assert expected_inputs(0, 39, camera_rate_hz=rate, laser_period_s=period) == sum(images)
    assert expected_inputs(13, 39, camera_rate_hz=rate, laser_period_s=period) == sum(images[13:])
    assert expected_inputs(13, 39) == 27  # a scan every step
    assert expected_inputs(5, 4) == 0


def test_the_tour_drives_the_route_out_and_back_without_teleports(tmp_path: Path) -> None:
    source = ROOT / "config" / "scenarios" / "lab_camera.yaml"
    raw = yaml.safe_load(source.read_text())
    loop = tour_route(raw)
    # lab_camera's kidnapping continues at waypoint 21: the tour drives 0..20 and back to the start.
    assert loop[:21] == raw["motion"]["waypoints"][:21]
    assert loop[-1] == raw["start"][:2]
    once = write_tour(source, tmp_path / "once.yaml", 1.0)
    twice = write_tour(source, tmp_path / "twice.yaml", once.end_time + 1.0)
    assert not twice.kidnappings
    assert twice.end_time > 2.0 * once.end_time - 5.0  # the second loop may start with a turn
    assert load_scenario(tmp_path / "twice.yaml").end_time == pytest.approx(twice.end_time)


def test_cdr_stamp_reads_the_header_of_serialized_messages() -> None:
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.serialization import serialize_message

    from robot_localization_suite.ros.tf import TFMessage, tf_message, transform_to_msg
    from robot_localization_suite.tools.soak.probes import cdr_stamp

    pose = PoseWithCovarianceStamped()
    pose.header.stamp.sec, pose.header.stamp.nanosec = 1_796_150_000, 250_000_000
    assert cdr_stamp(serialize_message(pose)) == pytest.approx(1_796_150_000.25, abs=1e-6)
    if TFMessage is not None:
        message = tf_message([transform_to_msg(12.5, "map", "odom", np.zeros(3))])
        assert cdr_stamp(serialize_message(message), 8) == pytest.approx(12.5, abs=1e-6)


def test_a_short_soak_writes_its_table_json_and_plot(tmp_path: Path, ros_domain_id: int) -> None:
    out = tmp_path / "soak"
    run = subprocess.run(
        [sys.executable, "-m", "robot_localization_suite.tools.soak", "--minutes", "0.5", "--warmup", "5",
         "--sample-period", "5", "--localizers", "mcl_baseline", "--out", str(out),
         "--domain-id", str(ros_domain_id)],
        capture_output=True, text=True, timeout=600, cwd=ROOT,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "[soak]" in run.stdout and "measuring" in run.stdout  # progress lines
    for name in ("soak.md", "soak.json", "soak.png", "stamps.npz", "nodes.log", "scenario_tour.yaml"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "soak.json").read_text())
    assert set(summary["processes"]) == {"scan_sim", "mcl_baseline", "rls_soak"}
    for name, process in summary["processes"].items():
        assert process["samples_in_window"] >= 2, name
        assert math.isfinite(process["rss_end_mb"]) and process["rss_end_mb"] > 0.0, name
        assert summary["samples"][name]["rss_mb"], name
    mcl = summary["localizers"]["mcl_baseline"]
    assert mcl["poses"] > 0
    for key in ("p50_ms", "p95_ms", "max_ms"):
        assert mcl["latency"][key] is not None and math.isfinite(mcl["latency"][key]), key
    assert mcl["inputs"]["published"] > 0 and mcl["inputs"]["processed"] > 0
    assert "| mcl_baseline |" in (out / "soak.md").read_text()


def test_a_soak_whose_dds_teardown_hangs_has_written_its_results_and_ends(tmp_path: Path, ros_domain_id: int) -> None:
    """The middleware's teardown comes after every result is on disk, under the stop deadline
    (ros/stopping.py): a monitor node whose destruction hangs holding the GIL loses nothing."""
    out = tmp_path / "soak"
    code = f"""
import ctypes, sys
from robot_localization_suite.tools.soak import probes
probes.StampMonitor.close = lambda self: ctypes.PyDLL(None).pause()  # rmw_destroy_node that never returns
from robot_localization_suite.tools.soak.cli import main
sys.exit(main(["--minutes", "0.3", "--warmup", "5", "--sample-period", "5", "--localizers", "mcl_baseline",
               "--out", {str(out)!r}, "--domain-id", "{ros_domain_id}"]))
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert run.returncode == -2, run.stdout[-3000:] + run.stderr[-3000:]  # ended by the deadline's SIGINT
    assert "Timeout (" in run.stderr and "<lambda>" in run.stderr  # where it hung, printed first
    for name in ("soak.md", "soak.json", "soak.png", "stamps.npz", "nodes.log"):
        assert (out / name).stat().st_size > 0, name
    assert json.loads((out / "soak.json").read_text())["localizers"]["mcl_baseline"]["poses"] > 0
