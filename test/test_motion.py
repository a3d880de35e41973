"""The odometry motion model (core/motion.py): sample statistics against its parameters, exact motion, bounds."""

from __future__ import annotations

import numpy as np
import pytest

from robot_localization_suite.core.motion import (
    OdometryMotionModel,
    VelocityMotionModel,
    apply_delta,
    arc_of_step,
    odometry_delta,
)
from robot_localization_suite.core.se2 import angle_difference, compose, relative, wrap_angle

SAMPLES = 100_000


def decompose_from_origin(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rot1, trans, rot2 of each sampled pose reached from the origin pose (0, 0, 0)."""
    trans = np.hypot(samples[:, 0], samples[:, 1])
    rot1 = np.arctan2(samples[:, 1], samples[:, 0])
    rot2 = wrap_angle(samples[:, 2] - rot1)
    return rot1, trans, rot2


def test_odometry_delta_known_value() -> None:
    # From (1, 1, 0) to (2, 2, pi/2): turn 45 deg, drive sqrt(2) m, turn 45 deg.
    delta = odometry_delta([1.0, 1.0, 0.0], [2.0, 2.0, np.pi / 2])
    assert delta.rot1 == pytest.approx(np.pi / 4)
    assert delta.trans == pytest.approx(np.sqrt(2))
    assert delta.rot2 == pytest.approx(np.pi / 4)
    assert delta.rotation == pytest.approx(np.pi / 2)
    # A turn on the spot has no meaningful heading of travel: all of it goes into rot2.
    spin = odometry_delta([0.0, 0.0, 0.0], [0.001, 0.0, 1.0])
    assert spin.rot1 == 0.0 and spin.rot2 == pytest.approx(1.0)


def test_differential_sample_statistics_match_the_model() -> None:
    alphas = {"alpha1": 0.05, "alpha2": 0.01, "alpha3": 0.04, "alpha4": 0.02}
    model = OdometryMotionModel(**alphas)
    previous, current = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.5, 0.6])
    delta = odometry_delta(previous, current)
    samples = model.sample(np.zeros((SAMPLES, 3)), previous, current, np.random.default_rng(11))
    rot1, trans, rot2 = decompose_from_origin(samples)

    # nav2_amcl's differential model: alpha scales a variance term, rotation noise uses the smaller
    # of the forward and backward rotation (here the forward one, both turns are small).
    a1, a2, a3, a4 = alphas.values()
    std_rot1 = np.sqrt(a1 * delta.rot1**2 + a2 * delta.trans**2)
    std_trans = np.sqrt(a3 * delta.trans**2 + a4 * (delta.rot1**2 + delta.rot2**2))
    std_rot2 = np.sqrt(a1 * delta.rot2**2 + a2 * delta.trans**2)

    standard_error = 1.0 / np.sqrt(SAMPLES)
    for name, values, mean, std in [
        ("rot1", rot1, delta.rot1, std_rot1),
        ("trans", trans, delta.trans, std_trans),
        ("rot2", rot2, delta.rot2, std_rot2),
    ]:
        assert np.mean(values) == pytest.approx(mean, abs=5 * std * standard_error), name
        assert np.std(values) == pytest.approx(std, rel=0.02), name
    # The three noises are drawn independently.
    correlation = np.corrcoef([rot1, trans, rot2])
    assert np.all(np.abs(correlation[np.triu_indices(3, 1)]) < 0.02)


def test_each_alpha_drives_its_own_term() -> None:
    previous, current = np.zeros(3), np.array([2.0, 0.0, 0.0])  # straight 2 m, no rotation
    rng = np.random.default_rng(5)
    only_a2 = OdometryMotionModel(alpha1=0.0, alpha2=0.01, alpha3=0.0, alpha4=0.0)
    rot1, trans, rot2 = decompose_from_origin(only_a2.sample(np.zeros((SAMPLES, 3)), previous, current, rng))
    # Translation causes rotation noise of std sqrt(a2) * trans = 0.2 rad; translation itself is exact.
    assert np.std(rot1) == pytest.approx(0.2, rel=0.02)
    assert np.std(trans) < 1e-9
    only_a3 = OdometryMotionModel(alpha1=0.0, alpha2=0.0, alpha3=0.01, alpha4=0.0)
    rot1, trans, rot2 = decompose_from_origin(only_a3.sample(np.zeros((SAMPLES, 3)), previous, current, rng))
    assert np.std(trans) == pytest.approx(0.2, rel=0.02)
    assert np.std(rot1) < 1e-9 and np.std(rot2) < 1e-9


def test_driving_backwards_is_not_a_half_turn_of_noise() -> None:
    model = OdometryMotionModel(alpha1=0.2, alpha2=0.0, alpha3=0.0, alpha4=0.0)
    previous, current = np.zeros(3), np.array([-1.0, 0.0, 0.0])  # 1 m in reverse: rot1 = pi, rot2 = -pi
    samples = model.sample(np.zeros((10_000, 3)), previous, current, np.random.default_rng(2))
    # Rotation noise is computed from min(|rot|, |rot - pi|) = 0: the robot ends exactly where odometry says.
    np.testing.assert_allclose(samples, np.tile([-1.0, 0.0, 0.0], (10_000, 1)), atol=1e-9)


def test_zero_alphas_give_the_exact_motion() -> None:
    model = OdometryMotionModel(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0, alpha5=0.0)
    previous, current = np.array([3.0, -1.0, 2.5]), np.array([3.4, -0.2, -2.9])
    particles = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, np.pi / 2], [-4.0, 2.0, -3.0]])
    moved = model.sample(particles, previous, current, np.random.default_rng(0))
    # Each particle moves by the odometry step expressed in its own frame.
    expected = compose(particles, relative(previous, current))
    np.testing.assert_allclose(moved[:, :2], expected[:, :2], atol=1e-9)
    assert np.all(np.abs(angle_difference(moved[:, 2], expected[:, 2])) < 1e-9)
    delta = odometry_delta(previous, current)
    np.testing.assert_allclose(apply_delta(particles, delta.rot1, delta.trans, delta.rot2), moved, atol=1e-9)


def test_omnidirectional_zero_alphas_and_strafe() -> None:
    exact = OdometryMotionModel(alpha1=0, alpha2=0, alpha3=0, alpha4=0, alpha5=0, omnidirectional=True)
    previous, current = np.array([1.0, 1.0, 0.3]), np.array([1.2, 1.9, 0.1])
    particles = np.array([[0.0, 0.0, 0.0], [2.0, -3.0, 2.0]])
    moved = exact.sample(particles, previous, current, np.random.default_rng(0))
    expected = compose(particles, relative(previous, current))
    np.testing.assert_allclose(moved, expected, atol=1e-9)


def test_omnidirectional_sample_statistics_match_the_model() -> None:
    alphas = {"alpha1": 0.03, "alpha2": 0.01, "alpha3": 0.05, "alpha4": 0.02, "alpha5": 0.04}
    model = OdometryMotionModel(**alphas, omnidirectional=True)
    previous, current = np.zeros(3), np.array([0.6, 0.8, 0.5])  # 1 m along bearing 0.927 rad, turn 0.5 rad
    samples = model.sample(np.zeros((SAMPLES, 3)), previous, current, np.random.default_rng(4))
    bearing = np.arctan2(0.8, 0.6)
    # Split each displacement into travel along the bearing and strafe across it.
    along = samples[:, 0] * np.cos(bearing) + samples[:, 1] * np.sin(bearing)
    across = -samples[:, 0] * np.sin(bearing) + samples[:, 1] * np.cos(bearing)
    rotation = samples[:, 2]
    trans, rot = 1.0, 0.5
    a1, a2, a3, a4, a5 = alphas.values()
    # nav2 OmniMotionModel: trans ~ a3 t^2 + a1 r^2, rot ~ a4 r^2 + a2 t^2, strafe ~ a1 r^2 + a5 t^2 (variances).
    for name, values, mean, std in [
        ("along", along, trans, np.sqrt(a3 * trans**2 + a1 * rot**2)),
        ("across", across, 0.0, np.sqrt(a1 * rot**2 + a5 * trans**2)),
        ("rotation", rotation, rot, np.sqrt(a4 * rot**2 + a2 * trans**2)),
    ]:
        assert np.mean(values) == pytest.approx(mean, abs=5 * std / np.sqrt(SAMPLES)), name
        assert np.std(values) == pytest.approx(std, rel=0.02), name


def test_bounds_contain_the_step_with_the_stated_margins() -> None:
    previous, current = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.2])
    bounds = OdometryMotionModel.bounds(
        previous,
        current,
        relative_translation=0.1,
        absolute_translation=0.01,
        relative_rotation=0.05,
        absolute_rotation=0.02,
    )
    # trans = 1 m: +- (0.1 * 1 + 0.01); rot1 = 0: +- 0.02; rot2 = 0.2: +- (0.05 * 0.2 + 0.02).
    assert bounds.trans == pytest.approx((0.89, 1.11))
    assert bounds.rot1 == pytest.approx((-0.02, 0.02))
    assert bounds.rot2 == pytest.approx((0.17, 0.23))


@pytest.mark.parametrize("name", ["alpha1", "alpha2", "alpha3", "alpha4", "alpha5"])
@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf")])
def test_bad_alpha_is_refused_with_its_value(name: str, value: float) -> None:
    with pytest.raises(ValueError, match=rf"{name}.*{value!r}"):
        OdometryMotionModel(**{name: value})


def _arc_end(start: np.ndarray, length: float, turn: float) -> np.ndarray:
    """Where driving ``length`` along an arc turning by ``turn`` from ``start`` ends (the kinematics)."""
    if abs(turn) < 1e-12:
        return start + np.array([length * np.cos(start[2]), length * np.sin(start[2]), 0.0])
    radius = length / turn
    return np.array([start[0] + radius * (np.sin(start[2] + turn) - np.sin(start[2])),
                     start[1] - radius * (np.cos(start[2] + turn) - np.cos(start[2])),
                     wrap_angle(start[2] + turn)])


@pytest.mark.parametrize(("length", "turn"), [(1.0, 0.0), (1.0, 0.6), (-0.8, 0.4), (0.5, -2.5), (0.0, 0.7)])
def test_velocity_model_reads_an_arc_back_and_moves_every_pose_along_it_exactly_without_noise(
        length: float, turn: float) -> None:
    odom_start = np.array([2.0, -1.0, 0.3])
    odom_end = _arc_end(odom_start, length, turn)
    assert np.allclose(arc_of_step(odom_start, odom_end), (length, turn), atol=1e-9)
    poses = np.array([[0.0, 0.0, 0.0], [5.0, 3.0, -2.0]])
    moved = VelocityMotionModel(0.0, 0.0, 0.0, 0.0).sample(poses, odom_start, odom_end, np.random.default_rng(0))
    for pose, out in zip(poses, moved, strict=True):
        np.testing.assert_allclose(out, compose(pose, relative(odom_start, odom_end)), atol=1e-9)


def test_velocity_model_noise_is_on_the_arc_length_and_turn_with_the_stated_variances() -> None:
    """Straight 2 m: along-track spread sqrt(alpha3) * 2 m, heading spread sqrt(alpha2) * 2 m, no final
    rotation of its own (the heading is the turn: one sample per pose of each)."""
    model = VelocityMotionModel(alpha1=0.0, alpha2=0.01, alpha3=0.04, alpha4=0.0)
    out = model.sample(np.zeros((SAMPLES, 3)), np.zeros(3), np.array([2.0, 0.0, 0.0]), np.random.default_rng(1))
    heading = out[:, 2]
    assert np.std(heading) == pytest.approx(np.sqrt(0.01) * 2.0, rel=0.02)
    # the end point lies on the arc its own heading change describes
    lengths = np.array([arc_of_step(np.zeros(3), pose)[0] for pose in out[:2000]])
    assert np.std(lengths) == pytest.approx(np.sqrt(0.04) * 2.0, rel=0.1)
    np.testing.assert_allclose(out[:2000, 1], [_arc_end(np.zeros(3), s, t)[1] for s, t in
                                               zip(lengths, heading[:2000], strict=True)], atol=1e-9)
