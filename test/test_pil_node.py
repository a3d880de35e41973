"""The pil_localizer plugin: its settings, messages through the adapter, the shared node running it."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from robot_localization_suite import registry
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.localizer import LocalizerStatus
from robot_localization_suite.core.pil.localizer import PilLocalizer, PilSettings
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.scan import LaserMount
from robot_localization_suite.core.se2 import angle_difference, compose
from robot_localization_suite.core.settings import parameters
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter


def _room() -> GridMap:
    data = np.zeros((80, 120), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[:45, 70:72] = 100  # partition at x = 3.5 m up to y = 2.25 m
    data[55:65, 15:30] = 100  # box at x 0.75-1.5 m, y 2.75-3.25 m
    return GridMap(data, 0.05, (0.0, 0.0))


def _pil(**overrides: object) -> PilLocalizer:
    plugin = registry.plugin("pil_localizer")
    return plugin.create(plugin.load_settings(overrides)[1])


def test_the_plugin_builds_pil_with_the_settings_defaults(tmp_path: Path) -> None:
    localizer = _pil(cache_dir=str(tmp_path))
    assert isinstance(localizer, PilLocalizer)
    assert localizer.settings == replace(PilSettings(), cache_dir=str(tmp_path))


def test_degree_parameters_are_converted_and_bad_values_refused(tmp_path: Path) -> None:
    localizer = _pil(field_of_view_deg=180, ambiguity_angle_deg=30.0, window_size=0, cache_dir=str(tmp_path))
    assert localizer.settings.field_of_view == pytest.approx(math.pi)
    assert localizer.settings.ambiguity_angle == pytest.approx(math.radians(30.0))
    assert localizer.layout.angle_count == 114 * 2
    with pytest.raises(ValueError, match="beam_mapping"):
        _pil(beam_mapping="average")


def test_messages_through_the_adapter_give_the_base_pose_and_bad_scans_are_skipped(tmp_path: Path) -> None:
    room = _room()
    localizer = _pil(cache_dir=str(tmp_path), show_progress=False, max_range=6.0)
    mount = LaserMount(0.2, 0.0, 0.0)
    logs: list[tuple[str, str]] = []
    adapter = LocalizerAdapter(localizer, node_name="pil_localizer", log=lambda *a: logs.append(a), mount=mount)
    assert adapter.on_map_msg(conversions.grid_map_to_msg(room, 0.0))

    base = np.array([1.8, 1.4, 0.7])
    laser = compose(base, mount.pose)
    angles = -math.pi + np.arange(360) * (2.0 * math.pi / 360)
    ranges = RayCaster(room, max_range=8.0).cast(laser, angles).astype(np.float64)
    ranges[::9] = np.nan
    msg = conversions.scan_to_msg(
        1.0, "laser", angle_min=-math.pi, angle_increment=2.0 * math.pi / 360, ranges=ranges, range_min=0.05, range_max=8.0
    )
    output = adapter.on_scan_msg(msg)
    assert output is not None
    assert output.estimate.status is LocalizerStatus.LOCALIZED
    assert np.hypot(*(output.estimate.pose[:2] - base[:2])) < 0.2
    assert abs(angle_difference(output.estimate.pose[2], base[2])) < 0.1
    assert output.pose.header.frame_id == "map"
    values = {kv.key: kv.value for kv in output.diagnostics.status[0].values}
    assert int(values["candidate_count"]) == len(output.candidates.poses) > 0
    assert "filter_count" in values

    bad = conversions.scan_to_msg(
        2.0, "laser", angle_min=-math.pi, angle_increment=2.0 * math.pi / 360, ranges=np.full(360, np.nan),
        range_min=0.05, range_max=8.0,
    )
    assert adapter.on_scan_msg(bad) is None
    few = np.full(90, np.nan)
    few[:5] = 1.0
    sparse = conversions.scan_to_msg(
        3.0, "laser", angle_min=-math.pi, angle_increment=2.0 * math.pi / 90, ranges=few, range_min=0.05, range_max=8.0
    )
    assert adapter.on_scan_msg(sparse) is None
    assert any("valid beam" in text for _, text in logs)


def test_the_node_declares_every_parameter_and_builds_pil(tmp_path: Path) -> None:
    rclpy = pytest.importorskip("rclpy")
    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    args = ["pil_localizer", "--ros-args", "-p", f"cache_dir:={tmp_path}", "-p", "field_of_view_deg:=240.0",
            "-p", "show_progress:=false"]
    rclpy.init(args=args)
    try:
        node = LocalizerNode(registry.plugin("pil_localizer"))
        node.trigger_configure()
        node.trigger_activate()
        try:
            assert isinstance(node.localizer, PilLocalizer)
            assert node.localizer.settings.field_of_view == pytest.approx(math.radians(240.0))
            assert node.localizer.settings.cache_dir == str(tmp_path)
            # every parameter reaches PIL: the overridden ones with their value, the others at the default
            assert node.localizer.settings == replace(
                PilSettings(), field_of_view=math.radians(240.0), cache_dir=str(tmp_path), show_progress=False)
            overridden = {"cache_dir", "field_of_view_deg", "show_progress"}
            for param in parameters(PilSettings):
                assert node.has_parameter(param.name), param.name
                if param.name not in overridden:
                    assert node.get_parameter(param.name).value == param.default, param.name
                # and is declared with its description and range (shown by `ros2 param describe`)
                described = node.describe_parameter(param.name)
                assert param.setting.doc in described.description, param.name
                if param.kind is float and param.high is not None:
                    (bounds,) = described.floating_point_range
                    assert (bounds.from_value, bounds.to_value) == pytest.approx((param.low, param.high)), param.name
            assert node.get_parameter("field_of_view_deg").value == 240.0
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
