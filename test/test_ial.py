"""IAL core: interval arithmetic, obstacle queries, the contractor's guarantee, Algorithm 1, restart, outputs.

Worlds are hand-made: the non-symmetric 16 m x 10 m office of ``mcl_test_world``
(no two places alike) with scans cast by the shared RayCaster, uniform range
noise inside eps_y, and odometry from the simulator's bounded model, so that
every bound IAL declares holds and the guarantee must too.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import slam_test_world
from hypothesis import given, settings
from hypothesis import strategies as st
from mcl_test_world import WAYPOINTS, _follow, office_map

from robot_localization_suite import registry
from robot_localization_suite.core.errors import SettingsError
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.ial.kernels import contract_box, inmap_hull, obstacle_hull, pave
from robot_localization_suite.core.ial.localizer import (
    IALSettings,
    IntervalLocalizer,
    ObstacleGrid,
    beam_intervals,
    boxes_hull,
)
from robot_localization_suite.core.interval import angle_hull, compose_boxes, interval_cos, interval_mul, interval_sin
from robot_localization_suite.core.localizer import GlobalFixer, Localizer, LocalizerStatus
from robot_localization_suite.core.metrics import boxes_contain
from robot_localization_suite.core.motion import OdometryMotionModel
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.scan import LaserMount, Scan
from robot_localization_suite.core.se2 import compose, wrap_angle
from robot_localization_suite.core.sim.config import OdometryConfig
from robot_localization_suite.core.sim.simulator import OdometrySimulator

EPS = 0.05  # eps_y of the tests [m]
RANGE_MAX = 10.0
ANGLES_360 = -math.pi + 2.0 * math.pi * np.arange(360) / 360
BOUNDED_ODOMETRY = OdometryConfig(model="bounded", relative_translation=0.05, absolute_translation=0.002,
                                  relative_rotation=0.05, absolute_rotation=0.002, scale_error=0.01,
                                  heading_drift=0.005)
# IAL's odometry bounds, as loose as or looser than BOUNDED_ODOMETRY's.
ODOM_BOUNDS = dict(odom_relative_translation=0.05, odom_absolute_translation=0.002,
                   odom_relative_rotation=0.05, odom_absolute_rotation=0.002)


@pytest.fixture(scope="module")
def office() -> GridMap:
    return office_map()


@pytest.fixture(scope="module")
def grid(office: GridMap) -> ObstacleGrid:
    return ObstacleGrid(office)


def bounded_scan(grid_map: GridMap, pose, rng, *, outliers: int = 0, stamp: float = 0.0, used: int = 36) -> Scan:
    """360 readings within +-EPS of the truth (float32), ``outliers`` of the ``used`` evenly picked ones random."""
    exact = RayCaster(grid_map, max_range=RANGE_MAX).cast(np.asarray(pose, float), ANGLES_360).astype(np.float64)
    ranges = np.where(np.isfinite(exact), exact + rng.uniform(-EPS, EPS, 360), np.inf)
    valid = np.flatnonzero(np.isfinite(ranges) & (ranges >= 0.1) & (ranges < RANGE_MAX))
    picked = valid[np.unique(np.round(np.linspace(0, valid.size - 1, min(used, valid.size))).astype(np.int64))]
    bad = rng.choice(picked, size=outliers, replace=False)
    ranges[bad] = rng.uniform(0.2, RANGE_MAX - 0.5, outliers)
    return Scan(stamp, ANGLES_360.copy(), ranges.astype(np.float32).astype(np.float64), 0.1, RANGE_MAX)


def bounded_drive(grid_map: GridMap, steps: int, seed: int, *, kidnap_step: int | None = None):
    """True poses along the office loop (5 cm steps), bounded odometry, bounded scans with <= 3 outliers."""
    rng = np.random.default_rng(seed)
    if kidnap_step is None:
        truth = _follow(WAYPOINTS, 0, steps, 0.05)
    else:
        truth = np.vstack([_follow(WAYPOINTS, 0, kidnap_step, 0.05), _follow(WAYPOINTS, 9, steps - kidnap_step, 0.05)])
    odometry_sim = OdometrySimulator(BOUNDED_ODOMETRY, rng)
    odometry = [odometry_sim.pose.copy()]
    for k in range(1, steps):
        if k == kidnap_step:  # the jump is not seen by the wheels
            odometry.append(odometry_sim.pose.copy())
        else:
            odometry.append(odometry_sim.step(truth[k - 1], truth[k]))
    scans = [bounded_scan(grid_map, truth[k], rng, outliers=int(rng.integers(0, 4)), stamp=0.1 * k) for k in range(steps)]
    return truth, np.array(odometry), scans


# -- interval arithmetic ------------------------------------------------------------------------
def test_interval_sin_cos_and_products_contain_every_point_on_100000_random_intervals() -> None:
    rng = np.random.default_rng(0)
    lo = rng.uniform(-30.0, 30.0, 100_000)
    hi = lo + rng.exponential(1.0, lo.size)
    t = lo + (hi - lo) * rng.random(lo.size)
    for function, interval in ((np.cos, interval_cos), (np.sin, interval_sin)):
        out_lo, out_hi = interval(lo, hi)
        assert np.all((out_lo <= function(t)) & (function(t) <= out_hi))
        assert np.all(out_hi - out_lo <= np.minimum(hi - lo, 2.0) + 1e-6)  # Lipschitz 1: never wider than needed
    b_lo = rng.uniform(-3, 3, lo.size)
    b_hi = b_lo + rng.exponential(1.0, lo.size)
    s = b_lo + (b_hi - b_lo) * rng.random(lo.size)
    p_lo, p_hi = interval_mul(lo, hi, b_lo, b_hi)
    assert np.all((p_lo <= t * s) & (t * s <= p_hi))


@settings(max_examples=300, deadline=None)
@given(st.floats(-50.0, 50.0), st.floats(0.0, 7.0), st.floats(0.0, 1.0))
def test_interval_cos_sin_are_tight_at_the_extrema(lo: float, width: float, fraction: float) -> None:
    hi = lo + width
    (c_lo, c_hi), (s_lo, s_hi) = interval_cos(lo, hi), interval_sin(lo, hi)
    t = lo + fraction * width
    assert c_lo <= math.cos(t) <= c_hi and s_lo <= math.sin(t) <= s_hi
    # each bound is attained (within the 1e-9 margin) by an endpoint or an extremum inside
    samples = np.linspace(lo, hi, 20001)
    assert c_hi - np.cos(samples).max() < 1e-6 and np.cos(samples).min() - c_lo < 1e-6


def test_angle_hull_covers_every_interval_across_the_cut_and_is_the_shortest_arc() -> None:
    assert angle_hull([3.0, -3.0], [3.5, -2.9]) == pytest.approx((3.0, 3.5))  # -3.0..-2.9 is inside 3.0..3.5
    assert angle_hull([0.1, 2.0], [0.2, 2.1]) == pytest.approx((0.1, 2.1))
    start, end = angle_hull([0.1, 2.0, -2.0], [0.2, 2.1, -1.9])  # the widest gap is 2.1 -> -2.0 + 2 pi
    assert (start, end) == pytest.approx((-2.0, 2.1))
    assert angle_hull([0.0], [7.0]) == pytest.approx((-math.pi, math.pi))
    rng = np.random.default_rng(1)
    for _ in range(200):
        lo = rng.uniform(-10, 10, 5)
        hi = lo + rng.uniform(0, 1.0, 5)
        start, end = angle_hull(lo, hi)
        points = lo + (hi - lo) * rng.random(5)
        offset = np.mod(points - start, 2 * math.pi)
        assert np.all(offset <= end - start + 1e-9)


# -- obstacle queries ---------------------------------------------------------------------------
def test_obstacle_hull_and_count_match_brute_force_with_off_map_cells_as_obstacles() -> None:
    rng = np.random.default_rng(2)
    mask = rng.random((23, 31)) < 0.03
    grid = ObstacleGrid(GridMap(np.where(mask, 100, 0).astype(np.int8), 0.1))
    pad = 20  # off-map obstacles on every side, more than any rectangle reaches
    padded = np.ones((23 + 2 * pad, 31 + 2 * pad), dtype=bool)
    padded[pad:-pad, pad:-pad] = mask
    for _ in range(3000):
        c0, r0 = rng.integers(-8, 33), rng.integers(-8, 25)
        c1, r1 = c0 + rng.integers(0, 12), r0 + rng.integers(0, 12)
        window = padded[r0 + pad : r1 + pad + 1, c0 + pad : c1 + pad + 1]
        found, hc0, hc1, hr0, hr1 = obstacle_hull(grid.sat, c0, c1, r0, r1)
        rows, cols = np.nonzero(window)
        assert found == bool(rows.size)
        if rows.size:
            assert (hc0, hc1, hr0, hr1) == (c0 + cols.min(), c0 + cols.max(), r0 + rows.min(), r0 + rows.max())
        # the in-map hull of free cells ignores the off-map ones
        free_found, *free_hull = inmap_hull(grid.free_sat, c0, c1, r0, r1)
        in_map = np.zeros_like(padded)
        in_map[pad:-pad, pad:-pad] = ~mask
        free_window = in_map[r0 + pad : r1 + pad + 1, c0 + pad : c1 + pad + 1]
        assert free_found == bool(free_window.any())
        if free_window.any():
            rows, cols = np.nonzero(free_window)
            assert tuple(free_hull) == (c0 + cols.min(), c0 + cols.max(), r0 + rows.min(), r0 + rows.max())


# -- the contractor's guarantee -----------------------------------------------------------------
def _random_cases(office: GridMap, count: int, rng: np.random.Generator):
    """Bounded-noise cases: pose, beams (8-40 of 72), ranges within eps (<= n_o outliers), a box around the pose."""
    poses = office.sample_free_poses(count, rng)
    clear = office.distance_field()[office.world_to_cell(poses[:, :2])[:, 1], office.world_to_cell(poses[:, :2])[:, 0]]
    poses = poses[clear > 0.1]  # the laser sits in a robot, away from walls
    angles = -math.pi + 2.0 * math.pi * np.arange(72) / 72
    exact = RayCaster(office, max_range=RANGE_MAX).cast(poses, angles).astype(np.float64)
    for k, pose in enumerate(poses):
        n = int(rng.integers(8, 41))
        index = np.sort(rng.choice(72, size=n, replace=False))
        ranges = exact[k, index] + rng.uniform(-EPS, EPS, n)
        keep = np.isfinite(ranges) & (ranges > 0.1)
        index, ranges = index[keep], ranges[keep]
        if ranges.size < 4:
            continue
        max_outliers = int(rng.integers(0, 4))
        bad = rng.choice(ranges.size, size=int(rng.integers(0, max_outliers + 1)), replace=False)
        ranges[bad] = rng.uniform(0.2, RANGE_MAX, bad.size)
        scan = Scan(0.0, angles[index], ranges.astype(np.float32).astype(np.float64), 0.1, RANGE_MAX + 1.0)
        beam_angles, lo, hi = beam_intervals(scan, range_error=EPS, max_beams=100)
        half = np.exp(rng.uniform(np.log([1e-3, 1e-3, 1e-4]), np.log([1.0, 1.0, 1.0])))
        centre = pose + rng.uniform(-1.0, 1.0, 3) * half
        box = np.array([centre[0] - half[0], centre[0] + half[0], centre[1] - half[1], centre[1] + half[1],
                        centre[2] - half[2], centre[2] + half[2]])
        yield pose, box, beam_angles, lo, hi, max_outliers


def test_the_contractor_never_removes_the_true_pose_on_10000_random_bounded_noise_cases(office, grid) -> None:
    rng = np.random.default_rng(3)
    checked = contracted = 0
    scratch, ok, top = np.empty((40, 12)), np.empty(40, dtype=np.bool_), np.empty((6, 4))
    while checked < 10_000:
        for pose, box, angles, lo, hi, n_o in _random_cases(office, 2000, rng):
            before = box.copy()
            consistent = contract_box(box, angles, lo, hi, n_o, grid.sat, grid.free_sat, grid.certain_sat, 9,
                                      0.0, 0.0, office.resolution, 0.0, scratch, ok, top)
            assert consistent >= angles.size - n_o, (pose, before)
            assert boxes_contain(box, pose), (pose, before, box)
            contracted += bool(np.any(box != before))
            checked += 1
    assert contracted > checked // 4  # the property is not vacuous: boxes do shrink


def test_paving_keeps_the_true_pose_and_bisects_down_to_xi(office, grid) -> None:
    rng = np.random.default_rng(4)
    xi = np.array([0.05, 0.05, math.radians(1.0)])
    runs = 0
    for pose, box, angles, lo, hi, n_o in _random_cases(office, 150, rng):
        boxes, consistent, _, limited = pave(box[None, :], angles, lo, hi, n_o, grid.sat, grid.free_sat,
                                             grid.certain_sat, 9, 0.0, 0.0, office.resolution, 0.0, xi, 3, 0.05,
                                             5000, 200_000)
        assert boxes_contain(boxes, pose)
        if not limited:
            assert np.all(boxes[:, 1::2] - boxes[:, 0::2] <= xi + 1e-9)
        runs += 1
    assert runs > 100


def test_a_slam_style_map_keeps_the_guarantee_with_a_one_cell_margin() -> None:
    # The world at 1 cm; the localizer's map at 5 cm marks a cell when its centre is inside a wall (what
    # SLAM produces), so walls are off by up to a cell: map_margin = one cell keeps the truth (DESIGN.md).
    fine = np.zeros((500, 800), dtype=np.int8)
    fine[:12, :] = fine[-12:, :] = fine[:, :12] = fine[:, -12:] = 100
    fine[180:250, 230:241] = fine[300:313, 400:620] = fine[60:130, 560:571] = 100
    world = GridMap(fine, 0.01)
    coarse = GridMap(np.where(fine[2::5, 2::5] > 0, 100, 0).astype(np.int8), 0.05)
    grid = ObstacleGrid(coarse, margin=0.05)
    rng = np.random.default_rng(5)
    scratch, ok, top = np.empty((40, 12)), np.empty(40, dtype=np.bool_), np.empty((6, 4))
    checked = 0
    for pose, box, angles, lo, hi, n_o in _random_cases(world, 600, rng):
        consistent = contract_box(box, angles, lo, hi, n_o, grid.sat, grid.free_sat, grid.certain_sat, 9,
                                  0.0, 0.0, 0.05, 0.05, scratch, ok, top)
        assert consistent >= 0 and boxes_contain(box, pose), (pose, box)
        checked += 1
    assert checked > 300


def test_the_laser_cell_constraint_can_be_removed_as_in_the_paper() -> None:
    # a box of laser positions wholly inside a pillar: refused with the constraint, kept without (paper)
    data = np.zeros((40, 40), dtype=np.int8)
    data[:1, :] = data[-1:, :] = data[:, :1] = data[:, -1:] = 100
    data[15:25, 15:25] = 100  # the pillar: 0.75-1.25 m
    pillar = GridMap(data, 0.05, (0.0, 0.0))
    inside = np.array([0.85, 1.15, 0.85, 1.15, 0.0, 0.1])
    free = np.array([0.2, 0.4, 0.2, 0.4, 0.0, 0.1])
    none = np.zeros(0)
    for constraint, kept in ((True, False), (False, True)):
        grid = ObstacleGrid(pillar, laser_cell_constraint=constraint, laser_in_free_cells=False)
        for box, expected in ((inside.copy(), kept), (free.copy(), True)):
            consistent = contract_box(box, none, none, none, 0, grid.sat, grid.free_sat, grid.certain_sat, 9,
                                      0.0, 0.0, 0.05, 0.0, np.zeros((0, 12)), np.zeros(0, dtype=bool),
                                      np.zeros((6, 1)))
            assert (consistent >= 0) is expected, (constraint, box)
    # the setting reaches the grid
    localizer = IntervalLocalizer(IALSettings(laser_cell_constraint=False), pillar)
    assert localizer.obstacles is not None and localizer.obstacles.free_sat[-1, -1] == data.size


def _slam_params(**overrides) -> IALSettings:
    """config/ial_localizer_slam.yaml, as rls_bench reads it for the real logs, with ``overrides``."""
    _, settings = registry.plugin("ial_localizer").load_settings(
        overrides, params_file=registry.config_dir() / "ial_localizer_slam.yaml")
    assert isinstance(settings, IALSettings)
    return settings


@pytest.mark.parametrize("unknown_is_obstacle", [True, False])
def test_a_reading_into_unknown_space_never_empties_the_true_pose_box(unknown_is_obstacle: bool) -> None:
    # Readings through the window, the unmapped room's door and the wall's gap end in unknown space.
    # Unknown cells as possible ends (the default): they need no outlier at all. Unknown space as an
    # outlier (the SLAM config): they are counted, and max_outliers = outliers + that count is enough.
    world, slam = slam_test_world.slam_world()
    settings = _slam_params(unknown_is_obstacle=unknown_is_obstacle)
    grid = ObstacleGrid(slam, margin=settings.map_margin, laser_in_free_cells=settings.laser_in_free_cells,
                        unknown_is_obstacle=unknown_is_obstacle)
    rng = np.random.default_rng(21)
    truth = slam_test_world.drive(0.1)
    angles = slam_test_world.ANGLES_180
    exact = RayCaster(world, max_range=slam_test_world.RANGE_MAX).cast(truth, angles).astype(np.float64)
    scratch, ok, top = np.empty((180, 12)), np.empty(180, dtype=np.bool_), np.empty((6, 181))
    into_unknown = checked = 0
    for pose, ranges in zip(truth, exact, strict=True):
        keep = np.isfinite(ranges)
        beams, distances = angles[keep], ranges[keep]
        unexplained = slam_test_world.unexplained(slam, pose, beams, distances, settings.map_margin)
        noisy = distances + rng.uniform(-slam_test_world.EPS, slam_test_world.EPS, distances.size)
        outliers = rng.choice(distances.size, size=int(rng.integers(0, 4)), replace=False)
        noisy[outliers] = rng.uniform(0.2, 9.0, outliers.size)  # readings no map explains
        scan = Scan(0.0, beams, noisy.astype(np.float32).astype(np.float64), 0.05, slam_test_world.RANGE_MAX)
        beam_angles, lo, hi = beam_intervals(scan, range_error=settings.range_error, max_beams=180)
        budget = outliers.size + (0 if unknown_is_obstacle else unexplained)
        for _ in range(5):
            half = np.exp(rng.uniform(np.log([1e-3, 1e-3, 1e-4]), np.log([0.5, 0.5, 0.2])))
            centre = pose + rng.uniform(-1.0, 1.0, 3) * half
            box = np.array([centre[0] - half[0], centre[0] + half[0], centre[1] - half[1], centre[1] + half[1],
                            centre[2] - half[2], centre[2] + half[2]])
            consistent = contract_box(box, beam_angles, lo, hi, budget, grid.sat, grid.free_sat, grid.certain_sat,
                                      settings.free_space_samples, slam.origin[0], slam.origin[1], slam.resolution,
                                      settings.map_margin, scratch, ok, top)
            assert consistent >= 0 and boxes_contain(box, pose), (pose, unexplained, budget)
            checked += 1
        into_unknown += unexplained > 0
    assert checked >= 1000 and into_unknown > len(truth) // 2  # most scans do see unknown space


def test_tracking_on_a_slam_like_map_keeps_the_truth_in_the_boxes() -> None:
    # A 180-degree scanner on a map with unknown space behind its walls, a wall with a gap and a room
    # never mapped; Thrun odometry within 4 sigma. With unknown cells as possible ends the guarantee
    # holds on the whole drive; with the SLAM config (unknown space counts as an outlier) it holds while
    # at most max_outliers readings of a scan end away from mapped walls, here the first 28 scans.
    world, slam = slam_test_world.slam_world()
    truth = slam_test_world.drive()
    rng = np.random.default_rng(22)
    odometry = slam_test_world.odometry(truth, rng)
    scans = slam_test_world.scans(world, truth, rng)
    for params, steps in ((_slam_params(unknown_is_obstacle=True), len(truth)), (_slam_params(), 28)):
        localizer = IntervalLocalizer(params, slam)
        localizer.on_odometry(0.0, odometry[0])
        localizer.set_initial_pose(truth[0], np.diag([0.1, 0.1, math.radians(5.0)]) ** 2)
        most_unexplained = 0
        for k in range(steps):
            localizer.on_odometry(0.1 * k, odometry[k])
            estimate = localizer.on_scan(scans[k])
            assert estimate is not None and boxes_contain(estimate.boxes, truth[k]), (k, params.unknown_is_obstacle)
            assert not estimate.details["restarted"]
            angles, lo, hi = beam_intervals(scans[k], range_error=params.range_error, max_beams=params.max_beams)
            most_unexplained = max(most_unexplained, slam_test_world.unexplained(
                slam, truth[k], angles, 0.5 * (lo + hi), params.map_margin - slam_test_world.EPS))
        assert most_unexplained >= 5  # not vacuous: readings into unknown space in both runs
        assert estimate.details["hull_width_x"] < 1.0 and estimate.details["hull_width_theta"] < math.radians(20)


def test_a_scan_mostly_into_unknown_space_is_retried_with_unknown_cells_as_ends_not_restarted() -> None:
    # A 6 m x 4 m map whose east half was never seen: facing it, every reading ends in unknown space.
    data = np.full((80, 120), -1, dtype=np.int8)
    data[:, :60] = 0
    data[:3, :60] = data[-3:, :60] = data[:, :3] = 100
    slam = GridMap(data, 0.05)
    world = np.zeros((80, 120), dtype=np.int8)
    world[:3, :] = world[-3:, :] = world[:, :3] = world[:, -3:] = 100
    world[30:50, 90:100] = 100
    truth = np.array([2.5, 2.0, 0.0])
    ranges = RayCaster(GridMap(world, 0.05), max_range=10.0).cast(truth, slam_test_world.ANGLES_180)
    scan = Scan(0.0, slam_test_world.ANGLES_180.copy(), ranges.astype(np.float64), 0.05, 10.0)
    for retry, kept in ((24, True), (0, False)):
        localizer = IntervalLocalizer(_slam_params(max_outliers_retry=retry), slam)
        localizer.set_initial_pose(truth, np.diag([0.05, 0.05, 0.05]) ** 2)
        estimate = localizer.on_scan(scan)
        assert estimate.details["outliers_retried"] is kept and estimate.details["restarted"] is not kept
        if kept:
            assert boxes_contain(estimate.boxes, truth) and estimate.details["hull_width_x"] < 1.0


def test_a_box_with_no_consistent_pose_contracts_to_empty(office, grid) -> None:
    rng = np.random.default_rng(6)
    truth = np.array([3.0, 4.5, 0.3])
    scan = bounded_scan(office, truth, rng)
    angles, lo, hi = beam_intervals(scan, range_error=EPS, max_beams=36)
    localizer = IntervalLocalizer(IALSettings(), office)
    # a 20 cm x 20 cm x 6 degree box in the east room, where nothing looks like the west room's view
    wrong = np.array([[13.0, 13.2, 4.0, 4.2, 0.27, 0.37]])
    assert len(localizer.iterate(wrong, angles, lo, hi).boxes) == 0
    # the same box around the truth keeps it
    right = np.array([[2.9, 3.1, 4.4, 4.6, 0.25, 0.35]])
    assert boxes_contain(localizer.iterate(right, angles, lo, hi).boxes, truth)


def test_prediction_contains_the_true_pose_for_bounded_odometry_steps_short_and_long() -> None:
    rng = np.random.default_rng(7)
    localizer = IntervalLocalizer(IALSettings(**ODOM_BOUNDS))
    for _ in range(3000):
        start = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi)])
        kind = rng.integers(0, 3)
        trans = [0.0, rng.uniform(0.0, 0.012), rng.uniform(0.0, 0.4)][kind]  # none, under the 1 cm threshold, long
        rot1, rot2 = rng.uniform(-math.pi, math.pi), rng.uniform(-0.5, 0.5)
        true_next = compose(start, np.array([trans * math.cos(rot1), trans * math.sin(rot1), wrap_angle(rot1 + rot2)]))
        odometry = OdometrySimulator(BOUNDED_ODOMETRY, rng)
        odometry.pose = rng.uniform(-20, 20, 3)
        previous = odometry.pose.copy()
        current = odometry.step(start, true_next)
        box = np.array([[start[0], start[0], start[1], start[1], start[2], start[2]]])
        predicted = localizer.predict(box, [(previous, current)])
        assert boxes_contain(predicted, true_next), (start, true_next, predicted)


class _ClippedNormal:
    """A random stream whose standard normal draws stop at +-4: Thrun's Gaussian odometry within 4 sigma."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def normal(self, loc: float, scale: float, size: int) -> np.ndarray:
        return np.clip(self.rng.normal(loc, scale, size), -4.0, 4.0)


def test_prediction_contains_the_true_pose_for_thrun_odometry_within_4_sigma() -> None:
    # The real-log bags' odometry (tools/carmen_to_bag.py): Thrun's model with variance scales alpha1..alpha4;
    # std = sqrt(a1 rot^2 + a2 trans^2) <= sqrt(a1) |rot| + sqrt(a2) trans, so 4 sqrt(alpha) bound 4 sigma.
    # Short steps with large rotations are the hard ones: the realised translation may come out negative.
    alphas = (1.2e-3, 1e-4, 4e-4, 1e-4)
    model = OdometryMotionModel(*alphas)
    k = 4.0
    settings = IALSettings(odom_relative_rotation=k * math.sqrt(alphas[0]),
                           odom_rotation_per_translation=k * math.sqrt(alphas[1]),
                           odom_relative_translation=k * math.sqrt(alphas[2]),
                           odom_translation_per_rotation=k * math.sqrt(alphas[3]),
                           odom_absolute_translation=0.0, odom_absolute_rotation=0.0)
    localizer = IntervalLocalizer(settings)
    rng = np.random.default_rng(17)
    noise = _ClippedNormal(rng)
    for _ in range(3000):
        start = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi)])
        trans = [0.0, rng.uniform(0.0, 0.03), rng.uniform(0.0, 1.2)][rng.integers(0, 3)]
        turn = rng.random() < 0.5  # else nearly straight: the noise then comes from the cross terms
        rot1 = rng.uniform(-math.pi, math.pi) if turn else rng.uniform(-0.02, 0.02)
        rot2 = rng.uniform(-1.0, 1.0) if turn else rng.uniform(-0.02, 0.02)
        true_next = compose(start, np.array([trans * math.cos(rot1), trans * math.sin(rot1), wrap_angle(rot1 + rot2)]))
        previous = rng.uniform(-20, 20, 3)
        current = model.sample(previous[None, :], start, true_next, noise)[0]
        box = np.array([[start[0], start[0], start[1], start[1], start[2], start[2]]])
        assert boxes_contain(localizer.predict(box, [(previous, current)]), true_next), (start, true_next)


def test_odometry_bounds_that_cannot_be_inverted_are_refused() -> None:
    with pytest.raises(SettingsError, match="cannot be inverted"):
        IALSettings(odom_relative_translation=0.5, odom_translation_per_rotation=2.0,
                    odom_rotation_per_translation=0.5)


def test_compose_boxes_is_outward_for_a_laser_mount() -> None:
    rng = np.random.default_rng(8)
    mount = LaserMount(0.3, -0.1, 0.4)
    for _ in range(500):
        lo = rng.uniform(-5, 5, 3)
        box = np.array([lo[0], lo[0] + rng.uniform(0, 1), lo[1], lo[1] + rng.uniform(0, 1), lo[2], lo[2] + rng.uniform(0, 2)])
        points = box[0::2] + (box[1::2] - box[0::2]) * rng.random((20, 3))
        moved = compose_boxes(box[None, :], mount.pose)
        for point in compose(points, mount.pose):
            assert boxes_contain(moved, point)


# -- Algorithm 1, end to end ----------------------------------------------------------------------
def test_updates_wait_for_motion_unless_a_nomotion_update_is_requested(office) -> None:
    rng = np.random.default_rng(12)
    localizer = IntervalLocalizer(IALSettings(max_beams=36, update_min_d=0.5, update_min_a=0.5), office)
    assert isinstance(localizer, Localizer) and isinstance(localizer, GlobalFixer)
    truth = np.array([3.0, 4.5, 0.3])
    localizer.on_odometry(0.0, np.zeros(3))
    first = localizer.on_scan(bounded_scan(office, truth, rng, stamp=0.0))
    assert first is not None and boxes_contain(first.boxes, truth)
    # no motion since: no update
    localizer.on_odometry(0.1, np.zeros(3))
    assert localizer.on_scan(bounded_scan(office, truth, rng, stamp=0.1)) is None
    localizer.request_nomotion_update()
    forced = localizer.on_scan(bounded_scan(office, truth, rng, stamp=0.2))
    assert forced is not None and boxes_contain(forced.boxes, truth)
    assert localizer.on_scan(bounded_scan(office, truth, rng, stamp=0.3)) is None  # the request was used up


def test_a_global_fix_from_one_scan_contains_the_truth_and_ranks_it_first(office) -> None:
    rng = np.random.default_rng(9)
    localizer = IntervalLocalizer(IALSettings(max_beams=36, max_outliers=5), office)
    for truth in ([3.0, 4.5, 0.3], [12.5, 3.0, -2.0], [9.0, 8.0, 1.5]):
        scan = bounded_scan(office, truth, rng, outliers=5)
        estimate = localizer.global_fix(scan)
        assert boxes_contain(estimate.boxes, truth)
        assert np.hypot(*(estimate.pose[:2] - np.asarray(truth[:2]))) < 0.2  # best candidate first
        assert abs(wrap_angle(estimate.pose[2] - truth[2])) < math.radians(5.0)
        assert estimate.details["box_count"] == len(estimate.candidates)
    assert localizer.boxes is None  # global_fix leaves the tracking state alone


def test_tracking_keeps_the_truth_and_the_hull_is_small_once_the_robot_moved_2_m(office) -> None:
    truth, odometry, scans = bounded_drive(office, 120, seed=10)
    localizer = IntervalLocalizer(IALSettings(max_beams=36, max_outliers=3, **ODOM_BOUNDS), office)
    travelled = 0.0
    for k in range(len(scans)):
        localizer.on_odometry(0.1 * k, odometry[k])
        estimate = localizer.on_scan(scans[k])
        assert boxes_contain(estimate.boxes, truth[k]), k
        assert not estimate.details["restarted"], k
        if k:
            travelled += float(np.hypot(*(truth[k, :2] - truth[k - 1, :2])))
        if travelled >= 2.0:
            d = estimate.details
            assert d["hull_width_x"] <= 0.2 and d["hull_width_y"] <= 0.2, (k, d["hull_width_x"], d["hull_width_y"])
            assert d["hull_width_theta"] <= math.radians(5.0), (k, d["hull_width_theta"])
            assert estimate.status is LocalizerStatus.LOCALIZED
            assert np.hypot(*(estimate.pose[:2] - truth[k, :2])) < 0.1
    assert travelled > 5.0


@pytest.mark.parametrize("check", [True, False])
def test_a_scan_the_map_explains_less_than_the_bounds_assume_is_not_localized(office, check: bool) -> None:
    # The bounds assume at most max_outliers of max_beams readings away from the map (3 of 36 here). From
    # step 100 on, a crowd the map lacks answers a sixth of the 360 readings, none of the 36 IAL uses: the
    # boxes stay tight around the truth, but the scan itself says the assumption does not hold.
    truth, odometry, scans = bounded_drive(office, 120, seed=10)
    localizer = IntervalLocalizer(IALSettings(max_beams=36, max_outliers=3, localized_needs_explained_scan=check,
                                              **ODOM_BOUNDS), office)
    rng = np.random.default_rng(0)
    statuses = []
    for k in range(len(scans)):
        scan = scans[k]
        if k >= 100:
            angles, ranges = scan.hits()
            used = np.unique(np.round(np.linspace(0, ranges.size - 1, 36)).astype(np.int64))
            crowd = rng.choice(np.setdiff1d(np.arange(ranges.size), used), size=60, replace=False)
            readings = scan.ranges.copy()
            hit_index = np.flatnonzero(np.isfinite(readings) & (readings >= scan.range_min)
                                       & (readings < scan.range_max))
            readings[hit_index[crowd]] = np.minimum(0.5 * readings[hit_index[crowd]], 1.5)
            scan = Scan(scan.stamp, scan.angles, readings, scan.range_min, scan.range_max)
        localizer.on_odometry(0.1 * k, odometry[k])
        estimate = localizer.on_scan(scan)
        assert boxes_contain(estimate.boxes, truth[k]), k
        statuses.append(estimate.status)
    assert all(status is LocalizerStatus.LOCALIZED for status in statuses[80:100])
    crowded = statuses[100:]
    if check:
        assert all(status is LocalizerStatus.AMBIGUOUS for status in crowded)
    else:
        assert all(status is LocalizerStatus.LOCALIZED for status in crowded)


def test_an_empty_list_restarts_global_localization(office) -> None:
    # a kidnapping: the truth jumps, odometry does not; the list empties and IAL restarts from the whole map
    truth, odometry, scans = bounded_drive(office, 60, seed=11, kidnap_step=40)
    localizer = IntervalLocalizer(IALSettings(max_beams=36, max_outliers=3, settle_updates=5, **ODOM_BOUNDS), office)
    restarts, statuses = [], []
    for k in range(len(scans)):
        localizer.on_odometry(0.1 * k, odometry[k])
        estimate = localizer.on_scan(scans[k])
        statuses.append(estimate.status)
        if estimate.details["restarted"]:
            restarts.append(k)
            assert estimate.status is LocalizerStatus.LOST
        assert boxes_contain(estimate.boxes, truth[k]), k
    assert restarts == [40]
    # The emptied list proved the bounds broken: the new set, small at once, is LOCALIZED only from its 5th update.
    assert statuses[39] is LocalizerStatus.LOCALIZED and LocalizerStatus.LOCALIZED not in statuses[40:45]
    assert set(statuses[45:]) == {LocalizerStatus.LOCALIZED}
    # a wrong initial pose empties the list on the first scan, and the same scan relocalizes
    localizer.set_initial_pose(truth[-1] + np.array([4.0, 0.0, 0.0]), np.diag([0.01, 0.01, 0.001]))
    estimate = localizer.on_scan(scans[-1])
    assert estimate.details["restarted"] and estimate.status is LocalizerStatus.LOST
    assert boxes_contain(estimate.boxes, truth[-1])


def test_the_same_input_gives_the_same_boxes(office) -> None:
    truth, odometry, scans = bounded_drive(office, 25, seed=12)
    outputs = []
    for _ in range(2):
        localizer = IntervalLocalizer(IALSettings(**ODOM_BOUNDS), office)
        boxes = []
        for k in range(len(scans)):
            localizer.on_odometry(0.1 * k, odometry[k])
            boxes.append(localizer.on_scan(scans[k]).boxes)
        outputs.append(boxes)
    for first, second in zip(*outputs, strict=True):
        assert np.array_equal(first, second)


def test_too_few_valid_beams_leave_the_boxes_uncontracted_with_a_warning(office) -> None:
    settings = IALSettings(max_outliers=5)
    localizer = IntervalLocalizer(settings, office)
    localizer.set_initial_pose(np.array([3.0, 4.5, 0.3]), np.diag([0.04, 0.04, 0.01]))
    before = localizer.boxes.copy()
    ranges = np.full(360, np.nan)
    ranges[:5] = 2.0  # five valid readings: fewer than max_outliers + 1
    ranges[5:20] = [-1.0, np.inf, 0.01, 50.0, -np.inf] * 3
    estimate = localizer.on_scan(Scan(1.0, ANGLES_360.copy(), ranges, 0.1, RANGE_MAX))
    assert "warning" in estimate.details and "5 valid readings" in estimate.details["warning"]
    assert estimate.details["valid_beams"] == 5
    assert np.array_equal(estimate.boxes.reshape(-1, 6), before)
    assert estimate.status is not LocalizerStatus.LOST
    # globally, the whole map stays
    fresh = IntervalLocalizer(settings, office)
    estimate = fresh.global_fix(Scan(1.0, ANGLES_360.copy(), ranges, 0.1, RANGE_MAX))
    assert "warning" in estimate.details and estimate.details["box_count"] == 1


def test_readings_outside_the_valid_interval_are_dropped_before_they_become_intervals() -> None:
    angles = np.linspace(-1.0, 1.0, 8)
    ranges = np.array([1.0, np.nan, np.inf, -np.inf, -2.0, 0.05, 12.0, 3.0])
    scan = Scan(0.0, angles, ranges, 0.1, 10.0)
    kept_angles, lo, hi = beam_intervals(scan, range_error=0.05, max_beams=100)
    assert kept_angles.tolist() == [angles[0], angles[7]]
    assert lo == pytest.approx([0.95, 2.95]) and hi == pytest.approx([1.05, 3.05])
    assert np.all(hi - lo > 0.1)  # eps on each side plus the float32 rounding of the reading
    evenly = beam_intervals(Scan(0.0, np.linspace(-1, 1, 100), np.full(100, 2.0), 0.1, 10.0), range_error=0.05,
                            max_beams=10)
    assert evenly[0].size == 10 and evenly[0][0] == -1.0 and evenly[0][-1] == 1.0


def test_the_outputs_describe_the_hull_and_rank_the_boxes(office) -> None:
    rng = np.random.default_rng(13)
    truth = np.array([12.5, 3.0, -2.0])
    localizer = IntervalLocalizer(IALSettings(), office)
    estimate = localizer.on_scan(bounded_scan(office, truth, rng))
    boxes = estimate.boxes.reshape(-1, 6)
    hull = boxes_hull(boxes)
    assert estimate.pose[:2] == pytest.approx(0.5 * (hull[0:4:2] + hull[1:4:2]))
    assert np.diag(estimate.covariance) == pytest.approx((hull[1::2] - hull[0::2]) ** 2 / 12.0)
    assert estimate.details["hull_width_x"] == pytest.approx(hull[1] - hull[0])
    centres = 0.5 * (boxes[:, 0::2] + boxes[:, 1::2])
    assert estimate.candidates[:, :2] == pytest.approx(centres[:, :2])
    weights = estimate.candidate_weights
    assert np.all(np.diff(weights) <= 0)  # most consistent beams first
    small = hull[1] - hull[0] <= 0.5 and hull[3] - hull[2] <= 0.5 and hull[5] - hull[4] <= math.radians(20.0)
    assert estimate.status is (LocalizerStatus.LOCALIZED if small else LocalizerStatus.AMBIGUOUS)


def test_set_initial_pose_gives_a_3_sigma_box_and_reinitialize_the_whole_map(office) -> None:
    localizer = IntervalLocalizer(IALSettings(), office)
    localizer.set_initial_pose(np.array([3.0, 4.0, 3.1]), np.diag([0.1**2, 0.2**2, 0.05**2]))
    assert localizer.boxes[0] == pytest.approx([2.7, 3.3, 3.4, 4.6, 3.1 - 0.15, 3.1 + 0.15])
    localizer.set_initial_pose(np.array([3.0, 4.0, 0.0]), np.zeros((3, 3)))  # floors keep a usable box
    assert localizer.boxes[0, 1] - localizer.boxes[0, 0] == pytest.approx(0.1)
    localizer.reinitialize()
    assert localizer.boxes is None


def test_settings_refuse_bad_values_by_name() -> None:
    for name, value in (("range_error", -0.1), ("max_outliers", -1), ("min_box_width_xy", 0.0),
                        ("map_margin", float("nan")), ("max_beams", 0), ("merge_width_theta", 4.0),
                        ("max_outliers", 2.5)):
        with pytest.raises(ValueError, match=name):
            IALSettings(**{name: value})
    with pytest.raises(ValueError, match="max_outliers"):
        IALSettings(max_outliers=36, max_beams=36)


def test_the_outlier_case_of_section_5_3_misleads_mcl_while_the_boxes_keep_the_truth() -> None:
    # Figures 13 and 14: 8 outliers make the half-turn twin B explain the scans better than the truth A.
    from robot_localization_suite.core.mcl.localizer import MclSettings, MonteCarloLocalizer
    from robot_localization_suite.tools.ial_outlier_case import outlier_case

    case = outlier_case(12)
    assert np.all(case.outliers.sum(axis=1) == 8)
    mcl = MonteCarloLocalizer(MclSettings(max_particles=20000, random_seed=1), case.grid_map)
    ial = IntervalLocalizer(IALSettings(max_beams=36, max_outliers=8), case.grid_map)
    for k, scan in enumerate(case.scans):
        odometry = np.array([0.0, 0.0, case.true_poses[k, 2] - case.true_poses[0, 2]])
        mcl.on_odometry(scan.stamp, odometry)
        ial.on_odometry(scan.stamp, odometry)
        mcl.request_nomotion_update()
        particle_estimate = mcl.on_scan(scan)
        boxes = ial.on_scan(scan).boxes
        assert boxes_contain(boxes, case.true_poses[k]), k
    # MCL settled on the twin, more than 2 m from the truth; IAL also keeps the twin (indistinguishable)
    assert np.hypot(*(particle_estimate.pose[:2] - case.twin_poses[-1, :2])) < 0.3
    assert np.hypot(*(particle_estimate.pose[:2] - case.true_poses[-1, :2])) > 2.0
    assert boxes_contain(boxes, case.twin_poses[-1])
