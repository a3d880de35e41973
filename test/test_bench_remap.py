"""A user's bag as it comes: ``rls_bench --remap FROM:=TO`` reads other topic names as the benchmark's, and a bag
without ``/odom`` gives its odometry on ``/tf`` (as a node with ``odom_source: tf`` reads it)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped

from robot_localization_suite.registry import config_dir
from robot_localization_suite.ros.bag import BagWriter, bag_topics, read_bag
from robot_localization_suite.tools import bench
from robot_localization_suite.tools.live_check import record_scenario

RENAMED = {"/scan": "/base_scan", "/ground_truth": "/base_pose_ground_truth"}


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """The office tour's first 8 s; the same bag with its scans and truth (a PoseStamped) under other names beside
    a /scan of nothing but no-returns (which the remapped /base_scan must hide); and the same bag without /odom."""
    folder = tmp_path_factory.mktemp("remap")
    source = record_scenario(config_dir() / "scenarios" / "office_kidnap.yaml", folder / "office", 8.0)
    renamed, tf_only = folder / "office_renamed", folder / "office_tf_only"
    with BagWriter(renamed) as writer:
        for item in read_bag(source):
            msg = item.msg
            if item.topic == "/ground_truth":  # the truth as motion capture gives it
                msg = PoseStamped(header=msg.header, pose=msg.pose.pose)
            writer.write(RENAMED.get(item.topic, item.topic), msg, item.stamp_ns)
            if item.topic == "/scan":  # a second laser that sees nothing, on the name the benchmark reads
                blind = item.msg
                blind.ranges = [float("inf")] * len(blind.ranges)
                writer.write("/scan", blind, item.stamp_ns)
    with BagWriter(tf_only) as writer:
        for item in read_bag(source):
            if item.topic != "/odom":
                writer.write(item.topic, item.msg, item.stamp_ns)
    return source, renamed, tf_only


def _bench(bag: Path, out: Path, *extra: str) -> dict:
    assert bench.main([str(bag), "--localizers", "mcl_baseline", "--mode", "tracking", "--workers", "0",
                       "--no-plots", "--out", str(out), *extra]) == 0
    (runs,) = json.loads((out / "summary.json").read_text()).values()
    return runs["mcl_baseline"]


def test_a_remapped_bag_scores_as_the_bag_it_came_from(bags: tuple[Path, Path, Path], tmp_path: Path) -> None:
    source, renamed, _ = bags
    assert {"/scan", "/base_scan", "/base_pose_ground_truth"} <= set(bag_topics(renamed))
    remap = ["--remap", "/base_scan:=/scan", "--remap", "base_pose_ground_truth:=/ground_truth"]  # "/" optional
    results = {"source": _bench(source, tmp_path / "source"), "renamed": _bench(renamed, tmp_path / "renamed", *remap)}
    for field in ("outputs", "inputs", "correct_rate", "rmse_xy_m", "map_coverage_median"):
        assert results["renamed"][field] == results["source"][field], field
    assert results["source"]["correct_rate"] == 1.0
    # without the remap, the blind /scan is read and there is no ground truth to score against
    reference = bench.load_reference(renamed)
    assert reference.ground_truth is None and reference.has_scan
    remapped = bench.load_reference(renamed, {"/base_scan": "/scan", "/base_pose_ground_truth": "/ground_truth"})
    assert remapped.ground_truth is not None
    assert np.array_equal(remapped.ground_truth.poses, bench.load_reference(source).ground_truth.poses)


@pytest.mark.parametrize(("item", "message"), [
    ("/base_scan", "--remap expects FROM:=TO"),
    ("/base_scan:=", "--remap expects FROM:=TO"),
    ("/base_scan:=/laser", "the benchmark reads no /laser; it reads /scan, /odom"),
])
def test_a_bad_remap_is_refused_naming_it(bags: tuple[Path, Path, Path], tmp_path: Path, item: str, message: str,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    assert bench.main([str(bags[1]), "--remap", item, "--out", str(tmp_path)]) != 0
    assert message in capsys.readouterr().err


def test_a_bag_without_odom_gives_its_odometry_on_tf(bags: tuple[Path, Path, Path], tmp_path: Path) -> None:
    source, _, tf_only = bags
    assert "/odom" not in bag_topics(tf_only) and "/tf" in bag_topics(tf_only)
    with_odom, from_tf = bench.load_reference(source), bench.load_reference(tf_only)
    assert from_tf.odometry is not None and with_odom.odometry is not None
    assert np.allclose(from_tf.odometry.stamps, with_odom.odometry.stamps)
    assert np.allclose(from_tf.odometry.poses, with_odom.odometry.poses, atol=1e-9)
    expected, got = _bench(source, tmp_path / "source"), _bench(tf_only, tmp_path / "tf_only")
    assert got["odometry_from"] == "/tf (odom -> base_link)" and "odometry_from" not in expected
    for field in ("outputs", "inputs", "correct_rate", "rmse_xy_m"):
        assert got[field] == expected[field], field
    assert "odometry from /tf (odom -> base_link)" in (tmp_path / "tf_only" / "summary.md").read_text()
