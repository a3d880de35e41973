"""ima_topo_localizer end to end: parameters, the node's ~/place, the lab_camera world, its bag and its targets."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot_localization_suite import registry
from robot_localization_suite.core import metrics
from robot_localization_suite.core.errors import MapError, ScenarioError
from robot_localization_suite.core.ima.settings import ImaSettings
from robot_localization_suite.core.ima.topomap import load_topomap
from robot_localization_suite.core.ima.tracking import ImaTopoLocalizer
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.se2 import angle_difference
from robot_localization_suite.core.sim.scenario_yaml import load_scenario
from robot_localization_suite.core.sim.simulator import Simulator
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter
from robot_localization_suite.ros.bag import bag_topics, read_bag
from robot_localization_suite.ros.extras import IMA_PLACE
from robot_localization_suite.tools import build_topomap


@pytest.fixture(scope="module")
def scenario(repo_root: Path):
    return load_scenario(repo_root / "config" / "scenarios" / "lab_camera.yaml")


# -- parameters -------------------------------------------------------------------------
def _ima(**overrides: object) -> ImaTopoLocalizer:
    plugin = registry.plugin("ima_topo_localizer")
    return plugin.create(plugin.load_settings(overrides)[1])


def test_the_plugin_gives_the_thesis_values_and_overrides_reach_the_nested_settings() -> None:
    localizer = _ima()
    assert isinstance(localizer, ImaTopoLocalizer)
    assert localizer.settings.ima == ImaSettings()
    s = localizer.settings
    assert (s.ima.width, s.ima.height, s.ima.slots, s.ima.clahe, s.ima.zoom) == (72, 58, 8, True, 1.1)
    assert (s.match_threshold, s.heading_threshold, s.min_translation) == (0.5, 0.6, 0.3)
    assert s.min_rotation == pytest.approx(math.radians(10.0), abs=1e-4)
    assert len(localizer.names) == 15
    settings = _ima(slots=6, zoom=1.0, update_min_d=0.5).settings
    assert (settings.ima.slots, settings.ima.zoom, settings.min_translation) == (6, 1.0, 0.5)


def test_a_missing_topomap_or_panorama_is_an_error_naming_it(tmp_path: Path, repo_root: Path) -> None:
    with pytest.raises(MapError, match="nowhere.yaml"):
        _ima(topomap=str(tmp_path / "nowhere.yaml"))
    source = repo_root / "config" / "topomaps" / "lab" / "topomap.yaml"
    meta = yaml.safe_load(source.read_text())
    meta["panorama_dir"] = str(source.parent)
    meta["nodes"][3]["panorama"] = "LOST_PLACE.png"
    broken = tmp_path / "topomap.yaml"
    broken.write_text(yaml.safe_dump(meta))
    with pytest.raises(MapError, match=r"LOST_PLACE\.png"):
        _ima(topomap=str(broken))


# -- the world --------------------------------------------------------------------------
def test_lab_camera_world_has_the_thesis_layout(repo_root: Path, scenario) -> None:
    topomap = load_topomap(repo_root / "config" / "topomaps" / "lab" / "topomap.yaml")
    nodes = yaml.safe_load((repo_root / "config" / "topomaps" / "lab" / "nodes.yaml").read_text())["nodes"]
    assert topomap.names == [n["name"] for n in nodes] and len(topomap.names) == 15
    assert topomap.hfov_deg == scenario.camera.hfov_deg
    assert np.all(scenario.grid_map.is_free(topomap.positions))
    # the free space: a 6 m x 6 m lab, a 2 m x 2 m entry, a 2 m x 10 m corridor
    free = scenario.grid_map.free_cell_centres()
    for (x0, x1, y0, y1), (width, height) in (((-0.2, 6.05, -0.2, 6.2), (6.0, 6.0)), ((8.15, 10.4, -2.5, 8.5), (2.0, 10.0))):
        inside = free[(free[:, 0] > x0) & (free[:, 0] < x1) & (free[:, 1] > y0) & (free[:, 1] < y1)]
        assert np.ptp(inside[:, 0]) + 0.05 == pytest.approx(width, abs=0.06)
        assert np.ptp(inside[:, 1]) + 0.05 == pytest.approx(height, abs=0.06)
    assert len(scenario.kidnappings) == 1 and len(scenario.people) == 2
    # the route passes within 0.05 m of every place
    route = scenario.trajectory.poses[:, :2]
    gaps = np.hypot(route[:, None, 0] - topomap.positions[None, :, 0], route[:, None, 1] - topomap.positions[None, :, 1]).min(axis=0)
    assert gaps.max() < 0.05


def test_people_are_in_the_camera_view_at_least_30_percent_of_the_images(scenario) -> None:
    caster = RayCaster(scenario.grid_map, max_range=30.0)
    half_fov = math.radians(scenario.camera.hfov_deg) / 2.0
    poses, times = scenario.trajectory.poses, scenario.trajectory.times
    seen = []
    for t in np.arange(0.0, scenario.end_time, 1.0 / scenario.camera.rate_hz):
        pose = poses[min(int(round(t / scenario.period)), len(poses) - 1)]
        visible = False
        for x, y, radius in scenario.people_at(float(times[min(int(round(t / scenario.period)), len(times) - 1)])):
            bearing = float(angle_difference(math.atan2(y - pose[1], x - pose[0]), pose[2]))
            distance = math.hypot(x - pose[0], y - pose[1])
            if abs(bearing) - math.asin(min(1.0, radius / max(distance, radius))) < half_fov:
                wall = caster.cast(np.array([pose[0], pose[1], 0.0]), np.array([pose[2] + bearing]))[0]
                visible |= distance - radius < wall
        seen.append(visible)
    assert np.mean(seen) >= 0.30


# -- build_topomap -----------------------------------------------------------------------
def test_build_topomap_writes_the_map_file_and_panoramas(tmp_path: Path, repo_root: Path) -> None:
    scenario_file = tmp_path / "tiny.yaml"
    data = yaml.safe_load((repo_root / "config" / "scenarios" / "lab_camera.yaml").read_text())
    data["map"] = str(repo_root / "config" / "maps" / "lab.yaml")
    data["camera"].update(width=96, height=72)
    scenario_file.write_text(yaml.safe_dump(data))
    out = tmp_path / "topo"
    out.mkdir()
    (out / "nodes.yaml").write_text(
        yaml.safe_dump({"heading_ref": 0.3, "nodes": [{"name": "A", "x": 2.0, "y": 2.0}, {"name": "B", "x": 9.2, "y": 3.0}]})
    )
    code = build_topomap.main([str(scenario_file), str(out), "--width", "72", "--height", "54", "--slots", "8"])
    assert code == 0
    topomap = load_topomap(out / "topomap.yaml")
    assert topomap.names == ["A", "B"] and topomap.hfov_deg == 60.0
    assert topomap.heading_refs.tolist() == [0.3, 0.3]
    assert topomap.panoramas[0].shape == (54, 432)
    assert all(item["max_insert_error_px"] <= 0.02 * 432 for item in topomap.source["insertions"])
    # bad inputs: a node in a wall, a scenario without a camera, a missing nodes file
    (out / "nodes.yaml").write_text(yaml.safe_dump({"nodes": [{"name": "WALL", "x": 6.05, "y": 5.0}]}))
    assert build_topomap.main([str(scenario_file), str(out)]) == 1
    del data["camera"]
    scenario_file.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match="no camera"):
        build_topomap.build_topomap(load_scenario(scenario_file), [("A", 2.0, 2.0)], out)
    with pytest.raises(MapError, match="nodes file"):
        build_topomap.load_nodes(tmp_path / "missing.yaml")


def test_build_topomap_refuses_a_node_name_that_is_a_path_and_an_out_dir_that_is_a_file(
    tmp_path: Path, repo_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    nodes = tmp_path / "nodes.yaml"
    for name in ("../../evil", "a/b", ".."):  # its panorama would be written outside OUT_DIR
        nodes.write_text(yaml.safe_dump({"nodes": [{"name": name, "x": 2.0, "y": 2.0}]}))
        with pytest.raises(MapError, match=rf"node name {re.escape(repr(name))} is not a plain file name"):
            build_topomap.load_nodes(nodes)
    nodes.write_text(yaml.safe_dump({"nodes": [{"name": "A", "x": 2.0, "y": 2.0}]}))
    (tmp_path / "afile").write_text("")
    scenario_file = str(repo_root / "config" / "scenarios" / "lab_camera.yaml")
    for out in (tmp_path / "afile", tmp_path / "afile" / "topo"):
        assert build_topomap.main([scenario_file, str(out), "--nodes", str(nodes)]) == 1
        assert f"{str(tmp_path / 'afile')!r} is a file, not a folder" in capsys.readouterr().err


# -- the bag and the targets ----------------------------------------------------------------
def test_the_bag_is_the_scenario_recorded(repo_root: Path, scenario) -> None:
    bag = repo_root / "bags" / "lab_camera"
    size = sum(p.stat().st_size for p in bag.iterdir())
    assert size < 6e6
    assert {"/camera/image_raw", "/odom", "/ground_truth", "/scan", "/map"} <= set(bag_topics(bag))
    first = next(item for item in read_bag(bag, ["/camera/image_raw"]))
    simulated = next(step.image for step in Simulator(scenario).run() if step.image is not None)
    assert np.array_equal(conversions.image_from_msg(first.msg), simulated)


def _replay(bag: Path, adapter: LocalizerAdapter) -> tuple[list, dict[float, np.ndarray]]:
    outputs, truth = [], {}
    for item in read_bag(bag, ["/odom", "/ground_truth", "/camera/image_raw"]):
        if item.topic == "/odom":
            adapter.on_odom_msg(item.msg)
        elif item.topic == "/ground_truth":
            stamp, pose = conversions.odometry_from_msg(item.msg)
            truth[round(stamp, 3)] = pose
        else:
            output = adapter.on_image_msg(item.msg)
            if output is not None:
                outputs.append(output)
    return outputs, truth


def test_lab_camera_targets_correct_place_heading_and_kidnap_recovery(repo_root: Path, scenario) -> None:
    adapter = LocalizerAdapter(
        _ima(),
        node_name="ima_topo_localizer",
        log=lambda level, text: None,
        extras_builder=lambda estimate: {"place": IMA_PLACE["place"].build(estimate)},
    )
    outputs, truth = _replay(repo_root / "bags" / "lab_camera", adapter)
    assert len(outputs) > 100
    correct, heading_errors, stamps = [], [], []
    for output in outputs:
        estimate = output.estimate
        true_pose = truth[round(estimate.stamp, 3)]
        details = estimate.details
        correct.append(metrics.nearest_node_is_place(estimate.place.xy, estimate.place.node_xy, true_pose))
        stamps.append(estimate.stamp)
        if estimate.heading_corrected:
            heading_errors.append(abs(math.degrees(angle_difference(estimate.pose[2], true_pose[2]))))
        assert output.extras["place"].data == details["place"]
    correct = np.asarray(correct)
    # The issue's target; 0.968 with the default odometry_reset "zoom", 0.897 with Code 3.1's "winner".
    assert correct.mean() >= 0.90
    assert len(heading_errors) > 50 and max(heading_errors) <= 10.0
    kidnap_time = scenario.kidnappings[0].time
    after = [ok for stamp, ok in zip(stamps, correct, strict=True) if stamp >= kidnap_time]
    assert any(after[:3])  # the right place within 3 update steps of the kidnapping
    assert np.mean(after[2:]) > 0.6  # and it keeps tracking the lab afterwards


def test_the_node_publishes_the_place_and_survives_bad_images(repo_root: Path) -> None:
    rclpy = pytest.importorskip("rclpy")
    from std_msgs.msg import String

    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    rclpy.init(args=["ima_topo_localizer", "--ros-args", "-p", "zoom:=1.0"])
    node = LocalizerNode(registry.plugin("ima_topo_localizer"), extras=IMA_PLACE)
    node.trigger_configure()
    node.trigger_activate()
    published, warnings = [], []
    try:
        assert node.localizer.settings.ima.zoom == 1.0
        assert set(node.extra_pubs) == {"place"}
        node.publish = lambda output, *_: published.append(output) if output is not None else None  # type: ignore[method-assign]
        node.adapter.log._sink = lambda level, text: warnings.append((level, text))
        messages = read_bag(repo_root / "bags" / "lab_camera", ["/odom", "/camera/image_raw"])
        images = 0
        for item in messages:
            if item.topic == "/odom":
                node.adapter.on_odom_msg(item.msg)
                continue
            images += 1
            node._on_image(item.msg)
            if images == 12:
                break
        assert published and isinstance(published[0].extras["place"], String)
        assert published[0].extras["place"].data == "LAB_SW"
        # an unsupported encoding is skipped with a warning; an rgb8 image is converted and used
        # stamped just after the bag's images (an input far ahead of the newest is refused as from the future)
        after = conversions.stamp_to_seconds(item.msg.header.stamp)
        # with its odometry: the node updates once odometry reaches an input's stamp
        node.adapter.on_odom_msg(conversions.odometry_to_msg(after + 0.1, np.array([5.0, 5.0, 1.0]), frame_id="odom"))
        bad = conversions.image_to_msg(after + 0.1, "camera", np.zeros((120, 160), np.uint8))
        bad.encoding = "16UC1"
        node._on_image(bad)
        assert any(level == "warn" and "16UC1" in text for level, text in warnings)
        count = len(published)
        node.adapter.on_odom_msg(conversions.odometry_to_msg(after + 0.2, np.array([5.0, 5.0, 1.0]), frame_id="odom"))
        colour = conversions.image_to_msg(after + 0.2, "camera", np.zeros((120, 160, 3), np.uint8))
        node._on_image(colour)
        assert len(published) == count + 1 and published[-1].extras["place"].data  # black: a supposed place
        assert published[-1].estimate.details["kind"] == "supposed"
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
