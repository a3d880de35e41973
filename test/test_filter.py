"""The shared filter toolkit (core/filter/): odometry gate, particle utilities, scan-to-map refinement."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_localization_suite.core.filter.odometry_gate import MotionMeasure, OdometryGate
from robot_localization_suite.core.filter.particles import (
    densest_neighbourhood_mean,
    low_variance_resample,
    weighted_pose_statistics,
)
from robot_localization_suite.core.filter.refinement import DistanceField, refine_poses
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.raycast import RayCaster

RESOLUTION = 0.05


# -- odometry gate ------------------------------------------------------------------------------
def test_the_gate_opens_exactly_at_either_threshold() -> None:
    gate = OdometryGate(0.25, 0.5)
    assert gate.due()  # a fresh gate is forced
    gate.add(0.0, [0.0, 0.0, 0.0])
    gate.mark_updated(gate.latest)
    assert not gate.forced and not gate.due()
    assert not gate.due([0.2499, 0.0, 0.0])
    assert gate.due([0.25, 0.0, 0.0])  # translation == update_min_d: due (nav2 uses >=)
    assert gate.due([0.15, 0.2, 0.0])  # hypot(0.15, 0.2) = 0.25
    assert not gate.due([0.0, 0.0, 0.4999])
    assert gate.due([0.0, 0.0, 0.5]) and gate.due([0.0, 0.0, -0.5])
    gate.request_update()
    assert gate.due([0.0, 0.0, 0.0])
    gate.mark_updated([1.0, 0.0, 3.0])
    assert not gate.due([1.0, 0.0, -3.0])  # 0.28 rad across +-pi, not 6 rad
    assert gate.due([1.0, 0.0, -2.5])  # 0.78 rad across +-pi


def test_an_unknown_reference_or_pose_never_opens_the_gate_only_forcing_does() -> None:
    gate = OdometryGate(0.0, 0.0)
    gate.reset(force=False)
    assert not gate.due() and not gate.due([5.0, 5.0, 1.0])  # no reference
    gate.add(1.0, [5.0, 5.0, 1.0])
    gate.reference = gate.latest
    assert gate.due()  # zero thresholds: due as soon as the motion is known
    gate.reset()
    assert gate.forced and gate.reference is None and gate.due()


def test_the_pose_at_a_stamp_is_interpolated_across_plus_minus_pi_and_clamped_at_the_ends() -> None:
    gate = OdometryGate()
    assert gate.at(1.0) is None and gate.latest is None
    gate.add(1.0, [0.0, 0.0, 3.0])
    gate.add(2.0, [1.0, 2.0, -3.0])  # turned 0.28 rad through pi
    np.testing.assert_allclose(gate.at(1.5)[:2], [0.5, 1.0])
    assert abs(abs(gate.at(1.5)[2]) - math.pi) < 1e-12  # half way is pi, not 0
    np.testing.assert_allclose(gate.at(1.25), [0.25, 0.5, 3.0 + 0.25 * (2.0 * math.pi - 6.0)])
    np.testing.assert_array_equal(gate.at(0.0), [0.0, 0.0, 3.0])  # before the first: the first
    np.testing.assert_array_equal(gate.at(9.0), [1.0, 2.0, -3.0])  # after the last: the last


def test_older_and_non_finite_odometry_is_rejected_without_raising() -> None:
    gate = OdometryGate()
    assert gate.add(5.0, np.array([1.0, 0.0, 0.0]))
    assert not gate.add(4.0, [9.0, 9.0, 0.0])  # older
    assert not gate.add(6.0, [np.nan, 0.0, 0.0])
    assert not gate.add(math.inf, [2.0, 0.0, 0.0])
    assert not gate.add(7.0, [1.0, 2.0])  # not a pose
    assert gate.rejected == 4
    np.testing.assert_array_equal(gate.latest, [1.0, 0.0, 0.0])
    assert gate.add(5.0, [1.5, 0.0, 0.0])  # same stamp: replaces
    np.testing.assert_array_equal(gate.at(5.0), [1.5, 0.0, 0.0])


def test_the_buffer_is_bounded_and_a_caller_s_pose_is_copied() -> None:
    gate = OdometryGate(capacity=3)
    pose = np.zeros(3)
    for k in range(20):
        pose[0] = k
        gate.add(float(k), pose)
    assert gate.latest[0] == 19.0  # copied, not the caller's array
    assert 3 <= len(gate._poses) <= 6
    assert gate.at(0.0)[0] >= 13.0  # the oldest kept


def test_path_length_counts_motion_that_returns_to_the_start() -> None:
    displacement = OdometryGate(0.5, 4.0)
    path = OdometryGate(0.5, 4.0, measure=MotionMeasure.PATH)
    for gate in (displacement, path):
        gate.add(0.0, [0.0, 0.0, 0.0])
        gate.mark_updated(gate.latest)
        gate.add(1.0, [0.3, 0.0, 0.0])
        gate.add(2.0, [0.3, 0.3, 0.0])  # sideways: 0.42 m from the start, 0.6 m travelled
    assert not displacement.due()
    assert path.due()
    translation, rotation = path.motion()
    assert translation == pytest.approx(0.6)
    assert rotation == pytest.approx(math.pi)  # the second step: rot1 = pi/2, rot2 = -pi/2
    path.mark_updated(path.latest)
    assert path.motion() == (0.0, 0.0) and not path.due()


def test_steps_are_returned_once_and_kept_through_trimming() -> None:
    gate = OdometryGate(capacity=2, keep_steps=True, measure=MotionMeasure.PATH)
    assert gate.take_steps() == []
    for k in range(7):
        gate.add(float(k), [float(k), 0.0, 0.0])
    steps = gate.take_steps()
    assert [(a[0], b[0]) for a, b in steps] == [(k, k + 1) for k in range(6)]
    assert gate.take_steps() == []
    gate.add(7.0, [7.0, 0.0, 0.0])
    assert [(a[0], b[0]) for a, b in gate.take_steps()] == [(6.0, 7.0)]


# -- particles ----------------------------------------------------------------------------------
def test_systematic_resampling_keeps_each_share_within_one_draw() -> None:
    rng = np.random.default_rng(4)
    weights = np.array([0.1, 0.0, 0.2, 0.7, 0.0])
    for count in (10, 97, 1000):
        counts = np.bincount(low_variance_resample(weights, count, rng), minlength=5)
        assert np.all(np.abs(counts - weights * count) < 1.0)
    # unnormalised weights are normalised
    counts = np.bincount(low_variance_resample(np.array([1.0, 3.0]), 100, rng), minlength=2)
    assert counts.tolist() == [25, 75]


def test_weighted_circular_mean_and_covariance_across_plus_minus_pi() -> None:
    poses = np.array([[0.0, 0.0, math.pi - 0.1], [2.0, 0.0, -math.pi + 0.1]])
    mean, covariance = weighted_pose_statistics(poses, np.array([3.0, 1.0]))
    assert mean[0] == pytest.approx(0.5)
    # weights 3:1 on +-0.1 rad around pi: atan2(0.5 sin 0.1, cos 0.1) from pi
    expected = math.pi - math.atan2(0.5 * math.sin(0.1), math.cos(0.1))
    assert mean[2] == pytest.approx(expected)
    assert covariance[2, 2] < 0.02  # deviations wrapped: ~0.1 rad, not ~6 rad
    assert covariance[0, 0] == pytest.approx(0.75)  # 3/4 * 0.5^2 + 1/4 * 1.5^2
    mean, covariance = weighted_pose_statistics(poses, np.zeros(2))  # no weight: uniform
    assert mean[0] == pytest.approx(1.0)
    mean, covariance = weighted_pose_statistics(np.zeros((0, 3)), np.zeros(0))
    assert np.all(np.isnan(mean)) and np.all(np.isnan(covariance))


def test_the_densest_neighbourhood_mean_is_one_hypothesis_not_the_average_of_two() -> None:
    rng = np.random.default_rng(5)
    here = np.column_stack([rng.normal(1.0, 0.05, 60), rng.normal(2.0, 0.05, 60), np.where(rng.random(60) < 0.5, 3.1, -3.1)])
    there = np.column_stack([rng.normal(6.0, 0.05, 40), rng.normal(2.0, 0.05, 40), np.zeros(40)])
    poses = np.vstack([here, there])
    mean = densest_neighbourhood_mean(poses, np.ones(100))
    assert abs(mean[0] - 1.0) < 0.05 and abs(abs(mean[2]) - math.pi) < 0.05
    weights = np.r_[np.ones(60), np.full(40, 2.0)]  # the other group now holds more weight
    mean = densest_neighbourhood_mean(poses, weights)
    assert abs(mean[0] - 6.0) < 0.05 and abs(mean[2]) < 0.05


# -- distance field and refinement --------------------------------------------------------------
def _l_room() -> GridMap:
    """A 6 m x 4 m room with a partition and a pillar: a scan pins x, y and theta."""
    data = np.zeros((80, 120), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[:40, 70:72] = 100  # partition at x = 3.5 m, up to y = 2 m
    data[55:60, 25:30] = 100  # pillar at x 1.25-1.5 m, y 2.75-3 m
    return GridMap(data, RESOLUTION, (0.0, 0.0))


def test_the_distance_field_is_sampled_bilinearly_with_its_gradient() -> None:
    room = _l_room()
    field = DistanceField(room)
    # 1 m east of the west wall's last cell centre (x = 0.075 m); the south wall and the pillar are farther
    d, gx, gy = field.lookup(np.array([[1.075, 1.5]]))
    assert d[0] == pytest.approx(1.0, abs=0.03)
    assert gx[0] == pytest.approx(1.0, abs=0.1) and abs(gy[0]) < 0.1  # distance grows eastwards
    d, gx, gy = field.lookup(np.array([[-1.0, 1.0], [0.0, 9.0]]))
    assert np.all(np.isinf(d)) and np.all(gx == 0.0)  # off the map: no distance, no pull


def test_a_map_one_cell_wide_or_high_has_a_distance_field() -> None:
    """numpy has no gradient along an axis of one cell: ir_initializer died on a 1 x 1 map (issue 14)."""
    row = np.zeros((1, 40), dtype=np.int8)
    row[0, 0] = 100
    for data in (row, row.T.copy(), np.full((1, 1), 100, dtype=np.int8)):
        field = DistanceField(GridMap(data, RESOLUTION, (0.0, 0.0)))
        assert field.grad_x.shape == field.grad_y.shape == data.shape
        assert np.all(np.isfinite(field.grad_x)) and np.all(np.isfinite(field.grad_y))
    field = DistanceField(GridMap(row, RESOLUTION, (0.0, 0.0)))
    assert np.all(field.grad_y == 0.0) and field.grad_x[0, 10] == pytest.approx(1.0)  # grows away from the wall
    for data in (row, np.full((1, 1), 100, dtype=np.int8)):  # the compact field looks up the same points
        compact = DistanceField(GridMap(data, RESOLUTION, (0.0, 0.0)), compact=True)
        for a in compact.lookup(np.array([[0.3, 0.02], [5.0, 5.0]])):
            assert not np.any(np.isnan(a))


def test_the_compact_distance_field_gives_the_same_numbers_in_a_sixth_of_the_memory() -> None:
    room = _l_room()
    full, compact = DistanceField(room), DistanceField(room, compact=True)
    assert compact.nbytes * 6 == full.nbytes  # float32 distances only, against float64 distance and gradients
    rng = np.random.default_rng(4)
    points = np.column_stack([rng.uniform(-0.5, 6.5, 5000), rng.uniform(-0.5, 4.5, 5000)])  # borders and off-map too
    for a, b in zip(full.lookup(points), compact.lookup(points), strict=True):
        np.testing.assert_array_equal(a, b)
    poses = np.column_stack([rng.uniform(0.5, 5.5, 30), rng.uniform(0.5, 3.5, 30), rng.uniform(-3, 3, 30)])
    angles, ranges = np.linspace(-2.0, 2.0, 90), rng.uniform(0.5, 4.0, 90)
    for options in ({"truncation": 0.3}, {"sigma": 0.15, "max_turn": 0.2}):
        a = refine_poses(full, poses, angles, ranges, iterations=8, max_shift=0.3, **options)
        b = refine_poses(compact, poses, angles, ranges, iterations=8, max_shift=0.3, **options)
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize(
    "options",
    [
        {"truncation": 0.3},  # hard truncation, weight 1 (PIL's use)
        {"sigma": 0.15, "max_turn": math.radians(10.0)},  # Gaussian weights, bounded turn (IR's use)
    ],
)
def test_refinement_recovers_a_known_small_offset(options: dict[str, float]) -> None:
    room = _l_room()
    truth = np.array([2.0, 1.2, 0.4])
    angles = np.linspace(-math.pi, math.pi, 240, endpoint=False)
    ranges = RayCaster(room, max_range=10.0).cast(truth, angles).astype(np.float64)
    hit = np.isfinite(ranges)
    start = truth + np.array([[0.08, -0.06, 0.05], [-0.05, -0.05, -0.06]])
    field = DistanceField(room)
    refined, scores = refine_poses(field, start, angles[hit], ranges[hit], iterations=15, max_shift=0.3, **options)
    assert np.all(np.hypot(*(refined[:, :2] - truth[:2]).T) < 0.02)
    assert np.all(np.abs(refined[:, 2] - truth[2]) < 0.01)
    _, before = refine_poses(field, start, angles[hit], ranges[hit], iterations=0, max_shift=0.3, **options)
    assert np.all(scores > before) and np.all(scores <= 1.0)
    # The shift stays bounded: a pose 0.3 m off moves at most max_shift from where it started.
    far = truth + np.array([0.3, 0.0, 0.0])
    moved, _ = refine_poses(field, far, angles[hit], ranges[hit], iterations=15, max_shift=0.1, **options)
    assert np.hypot(*(moved[0, :2] - far[:2])) <= 0.1 + 1e-9
    # No beams or no poses: the poses come back unchanged.
    same, zero = refine_poses(field, start, np.zeros(0), np.zeros(0), iterations=5, max_shift=0.3, **options)
    np.testing.assert_array_equal(same, start)
    assert np.all(zero == 0.0)


def test_time_going_back_by_more_than_the_jump_threshold_starts_a_new_timeline() -> None:
    gate = OdometryGate(0.1, 0.1, time_jump_s=3.0)
    assert gate.add(10.0, [0.0, 0.0, 0.0]) and gate.add(11.0, [1.0, 0.0, 0.0])
    gate.mark_updated(gate.latest)
    assert not gate.add(9.0, [0.0, 0.0, 0.0]) and gate.rejected == 1  # 2 s back: refused
    assert gate.add(5.0, [7.0, 7.0, 0.0]) and gate.time_jumps == 1  # 6 s back: restarted
    assert gate.reference is None and gate.forced
    assert np.allclose(gate.latest, [7.0, 7.0, 0.0]) and np.allclose(gate.at(11.0), [7.0, 7.0, 0.0])
