"""SE(2) algebra and the one angle wrap (core/se2.py): group properties and known values."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_localization_suite.core.se2 import (
    angle_difference,
    compose,
    inverse,
    quaternion_to_yaw,
    relative,
    transform_points,
    wrap_angle,
    yaw_to_quaternion,
)

coordinate = st.floats(-100.0, 100.0, allow_nan=False)
heading = st.floats(-10.0, 10.0, allow_nan=False)
poses = st.tuples(coordinate, coordinate, heading).map(lambda p: np.array(p, dtype=np.float64))


def assert_same_pose(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> None:
    np.testing.assert_allclose(a[..., :2], b[..., :2], atol=tol)
    assert np.all(np.abs(angle_difference(a[..., 2], b[..., 2])) <= tol)


def test_wrap_angle_known_values() -> None:
    # The wrap is to [-pi, pi): pi itself maps to -pi, 3 pi/2 to -pi/2, -5 pi/2 to -pi/2.
    assert wrap_angle(np.pi) == pytest.approx(-np.pi)
    assert wrap_angle(-np.pi) == pytest.approx(-np.pi)
    assert wrap_angle(1.5 * np.pi) == pytest.approx(-0.5 * np.pi)
    assert wrap_angle(-2.5 * np.pi) == pytest.approx(-0.5 * np.pi)
    assert wrap_angle(0.25) == pytest.approx(0.25)
    assert isinstance(wrap_angle(7.0), float)
    wrapped = wrap_angle(np.array([0.0, 2 * np.pi, 4 * np.pi + 0.1]))
    np.testing.assert_allclose(wrapped, [0.0, 0.0, 0.1], atol=1e-12)


@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_wrap_angle_range_and_equivalence(angle: float) -> None:
    wrapped = wrap_angle(angle)
    assert -np.pi <= wrapped < np.pi
    # Same direction: sin and cos agree.
    assert np.sin(wrapped) == pytest.approx(np.sin(angle), abs=1e-8)
    assert np.cos(wrapped) == pytest.approx(np.cos(angle), abs=1e-8)


def test_angle_difference_takes_the_short_way() -> None:
    # From 170 degrees to -170 degrees is +20 degrees, not -340.
    assert angle_difference(np.radians(-170), np.radians(170)) == pytest.approx(np.radians(20))
    assert angle_difference(np.radians(170), np.radians(-170)) == pytest.approx(np.radians(-20))


def test_compose_known_value() -> None:
    # A robot at (1, 2) facing +y moves 1 m forward and 0.5 m left: it ends at (0.5, 3) facing -x.
    a = np.array([1.0, 2.0, np.pi / 2])
    b = np.array([1.0, 0.5, np.pi / 2])
    assert_same_pose(compose(a, b), np.array([0.5, 3.0, np.pi]))


@settings(max_examples=200)
@given(poses)
def test_inverse_undoes_compose(a: np.ndarray) -> None:
    identity = np.zeros(3)
    assert_same_pose(compose(a, inverse(a)), identity, 1e-7)
    assert_same_pose(compose(inverse(a), a), identity, 1e-7)
    assert_same_pose(inverse(inverse(a)), a, 1e-7)


@settings(max_examples=200)
@given(poses, poses, poses)
def test_compose_is_associative(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
    assert_same_pose(compose(compose(a, b), c), compose(a, compose(b, c)), 1e-6)


@settings(max_examples=200)
@given(poses, poses)
def test_relative_recovers_the_composed_pose(a: np.ndarray, b: np.ndarray) -> None:
    assert_same_pose(relative(a, compose(a, b)), b, 1e-6)


@given(poses, st.lists(st.tuples(coordinate, coordinate), min_size=1, max_size=5))
def test_transform_points_agrees_with_compose(pose: np.ndarray, points: list[tuple[float, float]]) -> None:
    pts = np.array(points)
    as_poses = np.column_stack([pts, np.zeros(len(pts))])
    np.testing.assert_allclose(transform_points(pose, pts), compose(pose, as_poses)[:, :2], atol=1e-9)


def test_compose_broadcasts_over_a_cloud() -> None:
    cloud = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, np.pi / 2], [-2.0, 0.5, -np.pi / 2]])
    step = np.array([1.0, 0.0, 0.0])
    moved = compose(cloud, step)
    assert moved.shape == (3, 3)
    np.testing.assert_allclose(moved[:, :2], [[1.0, 0.0], [1.0, 2.0], [-2.0, -0.5]], atol=1e-12)


@given(heading)
def test_quaternion_round_trip(yaw: float) -> None:
    x, y, z, w = yaw_to_quaternion(yaw)
    assert x == 0.0 and y == 0.0
    assert z * z + w * w == pytest.approx(1.0)
    assert angle_difference(quaternion_to_yaw(x, y, z, w), yaw) == pytest.approx(0.0, abs=1e-9)
