"""Live equals replay: each laser localizer run live over DDS scores as the replay of the same scenario.

One ``scan_sim`` plays the first 22 s of ``office_kidnap`` (the tour before its first kidnapping at
25.5 s, with the probe's DDS discovery as slack: 220 scans) in real time to every laser localizer
node at once, each configured and activated through ``lifecycle_msgs`` with its packaged params file;
the same 22 s recorded by ``scan_sim``'s recorder are replayed through the benchmark's adapter. Live
drops the scans a node is too slow for (2 loaded cores) and starts after DDS discovery, so the
correct rates are compared within the issue's 5 points, not for equality. PIL, IR and IAL start
globally; MCL from the start pose (tracking, both ways): its global start on this window is a draw
(replayed with random_seed 0-7, 3 of 8 never fix), which would test luck, not the node. Measured
(docs/benchmark.md, "Live and replay"): equal rates here, 0.3-3 points apart on 40-90 s windows
with the kidnapping; with scans updated before the odometry of their stamp, IAL fell to 0.19-0.23
live against 1.0.

The camera localizers (IMA, and the hybrid with its camera cue) run together on the first 32 s of
``office_twins_camera``: the kidnapping into the identical twin office at 25.5 s, which only the camera
tells apart (the hybrid recovers through it 0.6 s later in the replay). Besides the correct rate, live
gives at least 80 % of the replay's outputs (measured: 42-43 of 43 for IMA, 71-74 of 73 for the hybrid).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from robot_localization_suite.ros.tf import TFMessage
from robot_localization_suite.tools.live_check import LiveResult, live_runs, record_scenario, replay_rate, scenario_path

pytestmark = pytest.mark.skipif(TFMessage is None, reason="tf2_msgs is not installed (make builds it)")

LOCALIZERS = ["mcl_baseline", "pil_localizer", "ir_initializer", "ial_localizer"]
TRACKING = ["mcl_baseline"]
SECONDS = 22.0
TOLERANCE = 0.05
CAMERA_LOCALIZERS = ["ima_topo_localizer", "hybrid_localizer"]
CAMERA_SECONDS = 32.0


def live_and_replay(tmp_path: Path, scenario_name: str, names: list[str], seconds: float,
                    tracking: Sequence[str] = ()) -> dict[str, tuple[LiveResult, dict[str, Any], str]]:
    """Each of ``names`` live together and replayed on the recorded seconds; both scored, within 5 points."""
    scenario = scenario_path(scenario_name)
    bag = record_scenario(scenario, tmp_path / scenario.stem, seconds)  # named so per-bag params apply as live
    live = {result.localizer: result for result in live_runs(names, scenario, seconds, tracking=tracking)}
    replay = {name: replay_rate(bag, name, "tracking" if name in tracking else "global") for name in names}
    lines = {name: f"{name}: live {live[name].correct_rate} over {live[name].outputs} outputs, "
                   f"replay {replay[name]['correct_rate']} over {replay[name]['outputs']}" for name in names}
    print("\n" + "\n".join(lines.values()))
    for name in names:
        assert live[name].correct_rate is not None and replay[name]["correct_rate"] is not None, lines[name]
        assert abs(live[name].correct_rate - replay[name]["correct_rate"]) <= TOLERANCE, lines[name]
    return {name: (live[name], replay[name], lines[name]) for name in names}


def test_every_laser_localizer_live_scores_within_5_points_of_its_replay(tmp_path: Path) -> None:
    runs = live_and_replay(tmp_path, "office_kidnap", LOCALIZERS, SECONDS, tracking=TRACKING)
    for live, _, line in runs.values():
        assert live.outputs >= 20, line  # localized live at all (MCL updates every 0.25 m: ~50 in 22 s)


def test_the_camera_localizers_live_score_within_5_points_of_their_replay_through_the_twin_kidnapping(
        tmp_path: Path) -> None:
    runs = live_and_replay(tmp_path, "office_twins_camera", CAMERA_LOCALIZERS, CAMERA_SECONDS)
    for live, replay, line in runs.values():
        assert replay["outputs"] >= 20, line
        assert live.outputs >= 0.8 * replay["outputs"], line
