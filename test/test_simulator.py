"""The simulator core: scenarios, ray casting with people, noise models, kidnappings, maps.

Hand-made worlds: a 4 m x 3 m room (walls one cell thick around a free
interior whose edges lie on cell boundaries, so distances are analytic).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot_localization_suite.core.errors import ScenarioError
from robot_localization_suite.core.grid_map import GridMap, load_map_yaml
from robot_localization_suite.core.motion import OdometryMotionModel, odometry_delta
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.se2 import angle_difference, relative
from robot_localization_suite.core.sim.config import (
    Kidnapping,
    LaserConfig,
    MapChange,
    MotionPlan,
    OdometryConfig,
    Person,
    Reinitialization,
    VelocitySegment,
)
from robot_localization_suite.core.sim.scenario import Scenario
from robot_localization_suite.core.sim.scenario_yaml import load_scenario, scenario_from_dict
from robot_localization_suite.core.sim.simulator import Simulator, ray_circle_ranges
from robot_localization_suite.tools import make_maps
from robot_localization_suite.tools.make_maps import MAP_BUILDERS

ROOT = Path(__file__).resolve().parent.parent
RES = 0.05
# Free interior of the room [m]: x 0.05..4.05, y 0.05..3.05 (one wall cell all round).
X0, X1, Y0, Y1 = 0.05, 4.05, 0.05, 3.05


def room_map() -> GridMap:
    data = np.full((62, 82), 100, dtype=np.int8)  # 3.1 m x 4.1 m
    data[1:61, 1:81] = 0
    return GridMap(data, RES, (0.0, 0.0))


def room_distance(pose: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Analytic distance from ``pose`` inside the room to its walls along ``angles`` (laser frame)."""
    heading = pose[2] + angles
    dx, dy = np.cos(heading), np.sin(heading)
    with np.errstate(divide="ignore"):
        tx = np.where(dx > 0, (X1 - pose[0]) / dx, np.where(dx < 0, (X0 - pose[0]) / dx, np.inf))
        ty = np.where(dy > 0, (Y1 - pose[1]) / dy, np.where(dy < 0, (Y0 - pose[1]) / dy, np.inf))
    return np.minimum(tx, ty)


def quiet_laser(**changes) -> LaserConfig:
    settings = dict(beams=180, range_noise_std=0.0, outlier_prob=0.0, dropout_prob=0.0, range_max=10.0)
    settings.update(changes)
    return LaserConfig(**settings)


def segments_scenario(**changes) -> Scenario:
    settings = dict(
        grid_map=room_map(),
        start=(1.0, 1.5, 0.0),
        motion=MotionPlan(segments=(VelocitySegment(0.5, 0.0, 2.0), VelocitySegment(0.0, 0.5, 1.0))),
        laser=quiet_laser(),
        odometry=OdometryConfig(),
    )
    settings.update(changes)
    return Scenario(**settings)


# -- determinism ------------------------------------------------------------------------------
def test_same_seed_gives_identical_runs_and_another_seed_differs() -> None:
    scenario = segments_scenario(laser=LaserConfig(beams=90))
    runs = [list(Simulator(scenario, seed=seed).run()) for seed in (5, 5, 6)]
    assert len(runs[0]) == scenario.step_count == 31  # 3 s at 10 Hz plus step 0
    for a, b in zip(runs[0], runs[1], strict=True):
        assert np.array_equal(a.ranges, b.ranges)
        assert np.array_equal(a.odom_pose, b.odom_pose)
        assert np.array_equal(a.true_pose, b.true_pose)
    assert not np.array_equal(runs[0][10].ranges, runs[2][10].ranges)
    assert not np.array_equal(runs[0][-1].odom_pose, runs[2][-1].odom_pose)
    # The true path does not depend on the noise seed.
    assert np.array_equal(runs[0][-1].true_pose, runs[2][-1].true_pose)


# -- ranges -------------------------------------------------------------------------------------
def test_ranges_match_analytic_room_distances_within_the_noise() -> None:
    std = 0.01
    scenario = segments_scenario(laser=quiet_laser(beams=360, range_noise_std=std))
    simulator = Simulator(scenario, seed=1)
    for step in simulator.run():
        expected = room_distance(step.laser_pose, simulator.angles)
        error = step.ranges - expected
        # 5 sigma of the Gaussian noise, plus float32 rounding.
        assert np.all(np.abs(error) < 5 * std + 1e-4), (step.time, np.abs(error).max())
    # and the noise is really there, with about the configured spread
    assert 0.5 * std < np.std(error) < 1.5 * std


def test_range_limits_follow_rep_117() -> None:
    # 1.5 m range: far walls give +inf (no return), nothing below range_min.
    scenario = segments_scenario(laser=quiet_laser(range_max=1.5, beams=360))
    simulator = Simulator(scenario, seed=0)
    step = simulator.step()
    expected = room_distance(step.laser_pose, simulator.angles)
    assert np.all(np.isposinf(step.ranges[expected >= 1.5 + 1e-6]))
    near = expected < 1.5 - 1e-6
    assert np.allclose(step.ranges[near], expected[near], atol=1e-4)


def test_ray_circle_ranges_analytic() -> None:
    circles = np.array([[3.0, 0.0, 0.5], [0.0, -2.0, 0.25]])
    angles = np.array([0.0, -np.pi / 2, np.pi / 2, np.pi, math.atan2(0.5, 3.0)])
    ranges = ray_circle_ranges([0.0, 0.0], angles, circles)
    assert ranges[0] == pytest.approx(2.5)  # straight at the first circle
    assert ranges[1] == pytest.approx(1.75)  # straight down at the second
    assert np.isinf(ranges[2]) and np.isinf(ranges[3])  # nothing up or behind
    # A grazing ray at atan(0.5 / 3) cuts the circle of radius 0.5 at distance 3 near its tangent.
    assert 2.5 < ranges[4] < 3.05
    # A circle containing the origin is ignored.
    assert np.isinf(ray_circle_ranges([0.0, 0.0], [0.0], [[0.1, 0.0, 0.5]])[0])


def test_a_person_shortens_exactly_the_beams_that_hit_it() -> None:
    radius, distance = 0.3, 2.0
    person = Person(radius=radius, speed=0.5, waypoints=((3.0, 1.5),))
    with_person = segments_scenario(people=(person,), laser=quiet_laser(beams=360, range_noise_std=0.005))
    without = segments_scenario(laser=quiet_laser(beams=360, range_noise_std=0.005))
    a = Simulator(with_person, seed=3).step()
    b = Simulator(without, seed=3).step()  # same seed: the same noise draws
    angles = Simulator(without).angles
    half_width = math.asin(radius / distance)
    hit = np.abs(angles) < half_width - 1e-3
    missed = np.abs(angles) > half_width + 1e-3
    assert hit.sum() >= 15
    assert np.array_equal(a.ranges[missed], b.ranges[missed])
    # Entry point on the circle: d cos(phi) - sqrt(r^2 - d^2 sin(phi)^2).
    phi = angles[hit]
    expected = distance * np.cos(phi) - np.sqrt(radius**2 - (distance * np.sin(phi)) ** 2)
    assert np.all(np.abs(a.ranges[hit] - expected) < 0.03)
    assert np.all(a.ranges[hit] < b.ranges[hit] - 0.5)
    assert np.allclose(a.people, [[3.0, 1.5, radius]])


def test_outliers_and_dropouts_happen_at_their_rates() -> None:
    laser = quiet_laser(beams=360, outlier_prob=0.05, dropout_prob=0.03)
    simulator = Simulator(segments_scenario(laser=laser), seed=9)
    steps = list(simulator.run())
    ranges = np.concatenate([s.ranges for s in steps])
    expected = np.concatenate([room_distance(s.laser_pose, simulator.angles) for s in steps])
    dropout = np.isposinf(ranges)
    wrong = ~dropout & (np.abs(ranges - expected) > 1e-3)
    assert 0.02 < dropout.mean() < 0.04
    # An outlier is uniform in [range_min, range_max): most land away from the true range.
    assert 0.035 < wrong.mean() < 0.06


def test_uniform_range_noise_stays_inside_its_bound() -> None:
    bound = 0.02
    laser = quiet_laser(beams=360, range_noise_model="uniform", range_noise_bound=bound, range_noise_std=0.5)
    simulator = Simulator(segments_scenario(laser=laser), seed=4)
    errors = []
    for step in simulator.run():
        errors.append(step.ranges - room_distance(step.laser_pose, simulator.angles))
    errors = np.concatenate(errors)
    assert np.abs(errors).max() <= bound + 1e-4
    assert np.abs(errors).max() > 0.9 * bound  # it does use the whole interval


# -- odometry and kidnapping -------------------------------------------------------------------
def test_kidnapping_jumps_ground_truth_but_not_odometry() -> None:
    target = (3.0, 2.5, -2.0)
    noiseless = OdometryConfig(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0)
    scenario = segments_scenario(kidnappings=(Kidnapping(1.0, target),), odometry=noiseless)
    steps = list(Simulator(scenario, seed=2).run())
    kidnapped = [s for s in steps if s.kidnapped]
    assert [s.index for s in kidnapped] == [10]
    jump = steps[10]
    assert np.allclose(jump.true_pose, target)
    assert np.hypot(*(jump.true_pose[:2] - steps[9].true_pose[:2])) > 1.0
    # Odometry moved by one step of 0.5 m/s x 0.1 s straight ahead, not by the jump.
    odom_step = relative(steps[9].odom_pose, jump.odom_pose)
    assert np.allclose(odom_step, [0.05, 0.0, 0.0], atol=1e-9)
    assert np.allclose(steps[-1].odom_pose[:2], [1.0, 0.0])  # 2 s at 0.5 m/s, then turning in place
    # After the jump the robot carries on driving from the new pose.
    assert np.hypot(*(steps[15].true_pose[:2] - np.array(target[:2]))) == pytest.approx(0.25, abs=1e-6)


def test_bounded_odometry_error_stays_inside_the_stated_bounds() -> None:
    config = OdometryConfig(
        model="bounded",
        relative_translation=0.05,
        absolute_translation=0.002,
        relative_rotation=0.05,
        absolute_rotation=0.002,
        scale_error=0.03,
        heading_drift=0.2,
    )
    steps = list(Simulator(segments_scenario(odometry=config), seed=8).run())
    checked = 0
    for previous, current in zip(steps[:-1], steps[1:], strict=True):
        truth = odometry_delta(previous.true_pose, current.true_pose)
        if truth.trans < 0.01:  # rot1 is undefined for tiny translations
            continue
        measured = odometry_delta(previous.odom_pose, current.odom_pose)
        bounds = OdometryMotionModel.bounds(
            previous.true_pose,
            current.true_pose,
            relative_translation=0.05,
            absolute_translation=0.002,
            relative_rotation=0.05,
            absolute_rotation=0.002,
        )
        assert bounds.trans[0] - 1e-9 <= measured.trans <= bounds.trans[1] + 1e-9
        assert bounds.rot1[0] - 1e-9 <= measured.rot1 <= bounds.rot1[1] + 1e-9
        assert bounds.rot2[0] - 1e-9 <= measured.rot2 <= bounds.rot2[1] + 1e-9
        checked += 1
    assert checked >= 15


def test_alpha_odometry_drifts_as_configured() -> None:
    # No random noise, only a 2 % scale error: 1 m driven reads 1.02 m.
    config = OdometryConfig(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0, scale_error=0.02)
    scenario = segments_scenario(odometry=config, motion=MotionPlan(segments=(VelocitySegment(0.5, 0.0, 2.0),)))
    last = list(Simulator(scenario).run())[-1]
    assert last.true_pose[0] - 1.0 == pytest.approx(1.0)
    assert last.odom_pose[0] == pytest.approx(1.02)
    assert last.odom_velocity[0] == pytest.approx(0.51)


# -- waypoints and cmd_vel --------------------------------------------------------------------------
def test_waypoints_are_followed_rotate_then_drive(room_scenario) -> None:
    data = {
        "map": "room.yaml",
        "start": [1.0, 1.0, 0.0],
        "motion": {
            "linear_speed": 0.5,
            "angular_speed": 1.0,
            "waypoints": [[3.0, 1.0], [3.0, 2.0, 3.14159], {"wait": 1.0}],
        },
        "laser": {"beams": 36},
    }
    scenario = room_scenario(data)
    trajectory = scenario.trajectory
    # 2 m at 0.5 m/s, a quarter turn at 1 rad/s, 1 m, another quarter turn, 1 s wait.
    expected_end = 4.0 + math.pi / 2 + 2.0 + math.pi / 2 + 1.0
    assert scenario.end_time == pytest.approx(expected_end, abs=0.1)
    assert np.allclose(trajectory.poses[-1], [3.0, 2.0, angle_difference(3.14159, 0.0)], atol=1e-6)
    # The path is the polyline: y stays 1 until x reaches 3.
    first_leg = trajectory.poses[trajectory.poses[:, 0] < 2.999]
    assert np.allclose(first_leg[:, 1], 1.0)


def test_cmd_vel_driving_stops_at_walls() -> None:
    scenario = Scenario(grid_map=room_map(), start=(3.5, 1.5, 0.0), laser=quiet_laser())
    simulator = Simulator(scenario)
    assert not simulator.finished
    simulator.step()
    steps = [simulator.step((1.0, 0.0)) for _ in range(20)]
    assert any(s.blocked for s in steps)
    # The robot keeps its radius (0.2 m) from the east wall at x = 4.05.
    assert steps[-1].true_pose[0] <= X1 - 0.2 + 1e-9
    assert steps[-1].true_pose[0] > X1 - 0.2 - 0.1
    with pytest.raises(ScenarioError, match="finite"):
        simulator.step((math.nan, 0.0))


# -- validation -------------------------------------------------------------------------------------
@pytest.fixture
def room_scenario(tmp_path: Path):
    """Build a scenario from a dict whose ``map: room.yaml`` is the hand-made room."""
    room_map().save(tmp_path / "room.yaml")
    return lambda data: scenario_from_dict(data, tmp_path)


def test_start_pose_in_an_obstacle_is_refused_with_the_pose(room_scenario) -> None:
    with pytest.raises(ScenarioError, match=r"start pose \[0\.020, 1\.500, 0\.000\] lies in an obstacle"):
        room_scenario({"map": "room.yaml", "start": [0.02, 1.5, 0.0]})
    with pytest.raises(ScenarioError, match=r"start pose \[0\.150, 1\.500, 0\.000\] is 0\.075 m from an obstacle"):
        room_scenario({"map": "room.yaml", "start": [0.15, 1.5, 0.0]})


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"laser": {"fov_deg": 45}}, r"laser\.fov_deg must be within \[90, 360\], got 45"),
        ({"laser": {"range_noise_std": -0.01}}, r"laser\.range_noise_std must be >= 0, got -0\.01"),
        ({"laser": {"range_noise_model": "cauchy"}}, r"range_noise_model must be one of .* got 'cauchy'"),
        ({"laser": {"outlier_prob": 1.5}}, r"laser\.outlier_prob must be within \[0, 1\], got 1\.5"),
        ({"laser": {"beams": 360.5}}, r"laser\.beams must be an integer, got 360\.5"),
        ({"laser": {"beams": 10**9}}, r"laser\.beams must be an integer within \[2, 100000\], got 1000000000"),
        ({"laser": {"rate_hz": 1e9}}, r"laser\.rate_hz must be within \(0, 1000\] Hz, got 1000000000\.0"),
        ({"duration": 1e9}, r"duration 1000000000\.0 s is longer than 86400 s, the most a scenario may last"),
        ({"duration": 3600, "laser": {"rate_hz": 1000}}, r"duration 3600\.0 s is longer than 999\.999 s, .* 1000000 laser steps"),
        (
            {"motion": {"segments": [{"v": 0.0, "w": 0.0, "duration": 1e6}]}},
            r"motion\.segments last 1000000\.0 s, longer than 86400 s",
        ),
        ({"motion": {"linear_speed": 1e-9, "waypoints": [[2.0, 1.0]]}}, r"motion\.linear_speed must be >= 0\.01, got 1e-09"),
        (
            {"motion": {"waypoints": [[2.0, 1.0]]}, "kidnappings": [{"time": 1e9, "pose": [2.0, 1.0, 0.0]}]},
            r"kidnappings\[0\]\.time 1000000000\.0 s is after 86400 s, the most a scenario may last",
        ),
        ({"odometry": {"alpha3": -1}}, r"odometry\.alpha3 must be >= 0, got -1"),
        ({"seed": -3}, r"seed must be an integer >= 0, got -3"),
        ({"motion": {"waypoints": [[2.0, 1.0], [9.0, 1.0]]}}, r"motion\.waypoints\[1\] \[9\.0, 1\.0\] is off the map"),
        ({"motion": {"waypoints": [[2.0, 1.0]], "segments": [{"v": 1, "w": 0, "duration": 1}]}}, "exactly one"),
        (
            {"kidnappings": [{"time": 1.0, "pose": [5.0, 1.0, 0.0]}]},
            r"kidnappings\[0\]\.pose .* \[5\.000, 1\.000, 0\.000\] is off the map",
        ),
        (
            {"people": [{"radius": 0.2, "speed": 1.0, "waypoints": [[1.0, 1.0], [1.0, 5.0]]}]},
            r"people\[0\] walks through an obstacle",
        ),
        ({"laser": {"beams": 90, "colour": "red"}}, r"laser has unknown key\(s\) \['colour'\]"),
        (
            {"motion": {"waypoints": [[3.9, 1.0]]}},
            r"the robot path reaches \[3\.8\d\d, 1\.000, 0\.000\] at t = 5\.\d\d s, 0\.175 m from an obstacle",
        ),
    ],
)
def test_bad_scenarios_are_refused_naming_the_value(room_scenario, changes: dict, message: str) -> None:
    data = {"map": "room.yaml", "start": [1.0, 1.0, 0.0], **changes}
    with pytest.raises(ScenarioError, match=message):
        room_scenario(data)


def test_a_scenario_without_motion_needs_a_duration(room_scenario) -> None:
    # Without either it never ends: scan_sim --record ran "of inf s simulated" until killed.
    with pytest.raises(ScenarioError, match=r"scenario has no 'motion' \(waypoints or segments\) and no 'duration'"):
        room_scenario({"map": "room.yaml", "start": [1.0, 1.0, 0.0]})
    standing = room_scenario({"map": "room.yaml", "start": [1.0, 1.0, 0.0], "duration": 2.0})
    assert standing.end_time == 2.0 and standing.step_count == 21


def test_a_route_longer_than_a_scenario_may_last_is_refused(room_scenario, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("robot_localization_suite.core.sim.scenario.MAX_DURATION_S", 3.0)
    with pytest.raises(ScenarioError, match=r"motion\.waypoints do not end within 3 s, the most a scenario may last"):
        room_scenario({"map": "room.yaml", "start": [1.0, 1.0, 0.0], "motion": {"waypoints": [[2.0, 1.0], {"wait": 5.0}]}})
    assert room_scenario({"map": "room.yaml", "start": [1.0, 1.0, 0.0], "motion": {"waypoints": [[2.0, 1.0]]}})


def test_missing_map_is_a_scenario_error(tmp_path: Path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"map": "nowhere.yaml", "start": [1, 1, 0]}))
    with pytest.raises(ScenarioError, match=r"nowhere\.yaml"):
        load_scenario(path)


# -- camera hook -------------------------------------------------------------------------------------
def test_camera_images_at_their_rate_and_lazy_import(room_scenario, monkeypatch: pytest.MonkeyPatch) -> None:
    data = {
        "map": "room.yaml",
        "start": [1.0, 1.5, 0.0],
        "motion": {"segments": [{"v": 0.3, "w": 0.2, "duration": 1.0}]},
        "laser": {"beams": 36},
        "camera": {"hfov_deg": 60, "width": 32, "height": 24, "rate_hz": 5.0, "encoding": "mono8"},
    }
    steps = list(Simulator(room_scenario(data)).run())
    with_image = [s.index for s in steps if s.image is not None]
    assert with_image == [0, 2, 4, 6, 8, 10]  # 5 Hz against a 10 Hz laser
    assert steps[0].image.shape == (24, 32) and steps[0].image.dtype == np.uint8
    # Without a camera section the camera module is never needed.
    monkeypatch.setitem(sys.modules, "robot_localization_suite.core.sim.camera", None)
    no_camera = dict(data)
    del no_camera["camera"]
    assert all(s.image is None for s in Simulator(room_scenario(no_camera)).run())
    with pytest.raises(ScenarioError, match="camera renderer cannot be loaded"):
        Simulator(room_scenario(data))


# -- the committed maps and scenarios -----------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(MAP_BUILDERS))
def test_committed_maps_are_what_make_maps_builds(name: str) -> None:
    committed = load_map_yaml(ROOT / "config" / "maps" / f"{name}.yaml", exact_resolution=True)
    built = MAP_BUILDERS[name](0.05)
    assert np.array_equal(committed.data, built.data)
    assert committed.resolution == 0.05


@pytest.mark.parametrize("resolution", ["0", "-0.05", "nan", "1e-6", "100"])
def test_make_maps_refuses_a_resolution_out_of_range(resolution: str, tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        make_maps.main(["--out", str(tmp_path), f"--resolution={resolution}", "corridor"])
    assert exit_info.value.code == 2
    assert f"argument --resolution: must be within [0.001, 0.5] m, got {resolution!r}" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_make_maps_refuses_an_out_folder_that_is_a_file(tmp_path: Path, capsys) -> None:
    (tmp_path / "afile").write_text("")
    for out in (tmp_path / "afile", tmp_path / "afile" / "maps"):
        with pytest.raises(SystemExit) as exit_info:
            make_maps.main(["--out", str(out), "corridor"])
        assert exit_info.value.code == 2
        assert f"--out {str(out)!r}: {str(tmp_path / 'afile')!r} is a file, not a folder" in capsys.readouterr().err


def test_map_sizes_and_corridor_symmetry() -> None:
    sizes = {name: load_map_yaml(ROOT / "config" / "maps" / f"{name}.yaml") for name in MAP_BUILDERS}
    assert (sizes["office"].width, sizes["office"].height) == (400, 400)
    assert (sizes["floor"].width, sizes["floor"].height) == (600, 220)
    assert (sizes["corridor"].width, sizes["corridor"].height) == (520, 80)
    corridor = sizes["corridor"].data
    different = corridor != np.rot90(corridor, 2)
    # Only the cabinet (0.7 m x 0.4 m, 112 cells) and its empty twin place differ.
    assert different.sum() == 224
    office = sizes["office"].data
    assert (office != np.rot90(office, 2)).mean() > 0.05 and (office != office[:, ::-1]).mean() > 0.05


@pytest.mark.parametrize("name", ["office_kidnap", "floor_kidnap", "corridor_kidnap"])
def test_kidnap_scenarios_meet_the_brief(name: str) -> None:
    scenario = load_scenario(ROOT / "config" / "scenarios" / f"{name}.yaml")
    assert 90.0 <= scenario.end_time <= 180.0
    assert len(scenario.kidnappings) >= 2
    assert scenario.laser.fov_deg == 360.0 and scenario.laser.beams == 360
    assert len(scenario.people) >= 2
    assert scenario.trajectory.kidnapped.sum() == len(scenario.kidnappings)


@pytest.mark.parametrize(
    ("name", "original", "twin", "max_changed"),
    [
        # the twin offices, 5 m apart: from this spot even the beams through the door agree
        ("office", (1.6, 3.2, 0.0), (6.6, 3.2, 0.0), 0.01),
        # the corridor twin under a half turn about (13, 2): identical scans but for a beam
        # grazing a cell corner or ending right at the 8 m limit
        ("corridor", (14.5, 2.0, 0.0), (11.5, 2.0, math.pi), 0.01),
        # the floor corridor: the same under a half turn about (16, 5.5) within 8 m
        ("floor", (16.0, 5.5, 0.0), (16.0, 5.5, math.pi), 0.02),
    ],
)
def test_ambiguous_kidnap_targets_look_alike(name: str, original, twin, max_changed: float) -> None:
    grid_map = load_map_yaml(ROOT / "config" / "maps" / f"{name}.yaml")
    caster = RayCaster(grid_map, max_range=8.0)
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    a, b = caster.cast(np.array([original, twin]), angles)
    with np.errstate(invalid="ignore"):  # inf - inf
        same = (np.isinf(a) & np.isinf(b)) | (np.abs(a - b) <= 0.1)
    changed = ~same
    assert changed.mean() <= max_changed


# -- world events: map changes and reinitialization requests ---------------------------------------
def changed_room_map() -> GridMap:
    """The room with a 0.5 m box at x 2.5..3.0, y 1.25..1.75 (right in front of the start pose)."""
    data = room_map().data.copy()
    data[25:35, 50:60] = 100
    return GridMap(data, RES, (0.0, 0.0))


def test_a_map_change_switches_the_sensed_map_at_its_step_and_a_reinitialization_is_flagged() -> None:
    changed = changed_room_map()
    standing = MotionPlan(segments=(VelocitySegment(0.0, 0.0, 2.0),))
    scenario = segments_scenario(motion=standing, map_changes=(MapChange(0.95, changed, "changed.yaml"),),
                                 reinitializations=(Reinitialization(1.5),))
    simulator = Simulator(scenario, seed=1)
    steps = list(simulator.run())
    assert [s.index for s in steps if s.new_map is not None] == [10]  # the first step at or after 0.95 s
    assert steps[10].new_map is changed and simulator.grid_map is changed
    assert [s.index for s in steps if s.reinitialize] == [15]
    # Noiseless laser facing east from (1.0, 1.5): 3.05 m to the wall before, 1.5 m to the box from step 10.
    ahead = int(np.argmin(np.abs(scenario.laser.angles)))
    before, after = steps[9].ranges[ahead], steps[10].ranges[ahead]
    assert before == pytest.approx(X1 - 1.0, abs=0.03) and after == pytest.approx(1.5, abs=0.03)
    expected = RayCaster(changed, max_range=scenario.laser.range_max).cast(steps[12].laser_pose, scenario.laser.angles)
    finite = np.isfinite(expected)
    assert np.allclose(steps[12].ranges[finite], expected[finite], atol=1e-4)
    assert scenario.map_at(0.9) is scenario.grid_map and scenario.map_at(0.95) is changed


@pytest.mark.parametrize(
    ("events", "message"),
    [
        ({"map_changes": [{"time": -1.0, "map": "changed.yaml"}]}, r"map_changes\[0\]\.time must be >= 0, got -1"),
        ({"map_changes": [{"time": 1.0, "map": "nowhere.yaml"}]}, r"map_changes\[0\]\.map 'nowhere\.yaml'.*does not exist"),
        ({"map_changes": [{"time": 1.0}]}, r"map_changes\[0\] needs 'time' and 'map'"),
        ({"map_changes": [{"time": 1.0, "map": "coarse.yaml"}]}, r"map_changes\[0\]\.map coarse\.yaml has resolution 0\.1"),
        ({"map_changes": [{"time": 1.0, "map": "shifted.yaml"}]}, r"map_changes\[0\]\.map shifted\.yaml has origin"),
        ({"map_changes": [{"time": 0.95, "map": "changed.yaml"}, {"time": 1.0, "map": "changed.yaml"}]},
         r"map_changes\[1\]\.time 1\.0 s must be at least one laser step after"),
        ({"map_changes": [{"time": 9.0, "map": "changed.yaml"}]}, r"map_changes\[0\]\.time 9\.0 s is after the scenario end"),
        # The robot drives east from (1.0, 1.5) at 0.5 m/s: the box appears in its way at 1 s.
        ({"map_changes": [{"time": 1.0, "map": "changed.yaml"}], "start": [1.0, 1.5, 0.0],
          "motion": {"segments": [{"v": 0.5, "w": 0.0, "duration": 4.0}]}},
         r"the robot path reaches .* from an obstacle of map_changes\[0\] \(changed\.yaml\)"),
        ({"reinitializations": [{"time": -0.5}]}, r"reinitializations\[0\]\.time must be >= 0, got -0\.5"),
        ({"reinitializations": [{"time": 2.0}, {"time": 1.0}]}, r"reinitializations\[1\]\.time 1\.0 s is before the previous"),
        ({"reinitializations": [{"time": 9.0}]}, r"reinitializations\[0\]\.time 9\.0 s is after the scenario end"),
        ({"reinitializations": [{"when": 1.0}]}, r"reinitializations\[0\] has unknown key\(s\) \['when'\]"),
    ],
)
def test_bad_world_events_are_refused_naming_the_value(tmp_path: Path, events: dict, message: str) -> None:
    room_map().save(tmp_path / "room.yaml")
    changed_room_map().save(tmp_path / "changed.yaml")
    GridMap(room_map().data[::2, ::2].copy(), 0.1, (0.0, 0.0)).save(tmp_path / "coarse.yaml")
    GridMap(room_map().data, RES, (0.5, 0.0)).save(tmp_path / "shifted.yaml")
    data = {"map": "room.yaml", "start": [1.0, 2.5, 0.0], "motion": {"segments": [{"v": 0.0, "w": 0.0, "duration": 3.0}]},
            **events}
    with pytest.raises(ScenarioError, match=message):
        scenario_from_dict(data, tmp_path)


def test_the_map_change_scenario_meets_its_brief() -> None:
    """office_mapchange: a changed office, a map change while moving and a reinitialization in the twin office."""
    scenario = load_scenario(ROOT / "config" / "scenarios" / "office_mapchange.yaml")
    assert [c.path for c in scenario.map_changes] == ["../maps/office_changed.yaml"]
    changed = scenario.map_changes[0].grid_map
    assert np.array_equal(changed.data, MAP_BUILDERS["office_changed"](0.05).data)
    assert 1000 < int((changed.data != scenario.grid_map.data).sum()) < 5000  # a changed building, not another one
    trajectory = scenario.trajectory
    change, request = scenario.event_step(scenario.map_changes[0].time), scenario.event_step(scenario.reinitializations[0].time)
    assert np.hypot(*(trajectory.poses[change + 1, :2] - trajectory.poses[change - 1, :2])) > 0.05  # moving
    assert np.allclose(trajectory.poses[request], [6.6, 3.2, 0.0])  # waiting in the east twin office
