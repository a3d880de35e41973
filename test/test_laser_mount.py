"""A laser mounted off the base, and upside down: scan_sim records it on /tf_static, rls_bench reads it from the bag
as a node does, and a localizer tracks as with a level laser."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot_localization_suite.core.errors import ScenarioError
from robot_localization_suite.core.scan import LaserMount
from robot_localization_suite.core.sim.scenario_yaml import load_scenario
from robot_localization_suite.core.sim.simulator import Simulator
from robot_localization_suite.registry import config_dir
from robot_localization_suite.ros.bag import read_bag
from robot_localization_suite.ros.tf import TFMessage, transform_from_msg
from robot_localization_suite.tools import bench
from robot_localization_suite.tools.live_check import record_scenario

pytestmark = pytest.mark.skipif(TFMessage is None, reason="tf2_msgs is not installed (make builds it)")

MOUNT = [0.2, 0.05, 0.3]  # off the base's centre and turned: a wrong mount is a wrong pose


def write_scenario(folder: Path, *, upside_down: bool | str, noise: bool = True) -> Path:
    """The office tour (its first 24 s come before any kidnapping) with a 270-degree laser mounted at MOUNT."""
    source = config_dir() / "scenarios" / "office_kidnap.yaml"
    data = yaml.safe_load(source.read_text())
    data["map"] = str((source.parent / data["map"]).resolve())
    data["laser"] = {**data.get("laser", {}), "mount": MOUNT, "upside_down": upside_down, "fov_deg": 270.0,
                     "beams": 271}
    if not noise:
        data["laser"].update(range_noise_std=0.0, outlier_prob=0.0, dropout_prob=0.0)
        data.pop("people", None)
    path = folder / f"office_{'upside_down' if upside_down is True else 'level'}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_an_upside_down_laser_reads_the_world_mirrored_and_a_bad_flag_is_refused(tmp_path: Path) -> None:
    level = Simulator(load_scenario(write_scenario(tmp_path, upside_down=False, noise=False)))
    flipped = Simulator(load_scenario(write_scenario(tmp_path, upside_down=True, noise=False)))
    for _ in range(5):
        a, b = level.step(), flipped.step()
        assert np.array_equal(a.true_pose, b.true_pose)
        # the same 271 directions (symmetric about the laser's x axis), swept the other way round
        assert np.allclose(b.ranges, a.ranges[::-1], atol=1e-4)
        assert not np.allclose(b.ranges, a.ranges, atol=0.05)
    with pytest.raises(ScenarioError, match="laser.upside_down must be true or false, got 'yes'"):
        load_scenario(write_scenario(tmp_path, upside_down="yes"))


def test_rls_bench_takes_the_mount_from_the_bags_tf_static_upside_down_included(tmp_path: Path) -> None:
    bag = record_scenario(write_scenario(tmp_path, upside_down=True), tmp_path / "office_upside_down", 12.0)
    (static,) = [item.msg for item in read_bag(bag, ["/tf_static"])]
    transform = transform_from_msg(static.transforms[0])
    assert transform.upside_down and transform.pose == pytest.approx(MOUNT)
    reference = bench.load_reference(bag)
    assert list(reference.laser_mounts) == ["base_link"]
    mount = reference.laser_mounts["base_link"]
    assert mount.pose == pytest.approx(MOUNT) and mount.upside_down

    assert bench.main([str(bag), "--localizers", "mcl_baseline", "ir_initializer", "--mode", "tracking",
                       "--workers", "0", "--no-plots", "--out", str(tmp_path / "out")]) == 0
    runs = json.loads((tmp_path / "out" / "summary.json").read_text())["office_upside_down"]
    for name, fields in runs.items():
        assert fields["laser_mount"] == "the bag's /tf_static: (0.2 m, 0.05 m, 0.3 rad, upside down)", name
        # the scans levelled at the mount explain the map at the truth; taken as a level laser they would not
        assert fields["map_coverage_median"] > 0.9, name  # 0.16 taken as a level laser (measured)
        assert fields["correct_rate"] >= 0.95 and fields["false_localized_rate"] == 0.0, (name, fields)
    # single-scan fixes get the scans levelled too (IR answers each from its first scan's geometry)
    assert bench.main([str(bag), "--global-fixes", "--every", "10", "--localizers", "ir_initializer",
                       "--workers", "0", "--out", str(tmp_path / "fixes")]) == 0
    fixes = json.loads((tmp_path / "fixes" / "summary.json").read_text())["office_upside_down"]["ir_initializer"]
    assert fixes["global_correct_rate"] >= 0.9, fixes
    # the parameters' mount (laser_x/y/yaw, laser_upside_down) is used only where /tf_static has none
    spec = bench.registry_spec("mcl_baseline", {"laser_x": -1.0, "laser_upside_down": False})
    assert spec.for_bag(reference.name, laser_mounts=reference.laser_mounts).mount == mount
    assert spec.for_bag(reference.name).mount == LaserMount(-1.0, 0.0, 0.0, False)


@pytest.mark.parametrize("pose", [(1e300, 0.0, 0.0), (0.2, -5e5, 0.0), (float("nan"), 0.0, 0.0), (0.0, 0.0, float("inf"))])
def test_a_transform_that_puts_the_laser_off_the_robot_is_no_mount(pose: tuple[float, float, float]) -> None:
    # a /tf_static of 1e300 m gave LOCALIZED poses off the map, then an overflow at every scan
    with pytest.raises(ValueError, match="is not a mount"):
        LaserMount(*pose)
    assert LaserMount(0.3, -0.1, 3.1).pose[0] == 0.3
