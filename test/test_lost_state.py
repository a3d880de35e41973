"""LOST means nothing worth using (issue 14): no pose on ``~/pose``, no new ``map -> odom``; diagnostics and candidates still.

The two methods whose LOST used to reach ``~/pose``: ial_localizer (a NaN pose and covariance when no
box is left) and pil_localizer (a pose of no worth, covariance 1e6, when nothing matches). Both are run
on a room map with a real scan, then a scan that fits nowhere: through the adapter, and through the node
with a probe subscribed over DDS.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_fuzz import room

from robot_localization_suite import registry
from robot_localization_suite.core.localizer import LocalizerStatus
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter

BEAMS = 360
TRUTH = np.array([1.8, 1.4, 0.7])
# A scan that fits nowhere in the room, for each method: every beam 0.3 m (a closet: no IAL box is left),
# every beam beyond range_max (nothing for PIL to match).
NOWHERE = {"ial_localizer": 0.3, "pil_localizer": 30.0}


def scan(stamp: float, ranges: np.ndarray) -> Any:
    return conversions.scan_to_msg(stamp, "laser", angle_min=-math.pi, angle_increment=2.0 * math.pi / BEAMS,
                                   ranges=ranges, range_min=0.05, range_max=8.0)


def real_scan(stamp: float) -> Any:
    angles = -math.pi + np.arange(BEAMS) * (2.0 * math.pi / BEAMS)
    return scan(stamp, RayCaster(room(), max_range=8.0).cast(TRUTH, angles).astype(np.float64))


def overrides(name: str, cache: Path) -> dict[str, Any]:
    return {"show_progress": False, "max_range": 8.0, "cache_dir": str(cache)} if name == "pil_localizer" else {}


@pytest.mark.parametrize("name", sorted(NOWHERE))
def test_a_lost_estimate_gives_no_pose_and_no_map_to_odom_through_the_adapter(name: str, tmp_path: Path) -> None:
    plugin = registry.plugin(name)
    logs: list[tuple[str, str]] = []
    adapter = LocalizerAdapter(plugin.create(plugin.load_settings(overrides(name, tmp_path))[1]), node_name=name,
                               log=lambda level, text: logs.append((level, text)))
    assert adapter.on_map_msg(conversions.grid_map_to_msg(room(), 0.0))
    adapter.on_odom_msg(conversions.odometry_to_msg(1.0, TRUTH, frame_id="odom"))
    found = adapter.on_scan_msg(real_scan(1.0))
    assert found is not None and found.estimate.status is not LocalizerStatus.LOST
    assert found.has_pose and found.pose is not None and found.map_to_odom is not None
    adapter.on_odom_msg(conversions.odometry_to_msg(2.0, TRUTH, frame_id="odom"))
    lost = adapter.on_scan_msg(scan(2.0, np.full(BEAMS, NOWHERE[name])))
    assert lost is not None and lost.estimate.status is LocalizerStatus.LOST
    assert not lost.has_pose and lost.pose is None and lost.map_to_odom is None
    assert lost.diagnostics.status[0].message == "LOST"
    assert all(math.isfinite(p.position.x) and math.isfinite(p.position.y) for p in lost.candidates.poses)
    assert not [text for level, text in logs if level == "warn"], logs  # LOST is a state, not a fault


def test_an_initializing_estimate_gives_no_pose(tmp_path: Path) -> None:
    """IAL before its first contraction (too few readings) holds the whole map's box: INITIALIZING, no pose
    (it used to publish the map's centre), diagnostics say so; the next real scan gives a pose."""
    plugin = registry.plugin("ial_localizer")
    adapter = LocalizerAdapter(plugin.create(plugin.load_settings({})[1]), node_name="ial_localizer",
                               log=lambda level, text: None)
    assert adapter.on_map_msg(conversions.grid_map_to_msg(room(), 0.0))
    adapter.on_odom_msg(conversions.odometry_to_msg(1.0, TRUTH, frame_id="odom"))
    ranges = np.full(BEAMS, np.inf)
    ranges[:2] = 1.0  # two readings: fewer than max_outliers + 1, the boxes stay uncontracted
    waiting = adapter.on_scan_msg(scan(1.0, ranges))
    assert waiting is not None and waiting.estimate.status is LocalizerStatus.INITIALIZING
    assert np.all(np.isfinite(waiting.estimate.pose))  # the core still reports the hull's centre ...
    assert not waiting.has_pose and waiting.pose is None and waiting.map_to_odom is None  # ... nobody receives it
    assert waiting.diagnostics.status[0].message == "INITIALIZING"
    adapter.on_odom_msg(conversions.odometry_to_msg(2.0, TRUTH, frame_id="odom"))
    found = adapter.on_scan_msg(real_scan(2.0))
    assert found is not None and found.estimate.status is not LocalizerStatus.INITIALIZING and found.has_pose


class Probe:
    """A node of the test's own, subscribed over DDS to what the localizer publishes."""

    def __init__(self, rclpy: Any, name: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped

        from robot_localization_suite.ros.qos import POSE_QOS, RELIABLE_QOS, TF_QOS
        from robot_localization_suite.ros.tf import TFMessage, transform_from_msg

        self.node = rclpy.create_node(f"{name}_lost_probe")
        self.poses: list[Any] = []
        self.diagnostics: list[str] = []
        self.candidates: list[Any] = []
        self.map_odom: list[np.ndarray] = []

        def on_tf(msg: Any) -> None:
            for item in msg.transforms:
                transform = transform_from_msg(item)
                if (transform.parent, transform.child) == ("map", "odom"):
                    self.map_odom.append(transform.pose)

        self.node.create_subscription(PoseWithCovarianceStamped, f"/{name}/pose", self.poses.append, POSE_QOS)
        self.node.create_subscription(PoseArray, f"/{name}/candidates", self.candidates.append, RELIABLE_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics",
                                      lambda msg: self.diagnostics.extend(s.message for s in msg.status
                                                                          if s.hardware_id == name), RELIABLE_QOS)
        if TFMessage is not None:
            self.node.create_subscription(TFMessage, "/tf", on_tf, TF_QOS)


@pytest.mark.parametrize("name", sorted(NOWHERE))
def test_a_lost_node_publishes_diagnostics_and_candidates_but_no_pose(name: str, tmp_path: Path) -> None:
    rclpy = pytest.importorskip("rclpy")
    from rclpy.executors import SingleThreadedExecutor

    from robot_localization_suite.nodes.localizer_node import LocalizerNode
    from robot_localization_suite.ros.tf import TFMessage

    args = [name, "--ros-args"] + [item for key, value in overrides(name, tmp_path).items()
                                   for item in ("-p", f"{key}:={str(value).lower() if isinstance(value, bool) else value}")]
    rclpy.init(args=args)
    node = LocalizerNode(registry.plugin(name))
    probe = Probe(rclpy, name)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(probe.node)

    def spin_until(done: Callable[[], bool], timeout: float = 20.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not done():
            executor.spin_once(timeout_sec=0.05)
        return done()

    try:
        node.trigger_configure()
        node.trigger_activate()
        assert spin_until(lambda: node.count_subscribers(f"/{name}/pose") >= 1
                          and node.count_subscribers("/diagnostics") >= 1)
        node._on_map(conversions.grid_map_to_msg(room(), 0.0))
        assert node._work.wait(60)  # a map from the topic is set up in the background
        node._after_work()
        node._on_odom(conversions.odometry_to_msg(1.0, TRUTH, frame_id="odom"))
        node._on_scan(real_scan(1.0))
        if node._work.busy:  # the first scan of this scanner starts PIL's precomputation in the background
            assert node._work.wait(60)
            node._after_work()
            node._on_odom(conversions.odometry_to_msg(1.5, TRUTH, frame_id="odom"))
            node._on_scan(real_scan(1.5))
        assert spin_until(lambda: len(probe.poses) == 1 and len(probe.diagnostics) == 1 and len(probe.candidates) == 1)
        pose = conversions.pose_from_pose_msg(probe.poses[0].pose.pose)
        assert np.all(np.isfinite(pose)) and probe.diagnostics[0] != "LOST"
        if TFMessage is not None:
            assert spin_until(lambda: len(probe.map_odom) == 1)
        node._on_odom(conversions.odometry_to_msg(2.0, TRUTH, frame_id="odom"))
        node._on_scan(scan(2.0, np.full(BEAMS, NOWHERE[name])))
        assert spin_until(lambda: len(probe.diagnostics) == 2 and len(probe.candidates) == 2)
        assert probe.diagnostics[1] == "LOST"
        spin_until(lambda: len(probe.poses) > 1, 1.0)
        assert len(probe.poses) == 1, "a LOST estimate was published on ~/pose"
        if TFMessage is not None:  # map -> odom is sent again unchanged, as on a scan without an update
            assert spin_until(lambda: len(probe.map_odom) == 2)
            np.testing.assert_allclose(probe.map_odom[1], probe.map_odom[0])
    finally:
        executor.shutdown()
        probe.node.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown()
