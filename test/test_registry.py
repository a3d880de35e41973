"""The plugin registry and the settings as the one definition of every parameter."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from robot_localization_suite import registry
from robot_localization_suite.core.errors import SettingsError
from robot_localization_suite.core.ima.settings import ImaTrackerSettings
from robot_localization_suite.core.mcl.settings import MclSettings
from robot_localization_suite.core.pil.settings import PilSettings
from robot_localization_suite.core.settings import (
    Settings,
    from_params,
    help_text,
    nested,
    parameters,
    read_params_file,
    setting,
    to_params,
    unknown_params,
)

PLUGIN_NAMES = sorted(registry.PLUGINS)
# Every packaged params file: config/<name>.yaml and the ones the benchmark reads for some bags.
PARAMS_FILES = [(name, plugin.params_file().name) for name, plugin in sorted(registry.PLUGINS.items())] + [
    (name, f"{name}_paper.yaml") for name in sorted(registry.PLUGINS)
    if (registry.config_dir() / f"{name}_paper.yaml").is_file()]  # the paper profiles (rls_bench --profile paper)
# The benchmark's files for some bags, read on top of config/<name>.yaml (a second --params-file).
BAG_PARAMS_FILES = [(name, file) for name, plugin in sorted(registry.PLUGINS.items())
                    for file in sorted(set(plugin.bench_params.values()))]


@pytest.mark.parametrize(("name", "file"), PARAMS_FILES + BAG_PARAMS_FILES)
def test_the_packaged_params_file_sets_exactly_the_plugins_parameters_with_their_types_and_ranges(
    name: str, file: str
) -> None:
    plugin = registry.plugin(name)
    path = registry.config_dir() / file
    section = yaml.safe_load(path.read_text())[name]["ros__parameters"]
    declared = {p.name: p for cls in (registry.NodeSettings, plugin.settings) for p in parameters(cls)}
    flat = {k: v for k, v in _flatten(section).items()}
    assert set(flat) <= set(declared), sorted(set(flat) - set(declared))
    documented = set(flat)
    if (name, file) in BAG_PARAMS_FILES:  # with the packaged file under it
        documented |= set(_flatten(yaml.safe_load(plugin.params_file().read_text())[name]["ros__parameters"]))
    assert set(parameters_names(plugin.settings)) <= documented, "the files document every method parameter"
    for key, value in flat.items():
        param = declared[key]
        assert type(value) is param.kind, key
        if param.low is not None:
            assert param.low <= value <= param.high, key
    node_settings, settings = plugin.load_settings(params_file=path)
    assert isinstance(node_settings, registry.NodeSettings) and isinstance(settings, plugin.settings)


def parameters_names(cls: type[Settings]) -> list[str]:
    return [p.name for p in parameters(cls)]


def _flatten(values: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in values.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


@pytest.mark.parametrize("name", PLUGIN_NAMES)
def test_every_parameter_has_a_description_and_a_value_beyond_its_range_is_refused_naming_the_range(name: str) -> None:
    plugin = registry.plugin(name)
    checked = 0
    for param in parameters(plugin.settings):
        assert param.setting.doc, param.name
        if param.kind in (int, float) and param.high is not None:
            expected = f"parameter {param.name} must be in {param.range_text()}"
            for beyond in _beyond(param):
                with pytest.raises(SettingsError, match=re.escape(expected)):
                    from_params(plugin.settings, {param.name: beyond})
            checked += 1
        if param.setting.choices:
            with pytest.raises(SettingsError, match=rf"parameter {param.name} must be one of"):
                from_params(plugin.settings, {param.name: "no_such_choice"})
    assert checked > 5


def _beyond(param: Any) -> list[Any]:
    """A value above the high bound and, when there is one, below the low bound (ROS units)."""
    step = 1 if param.kind is int else abs(param.high) * 0.5 + 1.0
    values = [param.kind(param.high + step)]
    if param.low is not None:
        values.append(param.kind(param.low - (1 if param.kind is int else abs(param.low) * 0.5 + 1.0)))
    return values


@pytest.mark.parametrize("name", PLUGIN_NAMES)
def test_the_running_node_refuses_an_out_of_range_value_naming_the_range_and_keeps_the_old_one(name: str) -> None:
    rclpy = pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    plugin = registry.plugin(name)
    ranged = [p for p in parameters(plugin.settings)
              if p.kind in (int, float) and p.high is not None and not p.setting.read_only]
    assert ranged, name
    rclpy.init(args=[name])
    try:
        node = LocalizerNode(plugin)
        try:
            for param in ranged:
                before = node.get_parameter(param.name).value
                for beyond in _beyond(param):
                    result = node.set_parameters([Parameter(param.name, value=beyond)])[0]
                    assert not result.successful, (param.name, beyond)
                    # ours, or rclpy's own check of the declared descriptor range, which comes first
                    ours = f"parameter {param.name} must be in {param.range_text()}"
                    theirs = (rf"Parameter {re.escape(param.name)} out of range\.? Min: "
                              rf"{re.escape(str(param.kind(param.low)))}, Max: {re.escape(str(param.kind(param.high)))},")
                    assert ours in result.reason or re.search(theirs, result.reason), result.reason
                    assert node.get_parameter(param.name).value == before
            # an open bound itself passes rclpy's closed descriptor range and is refused by the settings
            for param in [p for p in ranged if p.setting.low_open and p.low is not None][:3]:
                result = node.set_parameters([Parameter(param.name, value=param.kind(param.low))])[0]
                assert not result.successful
                assert f"parameter {param.name} must be in {param.range_text()}" in result.reason, result.reason
            # and a value inside the range is taken
            param = ranged[0]
            inside = param.kind(param.low if param.low is not None and not param.setting.low_open else param.high
                                if not param.setting.high_open else (param.low + param.high) / 2)
            assert node.set_parameters([Parameter(param.name, value=inside)])[0].successful, param.name
            assert node.get_parameter(param.name).value == inside
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_a_nav2_amcl_section_carries_over_and_lists_what_is_not_used() -> None:
    # the `amcl:` section of a nav2 params file: nested initial pose, nav2 plugin names,
    # integers where floats are declared, and parameters this node does not have
    nav2 = yaml.safe_load(
        """
        alpha1: 0.2
        base_frame_id: "base_footprint"
        do_beamskip: false
        save_pose_rate: 0.5
        max_particles: 2000
        robot_model_type: "nav2_amcl::OmniMotionModel"
        update_min_d: 1
        set_initial_pose: true
        initial_pose: {x: 1.5, y: -2.0, z: 0.0, yaw: 0.5}
        """
    )
    settings = from_params(MclSettings, nav2)
    assert settings.alpha1 == 0.2 and settings.max_particles == 2000 and settings.omnidirectional
    assert settings.update_min_d == 1.0 and isinstance(settings.update_min_d, float)
    assert not settings.do_beamskip  # nav2's false overrides this package's default
    # the frames and the initial pose are every localizer node's (registry.NodeSettings)
    node = from_params(registry.NodeSettings, nav2)
    assert node.set_initial_pose and node.initial_pose == (1.5, -2.0, 0.5) and node.base_frame_id == "base_footprint"
    not_used = set(unknown_params(MclSettings, nav2)) & set(unknown_params(registry.NodeSettings, nav2))
    assert sorted(not_used) == ["initial_pose.z", "save_pose_rate"]
    with pytest.raises(SettingsError, match="parameter laser_model_type must be one of likelihood_field, beam"):
        from_params(MclSettings, {"laser_model_type": "likelihood_field_prob"})
    with pytest.raises(SettingsError, match="parameter max_particles must be an integer, got 2.5"):
        from_params(MclSettings, {"max_particles": 2.5})
    with pytest.raises(SettingsError, match="parameter set_initial_pose must be true or false"):
        from_params(registry.NodeSettings, {"set_initial_pose": 1})


def test_degrees_in_ros_radians_inside_declared_once() -> None:
    params = {p.name: p for p in parameters(PilSettings)}
    fov = params["field_of_view_deg"]
    assert fov.default == pytest.approx(360.0) and fov.high == pytest.approx(360.0) and fov.unit == "deg"
    settings = from_params(PilSettings, {"field_of_view_deg": 240, "ambiguity_angle_deg": 30.0})
    assert settings.field_of_view == pytest.approx(math.radians(240.0))
    assert settings.ambiguity_angle == pytest.approx(math.radians(30.0))
    assert to_params(settings)["field_of_view_deg"] == pytest.approx(240.0)
    assert "field_of_view_deg = 360.0 [deg] (0..360]" in help_text(PilSettings)


def test_nested_settings_share_the_parent_namespace() -> None:
    settings = from_params(ImaTrackerSettings, {"scale_width": 64, "slots": 6, "update_min_d": 0.5})
    assert settings.ima.width == 64 and settings.ima.slots == 6 and settings.min_translation == 0.5
    assert to_params(settings)["scale_width"] == 64
    with pytest.raises(SettingsError, match="slots must be at most width/2 = 4"):
        from_params(ImaTrackerSettings, {"scale_width": 8, "slots": 6})


@dataclass(frozen=True)
class _Inner(Settings):
    width: float = setting(1.0, "a width", unit="m", low=0.0, low_open=True)


@dataclass(frozen=True)
class _Outer(Settings):
    inner: _Inner = nested(_Inner)
    name: str = setting("a", "a name", choices=("a", "b"))


def test_an_open_bound_is_excluded_and_every_field_is_checked_on_construction() -> None:
    with pytest.raises(SettingsError, match=r"_Inner.width must be in \(0..\] m, got 0.0"):
        _Inner(width=0.0)
    with pytest.raises(SettingsError, match="must be finite"):
        _Inner(width=math.inf)
    with pytest.raises(SettingsError, match="_Outer.name must be one of a, b"):
        _Outer(name="c")
    assert from_params(_Outer, {"width": 2, "name": "b"}) == _Outer(_Inner(2.0), "b")


def test_a_params_file_merges_wildcard_then_own_section_and_refuses_a_foreign_one(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"max_beams": 30, "alpha1": 0.1}},
        "mcl_baseline": {"ros__parameters": {"max_beams": 40, "initial_pose": {"x": 2.0}}},
    }))
    assert read_params_file(path, "mcl_baseline") == {"max_beams": 40, "alpha1": 0.1, "initial_pose.x": 2.0}
    assert read_params_file(path, "other") == {"max_beams": 30, "alpha1": 0.1}
    foreign = tmp_path / "f.yaml"
    foreign.write_text(yaml.safe_dump({"amcl": {"ros__parameters": {"max_beams": 30}}}))
    with pytest.raises(SettingsError, match="no section for node 'mcl_baseline'"):
        read_params_file(foreign, "mcl_baseline")
    node, settings = registry.plugin("mcl_baseline").load_settings({"min_particles": 100}, params_file=path)
    assert settings.max_beams == 40 and settings.min_particles == 100 and node.initial_pose_x == 2.0


def test_an_unknown_localizer_is_named_with_the_known_ones() -> None:
    with pytest.raises(KeyError, match="unknown localizer 'amcl'; known: mcl_baseline"):
        registry.plugin("amcl")


@pytest.mark.parametrize("name", sorted(registry.PLUGINS))
def test_every_packaged_params_file_names_the_simulators_robot_frame(name: str) -> None:
    """Live on ``scan_sim``, a node whose ``base_frame_id`` is not the simulator's robot frame finds no laser mount on
    /tf_static and drops every scan for 5 s before it falls back to laser_x/y/yaw (the hybrid's file did)."""
    simulator = read_params_file(registry.config_dir() / "scan_sim.yaml", "scan_sim")
    params = read_params_file(registry.config_dir() / f"{name}.yaml", name)
    assert params.get("base_frame_id") == simulator["base_frame"]
