"""rls_bench end to end on a small bag written here, with the echo test double."""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from echo_localizer import EchoLocalizer
from tqdm import tqdm

from robot_localization_suite import registry
from robot_localization_suite.core import metrics
from robot_localization_suite.core.errors import SettingsError
from robot_localization_suite.core.grid_map import GridMap, load_map_yaml
from robot_localization_suite.core.localizer import Place
from robot_localization_suite.core.motion import ODOMETRY_NOISE_KEY, OdometryMotionModel, declare_odometry_noise
from robot_localization_suite.core.progress import progress_disabled
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.bag import BagWriter, read_bag
from robot_localization_suite.tools import bench
from robot_localization_suite.tools import scan_coverage as bench_scan_coverage

SCAN_PERIOD = 0.1  # [s]
KIDNAP_AT = 10.0  # [s] after the first scan
REQUIRED_FIELDS = {
    "correct", "fine", "time_to_first_fix_s", "kidnap_recovery_s", "correct_rate", "fine_rate", "rmse_xy_m",
    "rmse_theta_rad", "update_ms_median", "update_ms_p95", "peak_rss_mb", "outputs", "mode",
}


def room_map() -> GridMap:
    """A 12 m x 8 m room at 5 cm with walls all round and one pillar."""
    data = np.zeros((160, 240), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[60:80, 150:170] = 100
    return GridMap(data, 0.05, (0.0, 0.0))


def true_trajectory(stamps: np.ndarray, kidnap: bool) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth and odometry: driving +x at 0.4 m/s; the truth jumps 3 m in y at KIDNAP_AT."""
    t = stamps - stamps[0]
    odom = np.stack([0.4 * t, np.zeros_like(t), np.zeros_like(t)], axis=1)
    truth = odom + np.array([1.0, 2.0, 0.0])
    if kidnap:
        truth[t >= KIDNAP_AT - 1e-9, 1] += 3.0
    return truth, odom


def write_bag(path, *, truth_topic: bool = True, map_topic: bool = True, kidnap: bool = True, duration: float = 20.0,
              map_change_at: float | None = None, reinitialize_at: float | None = None,
              custom_data: dict[str, str] | None = None):
    """``map_change_at`` / ``reinitialize_at`` [s after the first scan]: a second /map (the pillar moved) and a
    reinitialization request there, as ``scan_sim --record`` writes them (before that step's messages).
    ``custom_data``: the metadata's (``carmen_to_bag`` declares its odometry noise there)."""
    from std_msgs.msg import Header

    grid_map = room_map()
    changed = room_map()
    changed.data[60:80, 150:170], changed.data[100:120, 150:170] = 0, 100
    stamps = 100.0 + np.arange(0.0, duration + 1e-9, SCAN_PERIOD)
    truth, odom = true_trajectory(stamps, kidnap)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    ranges = RayCaster(grid_map, max_range=10.0).cast(truth, angles)
    with BagWriter(path, custom_data=custom_data) as writer:
        if map_topic:
            writer.write("/map", conversions.grid_map_to_msg(grid_map, stamps[0]), int(stamps[0] * 1e9) - 3000)
        for stamp, true_pose, odom_pose, scan in zip(stamps, truth, odom, ranges, strict=True):
            ns = int(round(stamp * 1e9))
            if map_change_at is not None and abs(stamp - stamps[0] - map_change_at) < 1e-6:
                writer.write("/map", conversions.grid_map_to_msg(changed, stamp), ns - 3000)
            if reinitialize_at is not None and abs(stamp - stamps[0] - reinitialize_at) < 1e-6:
                writer.write("/operator/reinitialize_global_localization",
                             Header(stamp=conversions.seconds_to_stamp(stamp), frame_id="map"), ns - 2500)
            writer.write("/odom", conversions.odometry_to_msg(stamp, odom_pose, frame_id="odom"), ns - 2000)
            if truth_topic:
                writer.write("/ground_truth", conversions.odometry_to_msg(stamp, true_pose, frame_id="map"), ns - 1000)
            writer.write("/scan", conversions.scan_to_msg(stamp, "laser", angle_min=angles[0],
                                                          angle_increment=angles[1] - angles[0], ranges=scan,
                                                          range_min=0.05, range_max=10.0), ns)
    return stamps, truth


@pytest.fixture(scope="module")
def kidnap_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("bags") / "room_kidnap"
    stamps, truth = write_bag(path)
    return path, metrics.Trajectory(stamps, truth)


def lost_for_two_seconds(stamp: float) -> tuple[float, float, float] | None:
    """Echo error: right, except for 2 s after the kidnapping, when it still reports the old place."""
    since_kidnap = stamp - 100.0 - KIDNAP_AT
    return (0.0, -3.0, 0.0) if -1e-9 <= since_kidnap < 2.0 - 1e-9 else (0.0, 0.0, 0.0)


def at_the_destination_early(stamp: float) -> tuple[float, float, float]:
    """Echo error: 1 s before the kidnapping it already names the place the robot is carried to."""
    since_kidnap = stamp - 100.0 - KIDNAP_AT
    return (0.0, 3.0, 0.0) if -1.0 - 1e-9 <= since_kidnap < -1e-9 else (0.0, 0.0, 0.0)


def constant_offset(stamp: float) -> tuple[float, float, float]:
    return (0.3, 0.0, 0.0)


def never(stamp: float) -> None:
    return None


def echo_spec(truth: metrics.Trajectory, error, name: str = "echo", **kwargs) -> bench.LocalizerSpec:
    return bench.LocalizerSpec(name, functools.partial(EchoLocalizer, truth, error, **kwargs))


def test_kidnap_recovery_and_outputs_end_to_end(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    summary = bench.run_benchmark([path], [echo_spec(truth, lost_for_two_seconds)], tmp_path, isolate=False)
    fields = summary["room_kidnap"]["echo"]
    assert REQUIRED_FIELDS <= set(fields)
    assert fields["mode"] == "global"
    assert fields["outputs"] == 201 and fields["inputs"] == 201
    assert fields["kidnappings"] == 1
    assert fields["kidnap_recovery_s"] == [pytest.approx(2.0, abs=SCAN_PERIOD)]
    assert fields["kidnap_recovery_updates"] == [21]  # 20 lost outputs, then the fix
    assert fields["time_to_first_fix_s"] == 0.0
    assert fields["correct"] == 181 and fields["fine"] == 181  # 20 outputs 3 m off, the rest exact
    assert fields["correct_rate"] == pytest.approx(181 / 201, abs=1e-4)
    assert fields["rmse_xy_m"] == pytest.approx(0.0, abs=1e-6)  # the wrong ones fall in the recovery
    # The echo says LOCALIZED at every output, also the 20 that are 3 m off.
    assert fields["localized_rate"] == 1.0 and fields["false_localized_rate"] == pytest.approx(20 / 201, abs=1e-4)
    assert fields["update_ms_median"] is not None and fields["update_ms_p95"] >= fields["update_ms_median"]
    assert fields["peak_rss_mb"] > 10
    assert fields["map"] == "room_kidnap:/map"
    # Files: JSON equal to the return value, a markdown table, three plots.
    assert json.loads((tmp_path / "summary.json").read_text()) == json.loads(json.dumps(summary))
    table = (tmp_path / "summary.md").read_text()
    assert "| room_kidnap | echo | 201 | 0.9 |" in table
    for kind in ("trajectory", "error", "update_time"):
        png = tmp_path / "plots" / "room_kidnap" / f"echo_{kind}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_truth_among_candidates_counts_as_candidate_recovery(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    plain = bench.run_benchmark([path], [echo_spec(truth, lost_for_two_seconds)], tmp_path, isolate=False,
                                plots=False)["room_kidnap"]["echo"]
    assert plain["kidnap_candidate_recovery_updates"] is None  # publishes no candidates
    fields = bench.run_benchmark([path], [echo_spec(truth, lost_for_two_seconds, truth_as_candidate=True)],
                                 tmp_path, isolate=False, plots=False)["room_kidnap"]["echo"]
    assert fields["kidnap_recovery_updates"] == [21]
    assert fields["kidnap_candidate_recovery_updates"] == [1]
    assert "| [21] | [1] |" in (tmp_path / "summary.md").read_text()


def test_constant_offset_end_to_end(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    fields = bench.run_benchmark([path], [echo_spec(truth, constant_offset)], tmp_path, isolate=False,
                                 plots=False)["room_kidnap"]["echo"]
    assert fields["correct_rate"] == 1.0
    assert fields["fine_rate"] == 0.0
    assert fields["rmse_xy_m"] == pytest.approx(0.3, abs=1e-6)
    assert fields["kidnap_recovery_s"] == [0.0]  # the echo follows the jump at once


def test_a_recovery_at_a_place_held_before_the_kidnapping_is_marked_in_the_table(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    fields = bench.run_benchmark([path], [echo_spec(truth, at_the_destination_early)], tmp_path, isolate=False,
                                 plots=False)["room_kidnap"]["echo"]
    assert fields["kidnap_recovery_s"] == [0.0]
    assert fields["kidnap_at_destination_before"] == [True]
    assert "| [0 (there before)] |" in (tmp_path / "summary.md").read_text()


def test_localizer_that_never_publishes_gives_nulls(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    fields = bench.run_benchmark([path], [echo_spec(truth, never, name="silent")], tmp_path,
                                 isolate=False)["room_kidnap"]["silent"]
    assert fields["outputs"] == 0
    for key in ("time_to_first_fix_s", "correct_rate", "fine_rate", "rmse_xy_m", "rmse_theta_rad"):
        assert fields[key] is None
    assert fields["kidnap_recovery_s"] == [None]
    assert fields["correct"] == 0
    assert fields["inputs"] == 201
    assert fields["update_ms_median"] is None  # asked 201 times, but a call that returns nothing is no update
    assert "| room_kidnap | silent | 0 | – |" in (tmp_path / "summary.md").read_text()


def test_bag_without_ground_truth_reports_timing(tmp_path, capsys):
    path = tmp_path / "no_truth"
    _, truth_poses = write_bag(path, truth_topic=False, kidnap=False, duration=3.0)
    truth = metrics.Trajectory(100.0 + np.arange(0.0, 3.0 + 1e-9, SCAN_PERIOD), truth_poses)
    summary = bench.run_benchmark([path], [echo_spec(truth, constant_offset)], tmp_path / "out", isolate=False)
    fields = summary["no_truth"]["echo"]
    assert "no /ground_truth" in capsys.readouterr().err
    assert fields["ground_truth"] is False and "no /ground_truth" in fields["note"]
    assert fields["outputs"] == 31 and fields["update_ms_median"] is not None
    assert fields["correct_rate"] is None and fields["correct"] is None


def test_a_bag_cut_short_is_benchmarked_on_what_was_recovered(kidnap_bag, tmp_path):
    """A recording that lost power at half: no footer, no metadata.yaml; the run uses the intact part and says so."""
    path, truth = kidnap_bag
    data = (path / "room_kidnap.mcap").read_bytes()
    cut = tmp_path / "room_cut"
    cut.mkdir()
    (cut / "room_cut.mcap").write_bytes(data[: len(data) // 2])
    summary = bench.run_benchmark([cut], [echo_spec(truth, constant_offset)], tmp_path / "out", isolate=False)
    fields = summary["room_cut"]["echo"]
    assert fields["recovered"] is True and 0 < fields["recovered_messages"] < 1 + 3 * 201
    assert 0 < fields["outputs"] < 201 and fields["outputs"] == fields["inputs"]
    assert fields["correct_rate"] == 1.0 and fields["map"] == "room_cut:/map"
    last_scan = 100.0 + SCAN_PERIOD * (fields["inputs"] - 1)  # the odometry of the next step may have made it
    assert last_scan - 1e-6 <= fields["recovered_until_s"] <= last_scan + SCAN_PERIOD + 1e-6
    assert "recovered from a damaged bag" in (tmp_path / "out" / "summary.md").read_text()
    assert (tmp_path / "out" / "plots" / "room_cut" / "echo_trajectory.png").is_file()
    sound = bench.run_benchmark([path], [echo_spec(truth, constant_offset)], tmp_path / "sound", isolate=False,
                                plots=False)["room_kidnap"]["echo"]
    assert "recovered" not in sound


def test_tracking_mode_sends_the_first_true_pose(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    built = []

    def factory():
        built.append(EchoLocalizer(truth, constant_offset))
        return built[-1]

    fields = bench.run_benchmark([path], [bench.LocalizerSpec("echo", factory)], tmp_path, mode="tracking",
                                 isolate=False, plots=False)["room_kidnap"]["echo"]
    assert fields["mode"] == "tracking"
    assert built[0].initial_pose == pytest.approx(truth.poses[0])
    assert built[0].odometry_count == 201
    assert built[0].grid_map is not None and built[0].grid_map.width == 240


def test_method_specific_fields_from_the_typed_estimate(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    nodes = np.array([[1.0, 2.0], [5.0, 2.0], [5.0, 5.0]])

    def fields_at(stamp: float, true_pose: np.ndarray) -> dict:
        late = stamp - 100.0 >= 15.0
        # A box around the truth, theta interval shifted by 2 pi; the last 5 s the box is 1 m off.
        shift = 1.0 if late else 0.0
        box = np.array([[true_pose[0] - 0.1 + shift, true_pose[0] + 0.1 + shift],
                        [true_pose[1] - 0.1, true_pose[1] + 0.1],
                        [true_pose[2] + 2 * np.pi - 0.1, true_pose[2] + 2 * np.pi + 0.1]])
        nearest = nodes[np.argmin(np.hypot(*(nodes - true_pose[:2]).T))]
        place = Place("node", nearest if not late else nodes[2], nodes)
        return {"boxes": box[None], "place": place, "heading_corrected": True}

    fields = bench.run_benchmark([path], [echo_spec(truth, constant_offset, fields=fields_at)], tmp_path,
                                 isolate=False, plots=False)["room_kidnap"]["echo"]
    assert fields["containment_rate"] == pytest.approx(150 / 201, abs=1e-4)
    # The last 5 s the truth is near node 1 or 2 and the output says node 2: right only when nearest is node 2.
    truth_after = truth.poses[truth.stamps - 100.0 >= 15.0 - 1e-9]
    nearest_is_2 = np.argmin(np.hypot(nodes[None, :, 0] - truth_after[:, None, 0],
                                      nodes[None, :, 1] - truth_after[:, None, 1]), axis=1) == 2
    assert fields["correct_place_rate"] == pytest.approx((150 + nearest_is_2.sum()) / 201, abs=1e-4)
    assert fields["heading_error_when_corrected_deg"]["max"] == pytest.approx(0.0, abs=1e-6)
    assert fields["heading_error_when_corrected_deg"]["count"] == 201


def test_global_fixes_report_rates_and_recall(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    spec = echo_spec(truth, constant_offset, decoys=3)  # right answer at rank 4
    summary = bench.run_global_fixes([path], [spec], tmp_path, every=10, isolate=False)
    fields = summary["room_kidnap"]["echo"]
    assert fields["fixes"] == 21
    assert fields["global_correct_rate"] == 0.0  # the best candidate is always a decoy
    assert fields["recall_at_k"] == {"1": 0.0, "5": 1.0, "10": 1.0, "30": 1.0, "50": 1.0, "100": 1.0}
    assert fields["fix_ms_median"] is not None
    table = (tmp_path / "summary.md").read_text()
    assert "| room_kidnap | echo | 21 | 0 | 0 | 1 0, 5 1, 10 1, 30 1, 50 1, 100 1 |" in table
    assert "recall@k: a correct candidate among the first k" in table


def test_global_fixes_leave_out_localizers_without_global_fix(kidnap_bag, tmp_path):
    path, truth = kidnap_bag

    class TrackingOnly(EchoLocalizer):
        global_fix = None

    spec = bench.LocalizerSpec("tracker", lambda: TrackingOnly(truth, constant_offset))
    assert bench.run_global_fixes([path], [spec], tmp_path, isolate=False) == {"room_kidnap": {}}


def test_run_in_a_child_process(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    ballast = np.ones(40_000_000)  # 320 MB resident in this process, none of it in the child's run
    summary = bench.run_benchmark([path], [echo_spec(truth, lost_for_two_seconds)], tmp_path, isolate=True,
                                  plots=False)
    fields = summary["room_kidnap"]["echo"]
    assert fields["kidnap_recovery_s"] == [pytest.approx(2.0, abs=SCAN_PERIOD)]
    # The child's own peak (python + numpy + rclpy), not this test process's size inherited through fork.
    assert 50 < fields["peak_rss_mb"] < 300 < bench.isolation.own_peak_rss_mb()
    del ballast


class BarredEcho(EchoLocalizer):
    """The echo with a precomputation progress bar on set_map, switched like IR's (core/progress.py)."""

    def set_map(self, grid_map):
        super().set_map(grid_map)
        for _ in tqdm(range(3), desc="BARRED PRECOMPUTATION", disable=progress_disabled(True)):
            pass


def test_child_runs_show_precomputation_bars_only_when_asked(kidnap_bag, tmp_path, capfd):
    path, truth = kidnap_bag
    spec = bench.LocalizerSpec("barred", functools.partial(BarredEcho, truth, constant_offset))
    before = os.environ.get("TQDM_DISABLE")
    shown = {}
    for child_progress in (False, True):
        summary = bench.run_benchmark([path], [spec], tmp_path / str(child_progress), isolate=True, plots=False,
                                      child_progress=child_progress)
        assert summary["room_kidnap"]["barred"]["correct_rate"] == 1.0  # the run itself is unchanged
        shown[child_progress] = "BARRED PRECOMPUTATION" in capfd.readouterr().err
    assert shown == {False: False, True: True}  # rls_bench without / with -v
    assert os.environ.get("TQDM_DISABLE") == before  # set for the child only


def test_the_verbose_flag_turns_the_child_runs_bars_on(kidnap_bag, tmp_path, monkeypatch):
    path, _ = kidnap_bag
    calls = []
    monkeypatch.setattr(bench.cli, "run_benchmark", lambda *args, **kwargs: calls.append(kwargs) or {})
    for extra in ([], ["-v"]):
        assert bench.main([str(path), "--localizers", "mcl_baseline", "--out", str(tmp_path), *extra]) == 0
    assert [call["child_progress"] for call in calls] == [False, True]


def test_with_tracking_and_global_fixes_append_their_tables(kidnap_bag, tmp_path, monkeypatch):
    path, _ = kidnap_bag
    runs = []

    def fake(kind):
        def run(bags, specs, out, **kwargs):
            runs.append((kind, kwargs.get("mode"), Path(out).relative_to(tmp_path).as_posix()))
            Path(out).mkdir(parents=True, exist_ok=True)
            (Path(out) / "summary.md").write_text(f"# {kind} {kwargs.get('mode')}\n")
            return {}
        return run

    monkeypatch.setattr(bench.cli, "run_benchmark", fake("replay"))
    monkeypatch.setattr(bench.cli, "run_global_fixes", fake("fixes"))
    argv = [str(path), "--localizers", "mcl_baseline", "--out", str(tmp_path), "--with-tracking", "--with-global-fixes"]
    assert bench.main(argv) == 0
    assert runs == [("replay", "global", "."), ("replay", "tracking", "tracking"), ("fixes", None, "global_fixes")]
    assert (tmp_path / "summary.md").read_text() == "# replay global\n\n## replay tracking\n\n## fixes None\n"


def test_compare_with_sets_this_runs_replays_beside_another_runs_per_localizer(kidnap_bag, tmp_path, monkeypatch):
    path, _ = kidnap_bag
    ours = {"room_kidnap": {"ir_initializer": {"outputs": 10, "correct_rate": 0.9, "rmse_xy_m": 0.05},
                            "pil_localizer": {"skipped": "not on this bag"}}}
    (tmp_path / "ours").mkdir()
    (tmp_path / "ours" / "summary.json").write_text(json.dumps(ours))
    paper = {"room_kidnap": {"ir_initializer": {"outputs": 10, "correct_rate": 0.5, "rmse_xy_m": 0.25},
                             "pil_localizer": {"outputs": 10, "correct_rate": 0.7}}}

    def replays(bags, specs, out, **kwargs):
        Path(out).mkdir(parents=True, exist_ok=True)
        return paper if kwargs["mode"] == "global" else {"room_kidnap": {}}  # tracking is not compared

    monkeypatch.setattr(bench.cli, "run_benchmark", replays)
    monkeypatch.setattr(bench.cli, "append_section", lambda out, sub: None)
    argv = [str(path), "--localizers", "ir_initializer", "pil_localizer", "--profile", "paper", "--out",
            str(tmp_path / "paper"), "--with-tracking", "--compare-with", f"ours={tmp_path / 'ours'}", "--no-plots"]
    assert bench.main(argv) == 0
    text = (tmp_path / "paper" / "comparison.md").read_text()
    ir = text[text.index("### ir_initializer"):text.index("### pil_localizer")]
    assert "| room_kidnap | paper | 0.5 |" in ir and "| room_kidnap | ours | 0.9 |" in ir
    assert "| 0.25 |" in ir and "| 0.05 |" in ir
    assert "| room_kidnap | ours | not on this bag |" in text[text.index("### pil_localizer"):]
    # a directory without summary.json is refused before anything runs
    assert bench.main([*argv[:-3], "--compare-with", f"ours={tmp_path / 'nowhere'}"]) == 1


def off_from_5_to_8_s(stamp: float) -> tuple[float, float, float]:
    """Echo error: 1 m off from 5 s to 8 s after the first scan, exact otherwise."""
    return (1.0, 0.0, 0.0) if 5.0 - 1e-9 <= stamp - 100.0 < 8.0 - 1e-9 else (0.0, 0.0, 0.0)


def test_map_coverage_fields_on_the_map_the_scans_came_from(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    fields = bench.run_benchmark([path], [echo_spec(truth, lost_for_two_seconds)], tmp_path, isolate=False,
                                 plots=False)["room_kidnap"]["echo"]
    # The scans are cast on the bag's own map: every end point is on a wall, every output covered.
    assert fields["map_coverage_median"] == 1.0
    assert fields["outputs_covered"] == 201
    assert fields["correct_rate_covered"] == fields["correct_rate"]
    assert "| room_kidnap | echo | 201 | 0.9 | 0.9 | 0.9 | 1 |" in (tmp_path / "summary.md").read_text()


def test_map_coverage_splits_rates_on_a_map_without_the_far_wall(kidnap_bag, tmp_path, monkeypatch):
    path, truth = kidnap_bag
    half = room_map()
    half.data[:, 230:] = -1  # beyond x = 11.5 m unknown: the far wall, which the robot sees more as it nears it
    half_yaml = half.save(tmp_path / "half.yaml")
    calls = []
    original = bench_scan_coverage.bag_scan_coverage
    monkeypatch.setattr(bench_scan_coverage, "bag_scan_coverage",
                        lambda *args, **kwargs: calls.append(args[0]) or original(*args, **kwargs))
    specs = [echo_spec(truth, off_from_5_to_8_s), echo_spec(truth, off_from_5_to_8_s, name="echo2")]
    fields = bench.run_benchmark([path], specs, tmp_path, map_yaml=half_yaml, isolate=False,
                                 plots=False)["room_kidnap"]["echo"]
    assert len(calls) == 1  # once per bag and map, not per localizer
    # The same figures straight from the helpers: each output's scan coverage, the correct outputs.
    coverage = bench_scan_coverage.bag_scan_coverage(path, load_map_yaml(half_yaml))
    stamps = 100.0 + np.arange(201) * SCAN_PERIOD
    correct = ~((stamps - 100.0 >= 5.0 - 1e-9) & (stamps - 100.0 < 8.0 - 1e-9))
    expected = metrics.coverage_rates(correct, coverage.at(stamps))
    assert 0 < expected["outputs_covered"] < 201  # the first ~100 outputs covered, the later ones not
    assert expected["correct_rate_covered"] < 1.0 == expected["correct_rate_uncovered"]
    assert fields["outputs_covered"] == expected["outputs_covered"]
    assert fields["correct_rate_covered"] == expected["correct_rate_covered"]
    assert fields["correct_rate"] == pytest.approx(171 / 201, abs=1e-4)
    assert fields["map_coverage_median"] == pytest.approx(np.median(coverage.coverage), abs=1e-4)
    fixes = bench.run_global_fixes([path], specs[:1], tmp_path / "fixes", map_yaml=half_yaml, every=5,
                                   isolate=False)["room_kidnap"]["echo"]
    every_5th = np.arange(0, 201, 5)
    expected = metrics.coverage_rates(correct[every_5th], coverage.at(stamps[every_5th]))
    assert fixes["fixes_covered"] == expected["outputs_covered"]
    assert fixes["global_correct_rate_covered"] == expected["correct_rate_covered"]
    assert fixes["global_correct_rate"] == expected["correct_rate"]


def test_containment_is_split_by_map_coverage_like_the_correct_rate(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    half = room_map()
    half.data[:, 230:] = -1  # the far wall unknown: the later scans are not covered
    half_yaml = half.save(tmp_path / "half.yaml")

    def box_off_from_5_to_8_s(stamp: float, true_pose: np.ndarray) -> dict:
        shift = off_from_5_to_8_s(stamp)[0]
        return {"boxes": np.array([[[true_pose[0] - 0.1 + shift, true_pose[0] + 0.1 + shift],
                                     [true_pose[1] - 0.1, true_pose[1] + 0.1],
                                     [true_pose[2] - 0.1, true_pose[2] + 0.1]]]),
                "details": {"explained_needed": 0.95}}  # the share of a scan the set's bound assumes explained

    fields = bench.run_benchmark([path], [echo_spec(truth, constant_offset, fields=box_off_from_5_to_8_s)], tmp_path,
                                 map_yaml=half_yaml, isolate=False, plots=False)["room_kidnap"]["echo"]
    coverage = bench_scan_coverage.bag_scan_coverage(path, load_map_yaml(half_yaml)).at(
        100.0 + np.arange(201) * SCAN_PERIOD)
    contained = np.ones(201, dtype=bool)
    contained[50:80] = False  # 5 s to 8 s: the box 1 m off the truth
    covered = coverage >= metrics.COVERED_FRACTION
    assert covered[50:80].all() and 0 < covered.sum() < 201  # the misses fall where the map covers the scan
    assert fields["containment_rate"] == pytest.approx(171 / 201, abs=1e-4)
    assert fields["containment_outputs_covered"] == covered.sum()
    assert fields["containment_rate_covered"] == pytest.approx(contained[covered].mean(), abs=1e-4)
    assert f"containment_rate_covered {fields['containment_rate_covered']:g}" in (tmp_path / "summary.md").read_text()
    # and over the outputs whose scan meets the bound the set declares, the guarantee's own condition
    held = coverage >= 0.95
    assert 0 < held.sum() < 201 and not held[50:80].all()  # some misses fall where the bound fails
    assert fields["containment_outputs_bound_held"] == held.sum()
    assert fields["containment_rate_bound_held"] == pytest.approx(contained[held].mean(), abs=1e-4)


PREPARE_SLEEP_S = 0.3


class PreparingEcho(EchoLocalizer):
    """The echo with a slow ``prepare(scan)``, as a method with scanner-dependent precomputation would have."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.prepared_with = None

    def prepare(self, scan):
        assert self.grid_map is not None, "prepare comes after set_map"
        self.prepared_with = (scan.stamp, scan.beam_count)
        time.sleep(PREPARE_SLEEP_S)

    def on_scan(self, scan):
        assert self.prepared_with is not None, "prepare comes before the first scan"
        return super().on_scan(scan)


def test_prepare_gets_the_first_scan_and_counts_in_map_setup(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    built = []

    def factory():
        built.append(PreparingEcho(truth, constant_offset))
        return built[-1]

    spec = bench.LocalizerSpec("prep", factory)
    fields = bench.run_benchmark([path], [spec], tmp_path, isolate=False, plots=False)["room_kidnap"]["prep"]
    assert built[0].prepared_with == (pytest.approx(truth.stamps[0]), 181)  # the bag's first scan
    assert fields["map_setup_s"] >= PREPARE_SLEEP_S
    assert fields["correct_rate"] == 1.0
    fixes = bench.run_global_fixes([path], [spec], tmp_path / "fixes", isolate=False)["room_kidnap"]["prep"]
    assert built[1].prepared_with == (pytest.approx(truth.stamps[0]), 181)
    assert fixes["map_setup_s"] >= PREPARE_SLEEP_S
    # Without prepare, set_map alone: well under the sleep.
    plain = bench.run_benchmark([path], [echo_spec(truth, constant_offset)], tmp_path / "plain", isolate=False,
                                plots=False)["room_kidnap"]["echo"]
    assert plain["map_setup_s"] < PREPARE_SLEEP_S


class IdlingEcho(EchoLocalizer):
    """An echo with background work: records the idle time it is given and when."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.idle_s: list[float] = []
        self.timeline: list[str] = []

    def idle(self, seconds):
        self.idle_s.append(seconds)
        self.timeline.append("idle")

    def on_scan(self, scan):
        self.timeline.append("scan")
        return super().on_scan(scan)


def test_background_work_gets_the_log_time_between_messages_untimed(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    made: list[IdlingEcho] = []

    def factory():
        made.append(IdlingEcho(truth, constant_offset))
        return made[-1]

    from robot_localization_suite.tools.bench import replay as bench_replay

    reference = bench.load_reference(path)
    record = bench_replay.replay_localizer(reference, bench.LocalizerSpec("idler", factory),
                                           reference.map_msg_grid, sample_rss=False)
    (echo,) = made
    # before every message but the first, the log time since the one before: the bag's span in all
    assert all(seconds >= 0.0 for seconds in echo.idle_s) and len(echo.idle_s) > record.inputs
    assert sum(echo.idle_s) == pytest.approx(truth.stamps[-1] - truth.stamps[0], abs=0.2)
    # every scan after the first comes after an idle, and the idles are not in the update times
    assert all(before == "idle" for before, now in zip(echo.timeline, echo.timeline[1:], strict=False)
               if now == "scan")
    assert record.update_ms.size == record.stamps.size


def test_a_crashing_localizer_is_an_error_entry_not_a_crash(kidnap_bag, tmp_path):
    path, truth = kidnap_bag

    def broken():
        raise RuntimeError("cannot build")

    summary = bench.run_benchmark([path], [bench.LocalizerSpec("broken", broken),
                                           echo_spec(truth, constant_offset)], tmp_path, isolate=False, plots=False)
    assert "cannot build" in summary["room_kidnap"]["broken"]["error"]
    assert summary["room_kidnap"]["echo"]["correct_rate"] == 1.0


def test_map_option_wins_over_the_bag_map(kidnap_bag, tmp_path):
    path, _ = kidnap_bag
    other = GridMap(np.zeros((10, 20), dtype=np.int8), 0.1, (-1.0, -1.0))
    yaml_path = other.save(tmp_path / "other.yaml")
    reference = bench.load_reference(path)
    grid_map, source = bench.resolve_map(reference, yaml_path)
    assert grid_map.width == 20 and source == str(yaml_path)
    grid_map, source = bench.resolve_map(reference, None)
    assert grid_map.width == 240 and source == "room_kidnap:/map"


def test_bag_without_map_and_no_config_map_is_reported(tmp_path):
    path = tmp_path / "nomap_xyz"
    stamps, truth_poses = write_bag(path, map_topic=False, kidnap=False, duration=1.0)
    truth = metrics.Trajectory(stamps, truth_poses)
    fields = bench.run_benchmark([path], [echo_spec(truth, constant_offset)], tmp_path / "out",
                                 isolate=False)["nomap_xyz"]["echo"]
    assert fields["error"].startswith("no map")


def test_command_line_refuses_bad_arguments(kidnap_bag, tmp_path, capsys):
    path, _ = kidnap_bag
    assert bench.main([str(path), "--localizers", "no_such_localizer", "--out", str(tmp_path)]) == 1
    assert "no_such_localizer" in capsys.readouterr().err
    assert bench.main([str(path), "--set", "bad", "--out", str(tmp_path)]) == 1
    assert "name.param=value" in capsys.readouterr().err
    assert bench.main(["--out", str(tmp_path)]) == 1
    # a value that is no YAML, or a misspelt localizer (its value silently dropped before), is one line
    for bad, said in ((["--set", "mcl_baseline.max_particles=[1,2"], "the value '[1,2' is not YAML"),
                      (["--sweep", "mcl_baseline.max_particles=[1"], "the value '[1' is not YAML"),
                      (["--set", "mcl_basline.max_particles=100"], "--set names no localizer: mcl_basline")):
        assert bench.main([str(path), *bad, "--out", str(tmp_path)]) == 1
        err = capsys.readouterr().err
        assert said in err and "Traceback" not in err, err
    assert bench.cli._parse_overrides(["mcl_baseline.max_particles=5000", "ial_localizer.outliers=2.5"]) == {
        "mcl_baseline": {"max_particles": 5000}, "ial_localizer": {"outliers": 2.5}}


def test_all_mode_pairs_camera_and_laser_localizers_with_their_bags(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    assert bench.discover_bags(path.parent) == [path]
    camera = bench.LocalizerSpec("camera_echo", lambda: None, uses_camera=True)
    declared = bench.LocalizerSpec("picky", lambda: None, skip={"room_*": "too large a map"})
    summary = bench.run_benchmark([path], [camera, declared, echo_spec(truth, constant_offset)], tmp_path,
                                  isolate=False, plots=False, honour_skips=True)["room_kidnap"]
    assert summary["camera_echo"]["skipped"] == "no /camera/image_raw in the bag"
    assert summary["picky"]["skipped"] == "too large a map"
    assert summary["echo"]["correct_rate"] == 1.0
    assert "skipped: too large a map" in (tmp_path / "summary.md").read_text()


def test_a_global_only_skip_still_runs_tracking_with_the_bags_own_params(kidnap_bag, tmp_path):
    path, truth = kidnap_bag
    base = echo_spec(truth, constant_offset)
    spec = dataclasses.replace(base, skip_global={"room_*": "boxes saturate"},
                               per_bag={"room_*": dataclasses.replace(base, params="echo_slam.yaml")})
    summary = bench.run_benchmark([path], [spec], tmp_path / "g", isolate=False, plots=False, honour_skips=True)
    assert summary["room_kidnap"]["echo"]["skipped"] == "boxes saturate (global mode)"
    summary = bench.run_benchmark([path], [spec], tmp_path / "t", mode="tracking", isolate=False, plots=False,
                                  honour_skips=True)
    fields = summary["room_kidnap"]["echo"]
    assert fields["correct_rate"] == 1.0 and fields["params"] == "echo_slam.yaml"
    assert "params echo_slam.yaml" in (tmp_path / "t" / "summary.md").read_text()


def test_ial_runs_the_real_logs_in_tracking_mode_only_with_the_slam_params():
    spec = bench.registry_spec("ial_localizer")
    for bag in ("intel", "fr101", "orebro_cv3of5"):
        assert "saturate" in spec.skip_reason(bag, "global") and "saturate" in spec.skip_reason(bag, "global_fixes")
        assert spec.skip_reason(bag, "tracking") is None
        settings = spec.for_bag(bag).factory.args[1]
        assert spec.for_bag(bag).params == "ial_localizer_slam.yaml" and not settings.unknown_is_obstacle
    assert spec.for_bag("office_kidnap") is spec and spec.skip_reason("office_kidnap") is None
    assert spec.factory.args[1].unknown_is_obstacle and spec.params is None


DECLARED = {"alpha1": 0.0012, "alpha2": 0.0001, "alpha3": 0.0004, "alpha4": 0.0001}


def test_a_bags_declared_odometry_noise_becomes_the_motion_noise_unless_set_otherwise():
    mcl = bench.registry_spec("mcl_baseline")
    assert mcl.factory.args[1].alpha1 == 0.02  # the packaged value
    declared = mcl.for_bag("orebro", DECLARED)
    settings = declared.factory.args[1]
    tracking = (settings.tracking_alpha1, settings.tracking_alpha2, settings.tracking_alpha3, settings.tracking_alpha4)
    assert tracking == (0.0012, 0.0001, 0.0004, 0.0001) and settings.alpha1 == 0.02  # the search noise stays
    assert declared.odometry_noise == {f"tracking_{k}": v for k, v in DECLARED.items()}
    assert declared.name == "mcl_baseline"
    assert settings.max_particles == mcl.factory.args[1].max_particles  # nothing else changes
    assert mcl.for_bag("orebro") is mcl  # a bag that declares nothing
    own = bench.registry_spec("mcl_baseline", {"tracking_alpha1": 0.5}).for_bag("orebro", DECLARED)
    assert own.factory.args[1].tracking_alpha1 == 0.5 and own.factory.args[1].tracking_alpha3 == 0.0004  # --set wins
    assert "tracking_alpha1" not in own.odometry_noise
    kept = bench.registry_spec("mcl_baseline", declared_noise=False)  # --odometry-noise params
    assert kept.for_bag("orebro", DECLARED) is kept
    hybrid = bench.registry_spec("hybrid_localizer").for_bag("intel", DECLARED).factory.args[1]
    assert hybrid.mcl.tracking_alpha3 == 0.0004 and hybrid.mcl.alpha3 == 0.02
    ial = bench.registry_spec("ial_localizer")
    assert ial.for_bag("orebro", DECLARED) is ial.for_bag("orebro")  # IAL's bounds come from its slam file
    assert ial.for_bag("orebro", DECLARED).params == "ial_localizer_slam.yaml"


def test_the_declared_noise_is_read_from_the_bag_and_reported(tmp_path, caplog):
    good, bad = tmp_path / "declares", tmp_path / "garbled"
    write_bag(good, kidnap=False, duration=2.0,
              custom_data={ODOMETRY_NOISE_KEY: declare_odometry_noise(OdometryMotionModel(**DECLARED))})
    write_bag(bad, kidnap=False, duration=2.0, custom_data={ODOMETRY_NOISE_KEY: '{"model": "odometry", "alpha1": -1}'})
    assert bench.load_reference(good).odometry_noise == DECLARED
    with caplog.at_level(logging.WARNING, logger="rls_bench"):
        assert bench.load_reference(bad).odometry_noise is None
    assert "ignoring its declared odometry noise" in caplog.text and "alpha" in caplog.text
    summary = bench.run_benchmark([good], [bench.registry_spec("mcl_baseline")], tmp_path / "out", isolate=False,
                                  mode="tracking")
    assert summary["declares"]["mcl_baseline"]["odometry_noise"].startswith("declared by the bag: tracking_alpha1=0.0012")
    assert "odometry noise declared by the bag" in (tmp_path / "out" / "summary.md").read_text()


def exit_at_once():
    """A factory whose process dies without a Python exception (as a segfault would)."""
    os._exit(3)


def test_a_dying_child_is_an_error_entry(kidnap_bag, tmp_path):
    path, _ = kidnap_bag
    summary = bench.run_benchmark([path], [bench.LocalizerSpec("dies", exit_at_once)], tmp_path, isolate=True)
    assert summary["room_kidnap"]["dies"]["error"] == "child process died (exit code 3)"


# Run in a fresh interpreter: this test process has long since imported rclpy through the bag writer.
IMPORT_CHECK = """
import sys
import robot_localization_suite.tools.bench
heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("rclpy", "rosidl_parser", "builtin_interfaces")
               or m.split(".")[0].endswith("_msgs") or m.startswith("robot_localization_suite.nodes"))
assert not heavy, heavy
"""


def test_importing_the_benchmark_loads_no_rclpy_messages_or_nodes():
    result = subprocess.run([sys.executable, "-c", IMPORT_CHECK], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


def test_the_package_runs_as_a_module():
    result = subprocess.run([sys.executable, "-m", "robot_localization_suite.tools.bench", "--help"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: rls_bench")


def test_an_override_naming_no_parameter_is_refused_before_anything_runs():
    with pytest.raises(SettingsError, match="mcl_baseline has no parameter 'alpha_1'"):
        bench.registry_spec("mcl_baseline", {"alpha_1": 0.1})
    assert bench.registry_spec("mcl_baseline", {"alpha1": 0.1, "laser_x": 0.2}).mount.x == 0.2


def test_a_params_file_or_the_paper_profile_replaces_the_packaged_and_per_bag_files(kidnap_bag, tmp_path, capsys):
    paper = bench.registry_spec("ir_initializer", {"seed": 3},
                                params_file=registry.config_dir() / "ir_initializer_paper.yaml")
    settings = paper.factory.args[1]
    assert (settings.nms_distance, settings.refine_candidates, settings.initial_particles) == (0.0, 0, "one_per_candidate")
    assert settings.pattern_views == "two_240"  # the paper's two 240-degree views
    assert settings.seed == 3 and paper.params == "ir_initializer_paper.yaml"  # --set still on top
    assert bench.registry_spec("ir_initializer").factory.args[1].initial_particles == "rank"
    ial = bench.registry_spec("ial_localizer", params_file=registry.config_dir() / "ial_localizer_paper.yaml")
    assert ial.for_bag("intel") is ial and not ial.factory.args[1].laser_cell_constraint  # no per-bag file
    pil = bench.registry_spec("pil_localizer", params_file=registry.config_dir() / "pil_localizer_paper.yaml")
    assert pil.factory.args[1].match_score == "correlation"
    ima = bench.registry_spec("ima_topo_localizer", params_file=registry.config_dir() / "ima_topo_localizer_paper.yaml")
    assert ima.factory.args[1].odometry_reset == "winner"  # Code 3.1
    assert ima.factory.args[1].pose_estimate == "node"  # the thesis: the winner's node
    own = tmp_path / "mine.yaml"
    own.write_text("mcl_baseline:\n  ros__parameters:\n    max_particles: 777\n")
    assert bench.registry_spec("mcl_baseline", params_file=own).factory.args[1].max_particles == 777
    path, _ = kidnap_bag
    # mcl_baseline is no paper's method: no profile file, refused naming it
    assert bench.main([str(path), "--localizers", "mcl_baseline", "--profile", "paper", "--out", str(tmp_path)]) == 1
    assert "mcl_baseline_paper.yaml" in capsys.readouterr().err
    assert bench.main([str(path), "--localizers", "mcl_baseline", "--params-file", "mcl_baseline=none.yaml",
                       "--out", str(tmp_path)]) == 1
    assert "none.yaml" in capsys.readouterr().err
    assert bench.main([str(path), "--localizers", "mcl_baseline", "--params-file", "ir_initializer=" + str(own),
                       "--out", str(tmp_path)]) == 1
    assert "not run" in capsys.readouterr().err


# -- world events: a map change and a reinitialization request mid-bag ---------------------------------
class EventEcho(EchoLocalizer):
    """The echo double that notes when it got each map and each reinitialization (after which scan stamp)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.last_scan = -np.inf
        self.maps: list[tuple[float, GridMap]] = []
        self.reinitializations: list[float] = []

    def set_map(self, grid_map) -> None:
        super().set_map(grid_map)
        self.maps.append((self.last_scan, grid_map))

    def reinitialize(self) -> None:
        self.reinitializations.append(self.last_scan)

    def on_scan(self, scan):
        self.last_scan = scan.stamp
        return super().on_scan(scan)


def wrong_for_a_second_after_the_map_change(stamp: float) -> tuple[float, float, float]:
    return (0.0, 3.0, 0.0) if 105.0 - 1e-9 <= stamp < 106.0 - 1e-9 else (0.0, 0.0, 0.0)


@pytest.mark.parametrize("mode", ["global", "tracking"])
def test_the_replay_applies_a_map_change_and_a_reinitialization_where_the_bag_has_them(tmp_path, mode):
    from robot_localization_suite.tools.bench import replay as bench_replay
    from robot_localization_suite.tools.bench.reference import load_reference

    path = tmp_path / "room_events"
    stamps, truth_poses = write_bag(path, kidnap=False, map_change_at=5.0, reinitialize_at=12.0)
    truth = metrics.Trajectory(stamps, truth_poses)
    made: list[EventEcho] = []

    def factory() -> EventEcho:
        made.append(EventEcho(truth, wrong_for_a_second_after_the_map_change))
        return made[-1]

    reference = load_reference(path)
    assert reference.map_change_stamps.tolist() == [pytest.approx(105.0, abs=1e-5)]
    assert reference.reinitialize_stamps.tolist() == [pytest.approx(112.0, abs=1e-5)]
    assert np.array_equal(reference.map_msg_grid.data, room_map().data)  # the bag's map is its first /map
    spec = bench.LocalizerSpec("echo", factory)
    record = bench_replay.replay_localizer(reference, spec, reference.map_msg_grid, mode=mode, sample_rss=False)
    (localizer,) = made
    # The first map before any scan, the changed one between the scans at 104.9 s and 105.0 s.
    assert [after for after, _ in localizer.maps] == [-np.inf, pytest.approx(104.9)]
    assert localizer.maps[1][1].data[110, 160] == 100 and localizer.maps[1][1].data[70, 160] == 0
    assert localizer.reinitializations == [pytest.approx(111.9)]
    assert record.stamps.size == 201

    # The summary: how many events, and LOCALIZED honesty from each event to the next.
    summary = bench.run_benchmark([path], [bench.LocalizerSpec("echo", factory)], tmp_path / "out", isolate=False,
                                  plots=False, mode=mode)
    fields = summary["room_events"]["echo"]
    assert (fields["map_changes"], fields["reinitializations"], fields["kidnappings"]) == (1, 1, 0)
    after_change, after_request = fields["after_events"]
    assert after_change["event"] == "map_change" and after_change["time_s"] == pytest.approx(105.0)
    assert after_change["outputs"] == 70 and after_change["localized_outputs"] == 70
    assert after_change["false_localized_rate"] == pytest.approx(10 / 70, abs=1e-4)
    assert after_change["correct_rate"] == pytest.approx(60 / 70, abs=1e-4)
    assert after_request["event"] == "reinitialization" and after_request["outputs"] == 81
    assert after_request["false_localized_rate"] == 0.0
    assert fields["false_localized_rate"] == pytest.approx(10 / 201, abs=1e-4)
    table = (tmp_path / "out" / "summary.md").read_text()
    assert "after the map change at 105 s: correct 0.857, LOCALIZED 1, false LOCALIZED 0.143" in table


def test_a_bags_bad_truth_and_refused_map_are_said_not_hidden(kidnap_bag, tmp_path, capsys):
    # NaN ground-truth poses were dropped without a word; a /map refused (resolution 0) read as "no map"
    path, truth = kidnap_bag
    bad = tmp_path / "bad_truth_and_map"
    seen = 0
    with BagWriter(bad) as writer:
        for item in read_bag(path):
            msg = item.msg
            if item.topic == "/ground_truth":
                seen += 1
                if seen % 10 == 0:
                    msg.pose.pose.position.x = float("nan")
            elif item.topic == "/map":
                msg.info.resolution = 0.0
            writer.write(item.topic, msg, item.stamp_ns)
    summary = bench.run_benchmark([bad], [echo_spec(truth, constant_offset)], tmp_path / "out", isolate=False,
                                  plots=False)
    fields = summary["bad_truth_and_map"]["echo"]
    assert "its /map was refused: map resolution must be positive, got 0.0" in fields["error"]
    assert "its /map was refused" in capsys.readouterr().err
    reference = bench.load_reference(bad)
    assert reference.truth_not_finite == seen // 10 and reference.truth_messages == seen
    table = bench.summary_table({"bad_truth_and_map": {"echo": {"outputs": 1, "ground_truth_not_finite": 4}}})
    assert "4 ground-truth poses not finite, left out" in table


def test_command_line_refuses_counts_and_times_that_mean_nothing(kidnap_bag, tmp_path, capsys):
    path, _ = kidnap_bag
    for bad, said in ((["--every", "0"], "--every: must be at least 1, got 0"),
                      (["--max-seconds", "-1"], "--max-seconds: must be a finite number of seconds above 0")):
        with pytest.raises(SystemExit):
            bench.main([str(path), *bad, "--out", str(tmp_path)])
        assert said in capsys.readouterr().err
    afile = tmp_path / "afile"
    afile.write_text("")
    assert bench.main([str(path), "--localizers", "mcl_baseline", "--out", str(afile)]) == 1
    assert "is a file, not a directory" in capsys.readouterr().err
