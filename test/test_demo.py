"""The demo's monitor (launch/demo.py): rows without stale or non-finite numbers, the in-place display."""

from __future__ import annotations

import io
import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from robot_localization_suite.launch.demo import DemoMonitor, LocalizerTrack, MonitorDisplay, NodeLogs, row_text

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


def test_the_display_redraws_in_place_on_a_terminal_and_prints_lines_elsewhere() -> None:
    stream = io.StringIO()
    display = MonitorDisplay(stream, redraw=True)
    display.update([], ["a", "b"])
    display.message("kept")
    display.update(["*** event ***"], ["c", "d"])
    text = stream.getvalue()
    # The two-line block is erased (cursor up 2, clear) before the message and before the new block.
    assert text.count("\x1b[2F\x1b[J") == 2
    assert text.endswith("[demo] *** event ***\n[demo] c\n[demo] d\n")
    plain = io.StringIO()
    display = MonitorDisplay(plain, redraw=False)
    display.update([], ["a", "b"])
    display.message("kept")
    display.update(["*** event ***"], ["c", "d"])
    assert "\x1b" not in plain.getvalue()
    assert plain.getvalue().splitlines() == ["[demo] a", "[demo] b", "[demo] kept", "[demo] *** event ***",
                                             "[demo] c", "[demo] d"]


def test_node_output_goes_to_one_log_per_node(tmp_path) -> None:  # noqa: ANN001
    logs = NodeLogs(tmp_path / "logs")
    logs.write("scan_sim", "one")
    logs.write("mcl_baseline", "two")
    logs.write("scan_sim", "three")
    logs.close()
    assert (tmp_path / "logs" / "scan_sim.log").read_text() == "one\nthree\n"
    assert (tmp_path / "logs" / "mcl_baseline.log").read_text() == "two\n"
