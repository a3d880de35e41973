"""The mcl_baseline node module: parameters -> MclSettings, config file, an in-process node fed messages."""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcl_test_world import drive, office_map

from robot_localization_suite import registry
from robot_localization_suite.core.localizer import LocalizerStatus
from robot_localization_suite.core.mcl.localizer import MclSettings, MonteCarloLocalizer
from robot_localization_suite.nodes import mcl_baseline
from robot_localization_suite.ros import conversions

_RENAMED = {"initial_pose.x": "initial_pose_x", "initial_pose.y": "initial_pose_y", "initial_pose.yaw": "initial_pose_yaw"}


def test_make_localizer_from_the_registry_params_gives_the_settings_defaults() -> None:
    localizer = mcl_baseline.make_localizer(registry.localizer_params("mcl_baseline"))
    assert isinstance(localizer, MonteCarloLocalizer)
    assert localizer.settings == MclSettings()


def test_every_parameter_reaches_the_settings_and_the_config_file_lists_them_all(repo_root: Path) -> None:
    names = [spec.name for spec in mcl_baseline.PARAMS]
    assert len(names) == len(set(names))
    assert {_RENAMED.get(name, name) for name in names} == {field.name for field in fields(MclSettings)}
    config = yaml.safe_load((repo_root / "config" / "mcl_baseline.yaml").read_text())["mcl_baseline"]["ros__parameters"]
    assert set(config) == set(names)
    defaults = MclSettings()
    for spec in mcl_baseline.PARAMS:
        assert spec.description
        assert type(config[spec.name]) is type(spec.default), spec.name
        assert config[spec.name] == pytest.approx(getattr(defaults, _RENAMED.get(spec.name, spec.name))), spec.name


def test_a_nav2_amcl_params_section_carries_over() -> None:
    # the `amcl:` section of a nav2 params file: nested initial pose, nav2 plugin names,
    # integers where floats are declared, and parameters this node does not have
    nav2 = yaml.safe_load(
        """
        alpha1: 0.2
        alpha2: 0.2
        base_frame_id: "base_footprint"
        do_beamskip: false
        laser_model_type: "likelihood_field"
        max_particles: 2000
        min_particles: 500
        robot_model_type: "nav2_amcl::OmniMotionModel"
        recovery_alpha_fast: 0.0
        sigma_hit: 0.2
        update_min_d: 1
        set_initial_pose: true
        initial_pose: {x: 1.5, y: -2.0, z: 0.0, yaw: 0.5}
        """
    )
    settings = mcl_baseline.make_localizer(nav2).settings
    assert settings.alpha1 == 0.2 and settings.max_particles == 2000 and settings.omnidirectional
    assert settings.update_min_d == 1.0 and isinstance(settings.update_min_d, float)
    assert (settings.initial_pose_x, settings.initial_pose_y, settings.initial_pose_yaw) == (1.5, -2.0, 0.5)
    with pytest.raises(ValueError, match="laser_model_type"):
        mcl_baseline.make_localizer({"laser_model_type": "likelihood_field_prob"})


def test_the_node_handles_a_message_feed_and_its_services() -> None:
    rclpy = pytest.importorskip("rclpy")
    from std_srvs.srv import Empty

    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    office = office_map()
    run = drive(office, steps=80, seed=2)
    rclpy.init(args=["mcl_baseline", "--ros-args", "-p", "max_particles:=3000", "-p", "min_particles:=200"])
    node = LocalizerNode(mcl_baseline.NODE_NAME, mcl_baseline.PARAMS, mcl_baseline.make_localizer)
    published = []
    try:
        for spec in mcl_baseline.PARAMS:
            assert node.has_parameter(spec.name), spec.name
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
