"""The ial_localizer plugin: params file, the adapter's mount, ~/boxes markers, bag replay, the shared node."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcl_test_world import WAYPOINTS, _follow, office_map
from visualization_msgs.msg import Marker, MarkerArray

from robot_localization_suite import registry
from robot_localization_suite.core.ial.localizer import IALSettings, IntervalLocalizer
from robot_localization_suite.core.localizer import LocalizerStatus
from robot_localization_suite.core.metrics import boxes_contain
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.scan import LaserMount
from robot_localization_suite.core.se2 import compose
from robot_localization_suite.core.settings import parameters
from robot_localization_suite.core.sim.config import OdometryConfig
from robot_localization_suite.core.sim.simulator import OdometrySimulator
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter
from robot_localization_suite.ros.bag import read_bag
from robot_localization_suite.ros.extras import IAL_BOXES, boxes_markers

ANGLES = -math.pi + 2.0 * math.pi * np.arange(360) / 360


def _ial(**overrides: object) -> IntervalLocalizer:
    plugin = registry.plugin("ial_localizer")
    return plugin.create(plugin.load_settings(overrides)[1])


def test_the_plugin_follows_the_packaged_params_file_and_the_adapter_gives_it_the_mount(repo_root: Path) -> None:
    localizer = _ial()
    assert isinstance(localizer, IntervalLocalizer)
    config = yaml.safe_load((repo_root / "config" / "ial_localizer.yaml").read_text())["ial_localizer"]["ros__parameters"]
    node_parameters = {param.name for param in parameters(registry.NodeSettings)}  # base_frame_id, ...
    for name, value in config.items():
        if name not in node_parameters:
            assert getattr(localizer.settings, name) == pytest.approx(value), name
    assert localizer.mount == LaserMount()
    mounted = _ial(max_outliers=3)
    LocalizerAdapter(mounted, node_name="ial_localizer", log=lambda *_: None, mount=LaserMount(0.2, 0.0, 0.1))
    assert mounted.mount == LaserMount(0.2, 0.0, 0.1) and mounted.settings.max_outliers == 3
    with pytest.raises(ValueError, match="range_error"):
        _ial(range_error=-1.0)


def test_build_extras_draws_each_box_its_headings_and_the_hull() -> None:
    office = office_map()
    scan_ranges = RayCaster(office, max_range=10.0).cast(np.array([3.0, 4.5, 0.3]), ANGLES).astype(np.float64)
    from robot_localization_suite.core.scan import Scan

    estimate = IntervalLocalizer(IALSettings(), office).global_fix(Scan(2.5, ANGLES.copy(), scan_ranges, 0.1, 10.0))
    count = estimate.details["box_count"]
    assert count >= 1
    assert set(IAL_BOXES) == {"boxes"} and IAL_BOXES["boxes"].kind is MarkerArray
    markers = IAL_BOXES["boxes"].build(estimate)
    assert isinstance(markers, MarkerArray)
    assert markers.markers[0].action == Marker.DELETEALL
    by_namespace = {m.ns: m for m in markers.markers[1:]}
    assert len(by_namespace["ial_boxes"].points) == 8 * count  # four segments per box
    assert len(by_namespace["ial_headings"].points) == 4 * count  # two rays per box
    assert len(by_namespace["ial_hull"].points) == 8
    box = estimate.boxes[0]
    xs = [p.x for p in by_namespace["ial_boxes"].points[:8]]
    assert min(xs) == pytest.approx(box[0, 0]) and max(xs) == pytest.approx(box[0, 1])
    assert all(m.header.frame_id == "map" for m in markers.markers)
    assert markers.markers[1].header.stamp.sec == 2 and markers.markers[1].header.stamp.nanosec == 500_000_000
    assert len(boxes_markers(estimate, max_boxes=1).markers[1].points) == 8
    # an empty list (LOST) only clears the display
    estimate = replace(estimate, boxes=np.zeros((0, 3, 2)))
    assert len(boxes_markers(estimate).markers) == 1


def test_the_bounded_floor_bag_replayed_through_the_adapter_keeps_the_truth_in_the_boxes(repo_root: Path) -> None:
    # What rls_bench does: bag order, the node's adapter, the config's parameters. Both kidnappings of
    # this bag are visible at once, so every update, kidnappings included, must contain the truth.
    bag = repo_root / "bags" / "floor_kidnap_bounded"
    localizer = _ial()
    adapter = LocalizerAdapter(localizer, node_name="ial_localizer", log=lambda level, text: None)
    truth = None
    contained, restarts, statuses = [], [], []
    for message in read_bag(bag, ["/map", "/odom", "/ground_truth", "/scan"]):
        if message.topic == "/map":
            adapter.on_map_msg(message.msg)
        elif message.topic == "/odom":
            adapter.on_odom_msg(message.msg)
        elif message.topic == "/ground_truth":
            truth = conversions.odometry_from_msg(message.msg)[1]
        else:
            output = adapter.on_scan_msg(message.msg)
            details = output.estimate.details
            contained.append(boxes_contain(output.estimate.boxes, truth))
            restarts.append(details["restarted"])
            statuses.append(output.estimate.status)
    assert len(contained) == 1395
    assert all(contained), np.flatnonzero(~np.array(contained))[:10]
    assert sum(restarts) == 2  # one restart per kidnapping
    assert statuses.count(LocalizerStatus.LOCALIZED) > 0.7 * len(statuses)


def test_boxes_are_published_in_the_base_frame_with_a_laser_mount() -> None:
    office = office_map()
    mount = LaserMount(0.25, 0.05, 0.3)
    rng = np.random.default_rng(3)
    truth = _follow(WAYPOINTS, 0, 60, 0.05)
    laser = compose(truth, mount.pose)
    ranges = RayCaster(office, max_range=10.0).cast(laser, ANGLES).astype(np.float64)
    ranges = np.where(np.isfinite(ranges), ranges + rng.uniform(-0.04, 0.04, ranges.shape), np.inf)
    odometry = OdometrySimulator(OdometryConfig(model="bounded", relative_translation=0.05, absolute_translation=0.002,
                                                relative_rotation=0.05, absolute_rotation=0.002), rng)
    localizer = _ial(max_beams=36, max_outliers=2)
    adapter = LocalizerAdapter(localizer, node_name="ial_localizer", log=lambda level, text: None, mount=mount)
    adapter.set_map(office)
    for k in range(len(truth)):
        odom = odometry.pose.copy() if k == 0 else odometry.step(truth[k - 1], truth[k])
        adapter.on_odom_msg(conversions.odometry_to_msg(0.1 * k, odom, frame_id="odom"))
        output = adapter.on_scan_msg(conversions.scan_to_msg(0.1 * k, "laser", angle_min=ANGLES[0],
                                                             angle_increment=ANGLES[1] - ANGLES[0], ranges=ranges[k],
                                                             range_min=0.1, range_max=10.0))
        boxes = output.estimate.boxes
        assert boxes_contain(boxes, truth[k]), k  # base pose in the base-frame boxes
        assert not output.estimate.details["restarted"], k
    assert np.hypot(*(output.estimate.pose[:2] - truth[-1, :2])) < 0.1  # the adapter's base pose


def test_the_node_handles_a_message_feed_its_extras_and_its_services() -> None:
    rclpy = pytest.importorskip("rclpy")
    from std_srvs.srv import Empty

    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    office = office_map()
    truth = _follow(WAYPOINTS, 0, 30, 0.05)
    ranges = RayCaster(office, max_range=10.0).cast(truth, ANGLES).astype(np.float64)
    rclpy.init(args=["ial_localizer", "--ros-args", "-p", "max_outliers:=4", "-p", "max_beams:=40"])
    node = LocalizerNode(registry.plugin("ial_localizer"), extras=IAL_BOXES)
    node.trigger_configure()
    node.trigger_activate()
    published = []
    try:
        for param in parameters(IALSettings):
            assert node.has_parameter(param.name), param.name
        assert "boxes" in node.extra_pubs
        localizer = node.localizer
        assert localizer.settings.max_outliers == 4 and localizer.settings.max_beams == 40
        node.publish = lambda output, *_: published.append(output) if output is not None else None  # type: ignore[method-assign]
        node.adapter.on_map_msg(conversions.grid_map_to_msg(office, 0.0))
        for k in range(len(truth)):
            odom = truth[k] - truth[0]  # exact odometry, in an odom frame aligned with the map
            node.adapter.on_odom_msg(conversions.odometry_to_msg(0.1 * k, odom, frame_id="odom"))
            node._on_scan(conversions.scan_to_msg(0.1 * k, "laser", angle_min=ANGLES[0],
                                                  angle_increment=ANGLES[1] - ANGLES[0], ranges=ranges[k],
                                                  range_min=0.1, range_max=10.0))
        # bad input on the same path: a scan of NaNs is skipped, odometry stepping back in time is ignored
        node._on_scan(conversions.scan_to_msg(100.0, "laser", angle_min=-1.0, angle_increment=0.01,
                                              ranges=np.full(200, np.nan), range_min=0.1, range_max=10.0))
        node.adapter.on_odom_msg(conversions.odometry_to_msg(0.0, np.zeros(3), frame_id="odom"))
        assert len(published) == len(truth)
        last = published[-1]
        assert last.estimate.status is LocalizerStatus.LOCALIZED
        assert boxes_contain(last.estimate.boxes, truth[-1])
        assert isinstance(last.extras["boxes"], MarkerArray)
        values = {kv.key: kv.value for kv in last.diagnostics.status[0].values}
        assert int(values["box_count"]) == last.estimate.details["box_count"]
        assert float(values["hull_width_x"]) < 0.3
        node._on_reinitialize(Empty.Request(), Empty.Response())
        assert localizer.boxes is None
        node._on_nomotion(Empty.Request(), Empty.Response())
        assert localizer.odometry.forced
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
