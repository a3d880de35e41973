"""Live equals replay: each laser localizer run live over DDS scores as the replay of the same scenario.

One ``scan_sim`` plays the first 25 s of ``office_kidnap`` (the tour up to its first kidnapping:
250 scans, global start) in real time to every laser localizer node at once, each configured and
activated through ``lifecycle_msgs`` with its packaged params file; the same 25 s recorded by
``scan_sim``'s recorder are replayed through the benchmark's adapter. Live drops scans the nodes are
too slow for (2 loaded cores) and starts them after DDS discovery, so the correct rates are compared
within the issue's 5 points, not for equality. Measured (docs/benchmark.md, "Live and replay"): equal
rates on this window, 0.3-3 points apart on 40-90 s windows with the kidnapping; with scans updated
before the odometry of their stamp (the node's wait removed) IAL fell to 0.19 live against 1.0.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from robot_localization_suite.ros.tf import TFMessage
from robot_localization_suite.tools.live_check import live_runs, record_scenario, replay_rate, scenario_path

pytestmark = pytest.mark.skipif(TFMessage is None, reason="tf2_msgs is not installed (make builds it)")

LOCALIZERS = ["mcl_baseline", "pil_localizer", "ir_initializer", "ial_localizer"]
SECONDS = 25.0  # office_kidnap's first kidnapping is at 25.5 s
TOLERANCE = 0.05


def test_every_laser_localizer_live_scores_within_5_points_of_its_replay(tmp_path: Path) -> None:
    scenario = scenario_path("office_kidnap")
    bag = record_scenario(scenario, tmp_path / "bag", SECONDS)
    live = {result.localizer: result for result in live_runs(LOCALIZERS, scenario, SECONDS)}
    replay = {name: replay_rate(bag, name) for name in LOCALIZERS}
    lines = {name: f"{name}: live {live[name].correct_rate} over {live[name].outputs} outputs, "
                   f"replay {replay[name]['correct_rate']} over {replay[name]['outputs']}" for name in LOCALIZERS}
    print("\n" + "\n".join(lines.values()))
    for name in LOCALIZERS:
        assert live[name].outputs >= 20, lines[name]  # localized live at all (MCL updates every 0.25 m: ~50 in 25 s)
        assert live[name].correct_rate is not None and replay[name]["correct_rate"] is not None, lines[name]
        assert abs(live[name].correct_rate - replay[name]["correct_rate"]) <= TOLERANCE, lines[name]
