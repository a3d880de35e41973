"""The demo's monitor (launch/demo.py): rows without stale or non-finite numbers, the in-place display."""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from robot_localization_suite.launch.demo import NodeLogs
from robot_localization_suite.launch.demo_monitor import DemoMonitor, LocalizerTrack, MonitorDisplay, row_text

_ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)


@given(
    status=st.sampled_from(["-", "LOCALIZED", "AMBIGUOUS", "INITIALIZING", "LOST"]),
    error=st.none() | st.tuples(_ANY_FLOAT, _ANY_FLOAT),
    error_stamp=st.none() | _ANY_FLOAT,
    pose=st.none() | st.tuples(_ANY_FLOAT, _ANY_FLOAT, _ANY_FLOAT),
    updates=st.lists(_ANY_FLOAT, max_size=3),
    origin=_ANY_FLOAT,
)
def test_a_row_never_prints_nan(status, error, error_stamp, pose, updates, origin) -> None:  # noqa: ANN001
    track = LocalizerTrack("loc", status=status, last_error=error, last_error_stamp=error_stamp,
                           last_pose=None if pose is None else np.array(pose), update_ms=list(updates))
    text = row_text(track, origin).lower()
    assert "nan" not in text and "inf" not in text, text


def test_a_lost_localizer_shows_lost_without_the_older_estimates_numbers() -> None:
    monitor = DemoMonitor(["ial_localizer"])
    for t in np.arange(0.0, 2.0, 0.1):
        monitor.on_truth(100.0 + t, np.array([t, 0.0, 0.0]))
    monitor.on_estimate("ial_localizer", 100.5, np.array([0.5, 0.01, 0.0]))
    monitor.on_diagnostics("ial_localizer", "LOCALIZED", 3.0)
    block = monitor.status_lines()
    (row,) = [line for line in block if "ial_localizer" in line]
    assert "LOCALIZED" in row and "0.01 m" in row and "(t =    0.5 s)" in row and "3.0 ms" in row
    assert any("error vs truth at the estimate's stamp" in line for line in block)
    # A LOST update brings no pose (and a non-finite pose is never shown nor scored).
    monitor.on_estimate("ial_localizer", 101.0, np.array([math.nan, math.nan, math.nan]))
    monitor.on_diagnostics("ial_localizer", "LOST", 4.0)
    (row,) = [line for line in monitor.status_lines() if "ial_localizer" in line]
    assert "LOST" in row and " m " not in row and "nan" not in row.lower(), row
    (summary,) = monitor.summary_rows()
    assert summary["outputs"] == 2 and summary["scored"] == 1


def test_the_display_redraws_in_place_on_a_terminal_and_prints_lines_elsewhere(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "40")
    stream = io.StringIO()
    display = MonitorDisplay(stream, redraw=True)
    display.update([], ["a", "b"])
    display.message("kept")
    display.update(["*** event ***"], ["c", "d"])
    text = stream.getvalue()
    # The two-line block is erased (cursor up 2, clear) before the message and before the new block.
    assert text.count("\x1b[2F\x1b[J") == 2
    assert text.endswith("[demo] *** event ***\n[demo] c\n[demo] d\n")
    # A block line wider than the terminal is cut (a wrapped line would break the redraw), a message is not.
    display.update([], ["x" * 100])
    assert stream.getvalue().endswith("\x1b[J[demo] " + "x" * 32 + "\n")
    plain = io.StringIO()
    display = MonitorDisplay(plain, redraw=False)
    display.update([], ["a", "b"])
    display.message("kept")
    display.update(["*** event ***"], ["c", "d"])
    display.update([], ["x" * 100])
    assert "\x1b" not in plain.getvalue() and plain.getvalue().endswith("x" * 100 + "\n")
    display.finish()
    assert plain.getvalue().splitlines() == ["[demo] a", "[demo] b", "[demo] kept", "[demo] *** event ***",
                                             "[demo] c", "[demo] d", "[demo] " + "x" * 100]


def test_node_output_goes_to_one_log_per_node(tmp_path) -> None:  # noqa: ANN001
    logs = NodeLogs(tmp_path / "logs")
    logs.write("scan_sim", "one")
    logs.write("mcl_baseline", "two")
    logs.write("scan_sim", "three")
    logs.close()
    assert (tmp_path / "logs" / "scan_sim.log").read_text() == "one\nthree\n"
    assert (tmp_path / "logs" / "mcl_baseline.log").read_text() == "two\n"


# -- a short demo run: its recording and layouts ----------------------------------------------------
_RUN_LOCALIZERS = ["mcl_baseline", "ial_localizer"]  # IAL also publishes its boxes as markers


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("demo")
    # x2, not x4: at x4 under the full suite's load the localizers' container (MCL and IAL in one process)
    # fell 2-4.5 s behind its odometry, IAL gave 121 poses instead of ~700 and MCL never had its fix.
    result = subprocess.run(
        [sys.executable, "-m", "robot_localization_suite.launch.demo", "--localizers", ",".join(_RUN_LOCALIZERS),
         "--speed", "2", "--duration", "25", "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    text = result.stdout + result.stderr
    assert result.returncode == 0, text
    (run_dir,) = out.iterdir()
    return run_dir, text


def test_the_demo_output_has_no_nan_and_no_node_lines(demo_run: tuple[Path, str]) -> None:
    _run_dir, text = demo_run
    assert "nan" not in text.lower(), text
    assert all(line.startswith("[demo] ") for line in text.splitlines()), text


def test_the_recording_holds_every_topic_with_ros2msg_schemas(demo_run: tuple[Path, str]) -> None:
    from mcap.reader import make_reader

    from robot_localization_suite.ros.recording import error_topic, run_topics

    run_dir, text = demo_run
    (path,) = (run_dir / "recording").glob("*.mcap")
    assert f"recording: {run_dir / 'recording'}" in text
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = summary.statistics.channel_message_counts
    channels = {channel.topic: channel for channel in summary.channels.values()}
    expected = {topic.name for topic in run_topics(_RUN_LOCALIZERS, camera=False)}
    expected |= {error_topic(name) for name in _RUN_LOCALIZERS}
    assert {"/map", "/scan", "/ground_truth", "/tf", "/tf_static", "/diagnostics", "/ial_localizer/boxes",
            "/mcl_baseline/pose", "/mcl_baseline/candidates"} <= expected
    assert expected <= set(channels), sorted(expected - set(channels))
    for topic in expected:
        channel = channels[topic]
        schema = summary.schemas[channel.schema_id]
        assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr"), topic
        assert schema.data, topic
        assert counts[channel.id] >= 1, topic
    assert summary.schemas[channels["/ial_localizer/boxes"].schema_id].name == "visualization_msgs/msg/MarkerArray"
    # /tf holds scan_sim's odom -> base_link and the true map -> odom, never a localizer's.
    from robot_localization_suite.ros.bag import read_bag

    links = {(t.header.frame_id, t.child_frame_id) for m in read_bag(run_dir / "recording", ["/tf"])
             for t in m.msg.transforms}
    assert links == {("odom", "base_link"), ("map", "odom")}


def test_the_layouts_are_json_naming_recorded_topics(demo_run: tuple[Path, str]) -> None:
    from robot_localization_suite.launch.foxglove_layout import LAYOUT_FILE, demo_layout, layout_topics
    from robot_localization_suite.registry import PLUGINS, config_dir
    from robot_localization_suite.ros.bag import bag_topics

    packaged = json.loads((config_dir() / LAYOUT_FILE).read_text())
    assert packaged == json.loads(json.dumps(demo_layout(list(PLUGINS)))), "rewrite it: python -m ...foxglove_layout"
    run_dir, _text = demo_run
    layout = json.loads((run_dir / "foxglove_layout.json").read_text())
    named = layout_topics(layout)
    assert {"/map", "/ground_truth", "/mcl_baseline/pose", "/evaluation/mcl_baseline/error"} <= named
    assert named <= set(bag_topics(run_dir / "recording")), sorted(named - set(bag_topics(run_dir / "recording")))
    # The packaged layout names the same topics for every localizer.
    assert {f"/{name}/pose" for name in PLUGINS} <= layout_topics(packaged)


def test_the_run_ends_with_a_picture_next_to_the_recording(demo_run: tuple[Path, str]) -> None:
    import matplotlib.image

    run_dir, text = demo_run
    picture = run_dir / "trajectories.png"
    assert f"picture: {picture}" in text
    image = matplotlib.image.imread(picture)
    assert image.shape[0] > 400 and image.shape[1] > 400
    assert image[..., :3].std() > 0.05  # a map and paths, not a blank canvas


def test_a_camera_run_s_layout_shows_the_images() -> None:
    from robot_localization_suite.launch.foxglove_layout import demo_layout, layout_topics
    from robot_localization_suite.ros.recording import run_topics

    layout = demo_layout(["ima_topo_localizer"], camera=True)
    assert "/camera/image_raw" in layout_topics(layout)
    recorded = {topic.name for topic in run_topics(["ima_topo_localizer"], camera=True)}
    named = {name for name in layout_topics(layout) if not name.startswith("/evaluation/")}
    assert named <= recorded, sorted(named - recorded)
    assert "/camera/image_raw" not in layout_topics(demo_layout(["mcl_baseline"]))
