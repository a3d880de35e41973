"""The mcl_baseline plugin and the shared node running it, fed messages in-process."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mcl_test_world import drive, office_map

from robot_localization_suite import registry
from robot_localization_suite.core.localizer import LocalizerStatus
from robot_localization_suite.core.mcl.localizer import MclSettings, MonteCarloLocalizer
from robot_localization_suite.core.settings import parameters
from robot_localization_suite.ros import conversions


def test_the_plugin_builds_the_filter_from_the_packaged_params_file() -> None:
    plugin = registry.plugin("mcl_baseline")
    localizer = plugin.create(plugin.load_settings()[1])
    assert isinstance(localizer, MonteCarloLocalizer)
    assert localizer.settings == MclSettings()  # the packaged file repeats the defaults


def test_the_node_handles_a_message_feed_and_its_services() -> None:
    rclpy = pytest.importorskip("rclpy")
    from std_srvs.srv import Empty

    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    office = office_map()
    run = drive(office, steps=80, seed=2)
    rclpy.init(args=["mcl_baseline", "--ros-args", "-p", "max_particles:=3000", "-p", "min_particles:=200"])
    node = LocalizerNode(registry.plugin("mcl_baseline"))
    published = []
    try:
        for param in parameters(MclSettings):
            assert node.has_parameter(param.name), param.name
        assert node.describe_parameter("sigma_hit").floating_point_range[0].to_value == 100.0
        localizer = node.localizer
        assert localizer.settings.max_particles == 3000
        node.publish = lambda output: published.append(output) if output is not None else None  # type: ignore[method-assign]
        node.adapter.on_map_msg(conversions.grid_map_to_msg(office, 0.0))
        node.adapter.on_initial_pose_msg(
            conversions.initial_pose_to_msg(0.0, run.truth[0], np.diag([0.05**2, 0.05**2, 0.05**2]))
        )
        for k in range(len(run.stamps)):
            node.adapter.on_odom_msg(conversions.odometry_to_msg(run.stamps[k], run.odometry[k], frame_id="odom"))
            scan = run.scans[k]
            node._on_scan(
                conversions.scan_to_msg(
                    scan.stamp, "laser", angle_min=scan.angles[0], angle_increment=scan.angles[1] - scan.angles[0],
                    ranges=scan.ranges, range_min=scan.range_min, range_max=scan.range_max,
                )
            )
        # bad input on the same path: a scan of NaNs, odometry stepping back in time
        node._on_scan(conversions.scan_to_msg(100.0, "laser", angle_min=-1.0, angle_increment=0.01,
                                              ranges=np.full(200, np.nan), range_min=0.1, range_max=10.0))
        node.adapter.on_odom_msg(conversions.odometry_to_msg(0.0, np.zeros(3), frame_id="odom"))
        assert len(published) > 5
        last = published[-1]
        assert last.estimate.status is LocalizerStatus.LOCALIZED
        assert np.hypot(*(last.estimate.pose[:2] - run.truth[len(run.stamps) - 1][:2])) < 0.2
        assert last.pose.header.frame_id == "map"
        values = {kv.key: kv.value for kv in last.diagnostics.status[0].values}
        assert int(values["particles"]) >= 200

        # the services, through their callbacks
        node._on_reinitialize(Empty.Request(), Empty.Response())
        assert localizer.particle_count == 3000 and np.all(office.is_free(localizer.particles[:, :2]))
        assert np.ptp(localizer.particles[:, 0]) > 10.0
        node._on_nomotion(Empty.Request(), Empty.Response())
        assert localizer.odometry.forced
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    assert math.isfinite(published[-1].update_ms)
