"""``replay_localizer(..., record_dir=...)``: a benchmark run as one MCAP that Foxglove opens."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader

from robot_localization_suite.registry import config_dir
from robot_localization_suite.ros.bag import read_bag
from robot_localization_suite.ros.recording import error_topic
from robot_localization_suite.tools import bench
from robot_localization_suite.tools.bench import load_reference, registry_spec, replay_localizer, resolve_map
from robot_localization_suite.tools.live_check import record_scenario


def test_a_replay_records_its_inputs_outputs_errors_and_the_true_map_to_odom(tmp_path: Path) -> None:
    bag = record_scenario(config_dir() / "scenarios" / "office_kidnap.yaml", tmp_path / "office", 6.0)
    reference = load_reference(bag)
    grid_map, _ = resolve_map(reference, None)
    record = replay_localizer(reference, registry_spec("ial_localizer"), grid_map, mode="tracking", sample_rss=False,
                              record_dir=tmp_path / "recordings")
    assert len(record.poses) > 10
    (run_dir,) = (tmp_path / "recordings").iterdir()
    assert run_dir.name == f"{reference.name}_ial_localizer_tracking"
    (path,) = run_dir.glob("*.mcap")
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {channel.topic: summary.statistics.channel_message_counts[cid] for cid, channel in summary.channels.items()}
    for channel in summary.channels.values():
        assert summary.schemas[channel.schema_id].encoding == "ros2msg" and channel.message_encoding == "cdr"
    inputs = {"/map", "/scan", "/odom", "/ground_truth", "/tf", "/tf_static"}
    outputs = {"/ial_localizer/pose", "/ial_localizer/candidates", "/ial_localizer/boxes", "/diagnostics",
               error_topic("ial_localizer")}
    assert inputs | outputs <= set(counts), sorted(counts)
    # Every output has its candidates, diagnostics and boxes; a pose and an error when it has a pose.
    outputs_count = len(record.poses)
    assert counts["/ial_localizer/candidates"] == counts["/diagnostics"] == counts["/ial_localizer/boxes"] == outputs_count
    lost = record.statuses.count("LOST") + record.statuses.count("INITIALIZING")  # no pose in either state
    assert counts["/ial_localizer/pose"] == counts[error_topic("ial_localizer")] == outputs_count - lost
    assert counts["/scan"] == counts["/odom"] == counts["/ground_truth"]
    # /tf: the bag's odom -> base_link and, per step, the true map -> odom; stamps on the 2025 clock, not 1970.
    links: dict[tuple[str, str], int] = {}
    for item in read_bag(run_dir, ["/tf"]):
        assert item.stamp_ns > 1_700_000_000 * 10**9
        for transform in item.msg.transforms:
            key = (transform.header.frame_id, transform.child_frame_id)
            links[key] = links.get(key, 0) + 1
    assert links == {("odom", "base_link"): counts["/odom"], ("map", "odom"): counts["/odom"]}


def test_rls_bench_record_writes_one_recording_per_run(tmp_path: Path) -> None:
    """``rls_bench --record DIR``: each (bag, localizer) run, in its child process, leaves its MCAP in DIR."""
    bag = record_scenario(config_dir() / "scenarios" / "office_kidnap.yaml", tmp_path / "office", 4.0)
    assert bench.main([str(bag), "--localizers", "pil_localizer", "ial_localizer", "--mode", "tracking", "--workers",
                       "0", "--no-plots", "--out", str(tmp_path / "out"), "--record", str(tmp_path / "rec")]) == 0
    assert sorted(path.name for path in (tmp_path / "rec").iterdir()) == [
        "office_ial_localizer_tracking", "office_pil_localizer_tracking"]
    for localizer in ("ial_localizer", "pil_localizer"):
        run_dir = tmp_path / "rec" / f"office_{localizer}_tracking"
        assert len(list(run_dir.glob("*.mcap"))) == 1
        errors = [message for message in read_bag(run_dir, [error_topic(localizer)])]
        assert errors, f"{localizer}: no scored output recorded"
