"""The odometry motion model shared by every localizer and the simulator.

Thrun, Burgard & Fox, *Probabilistic Robotics*, table 5.6 (``sample_motion_model_odometry``):
a motion between two odometry poses is decomposed into a first rotation
``rot1``, a translation ``trans`` and a second rotation ``rot2``, each perturbed
by zero-mean noise whose spread grows with the motion (alpha1..alpha4).

As nav2_amcl does (``nav2_amcl/src/motion_model/differential_motion_model.cpp``),
``alpha`` scales a *standard deviation* (``std = sqrt(a1 rot1^2 + a2 trans^2)``),
rotation noise uses the smaller of the forward and backward rotations so that
driving backwards is not penalised, and ``rot1`` is 0 for tiny translations.
The omnidirectional variant (nav2 ``OmniMotionModel``) adds ``alpha5`` for strafe.

``bounds`` gives the guaranteed-set version used by interval methods: every
component of the decomposition lies in ``value +- (relative * |value| + absolute)``.

:class:`VelocityMotionModel` is table 5.3 (``sample_motion_model_velocity``), for
methods whose paper uses it (IR, Aycard & Brouard): the step between two odometry poses
read as one arc at constant (v, w), its length and turn perturbed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .se2 import angle_difference, wrap_angle

__all__ = ["OdometryDelta", "OdometryMotionModel", "VelocityMotionModel", "MotionBounds", "odometry_delta",
           "apply_delta", "arc_of_step", "ODOMETRY_NOISE_KEY", "declare_odometry_noise", "read_odometry_noise"]

# Key of a bag's metadata ``custom_data`` that declares the noise of its /odom (docs/benchmark.md).
ODOMETRY_NOISE_KEY = "robot_localization_suite.odometry_noise"
_ALPHA_NAMES = ("alpha1", "alpha2", "alpha3", "alpha4")

# Below this translation [m] the heading of travel is meaningless (nav2 uses 0.01 m).
_MIN_TRANSLATION_FOR_HEADING = 0.01


@dataclass(frozen=True)
class OdometryDelta:
    """Rotation-translation-rotation decomposition of an odometry step [rad, m, rad]."""

    rot1: float
    trans: float
    rot2: float

    @property
    def rotation(self) -> float:
        return float(wrap_angle(self.rot1 + self.rot2))


def odometry_delta(previous: ArrayLike, current: ArrayLike) -> OdometryDelta:
    """Decompose the motion from odometry pose ``previous`` to ``current`` (both ``(3,)``)."""
    previous = np.asarray(previous, dtype=np.float64)
    current = np.asarray(current, dtype=np.float64)
    dx, dy = current[0] - previous[0], current[1] - previous[1]
    trans = float(np.hypot(dx, dy))
    rot1 = 0.0 if trans < _MIN_TRANSLATION_FOR_HEADING else float(angle_difference(np.arctan2(dy, dx), previous[2]))
    rot2 = float(angle_difference(angle_difference(current[2], previous[2]), rot1))
    return OdometryDelta(rot1, trans, rot2)


def apply_delta(
    poses: ArrayLike,
    rot1: float | NDArray[np.float64],
    trans: float | NDArray[np.float64],
    rot2: float | NDArray[np.float64],
) -> NDArray[np.float64]:
    """Move poses ``(N, 3)`` by rot1, trans, rot2 [rad, m, rad]: scalars or ``(N,)`` per pose."""
    poses = np.asarray(poses, dtype=np.float64)
    heading = poses[..., 2] + rot1
    out = np.empty_like(poses)
    out[..., 0] = poses[..., 0] + trans * np.cos(heading)
    out[..., 1] = poses[..., 1] + trans * np.sin(heading)
    out[..., 2] = wrap_angle(heading + rot2)
    return out


def _check_alphas(model: object, names: tuple[str, ...]) -> None:
    """A motion model's noise parameters must be finite and >= 0 (ValueError naming the one that is not)."""
    for name in names:
        value = getattr(model, name)
        if not np.isfinite(value) or value < 0.0:
            raise ValueError(f"motion model {name} must be finite and >= 0, got {value!r}")


@dataclass(frozen=True)
class MotionBounds:
    """Guaranteed bounds of an odometry step: ``[lo, hi]`` for rot1, trans, rot2."""

    rot1: tuple[float, float]
    trans: tuple[float, float]
    rot2: tuple[float, float]


@dataclass(frozen=True)
class OdometryMotionModel:
    """Probabilistic odometry motion model with nav2_amcl's parameters.

    Attributes:
        alpha1: rotation noise from rotation (nav2 ``alpha1``; default 0.2 in nav2).
        alpha2: rotation noise from translation (``alpha2``).
        alpha3: translation noise from translation (``alpha3``).
        alpha4: translation noise from rotation (``alpha4``).
        alpha5: strafe noise from translation, omnidirectional model only (``alpha5``).
        omnidirectional: use nav2's ``OmniMotionModel`` instead of the differential one.
    """

    alpha1: float = 0.2
    alpha2: float = 0.2
    alpha3: float = 0.2
    alpha4: float = 0.2
    alpha5: float = 0.2
    omnidirectional: bool = False

    def __post_init__(self) -> None:
        _check_alphas(self, ("alpha1", "alpha2", "alpha3", "alpha4", "alpha5"))

    def sample(
        self,
        poses: ArrayLike,
        previous_odom: ArrayLike,
        current_odom: ArrayLike,
        rng: np.random.Generator,
    ) -> NDArray[np.float64]:
        """Propagate poses ``(N, 3)`` through the odometry step with sampled noise."""
        poses = np.asarray(poses, dtype=np.float64)
        count = poses.shape[0]
        if self.omnidirectional:
            return self._sample_omni(poses, np.asarray(previous_odom, float), np.asarray(current_odom, float), rng)
        delta = odometry_delta(previous_odom, current_odom)
        # Driving backwards must not count as a half-turn of rotation noise.
        rot1_noise = min(abs(delta.rot1), abs(float(angle_difference(delta.rot1, np.pi))))
        rot2_noise = min(abs(delta.rot2), abs(float(angle_difference(delta.rot2, np.pi))))
        std_rot1 = np.sqrt(self.alpha1 * rot1_noise**2 + self.alpha2 * delta.trans**2)
        std_trans = np.sqrt(self.alpha3 * delta.trans**2 + self.alpha4 * (rot1_noise**2 + rot2_noise**2))
        std_rot2 = np.sqrt(self.alpha1 * rot2_noise**2 + self.alpha2 * delta.trans**2)
        rot1 = delta.rot1 - rng.normal(0.0, 1.0, count) * std_rot1
        trans = delta.trans - rng.normal(0.0, 1.0, count) * std_trans
        rot2 = delta.rot2 - rng.normal(0.0, 1.0, count) * std_rot2
        return apply_delta(poses, rot1, trans, rot2)

    def _sample_omni(self, poses, previous_odom, current_odom, rng):
        count = poses.shape[0]
        dx, dy = current_odom[0] - previous_odom[0], current_odom[1] - previous_odom[1]
        trans = float(np.hypot(dx, dy))
        rot = float(angle_difference(current_odom[2], previous_odom[2]))
        # Direction of travel in the robot frame, applied in each particle's frame.
        bearing = float(angle_difference(np.arctan2(dy, dx), previous_odom[2]))
        std_trans = np.sqrt(self.alpha3 * trans**2 + self.alpha1 * rot**2)
        std_rot = np.sqrt(self.alpha4 * rot**2 + self.alpha2 * trans**2)
        std_strafe = np.sqrt(self.alpha1 * rot**2 + self.alpha5 * trans**2)
        trans_hat = trans + rng.normal(0.0, 1.0, count) * std_trans
        strafe_hat = rng.normal(0.0, 1.0, count) * std_strafe
        rot_hat = rot + rng.normal(0.0, 1.0, count) * std_rot
        heading = poses[:, 2] + bearing
        out = np.empty_like(poses)
        out[:, 0] = poses[:, 0] + trans_hat * np.cos(heading) - strafe_hat * np.sin(heading)
        out[:, 1] = poses[:, 1] + trans_hat * np.sin(heading) + strafe_hat * np.cos(heading)
        out[:, 2] = wrap_angle(poses[:, 2] + rot_hat)
        return out

    @staticmethod
    def bounds(
        previous_odom: ArrayLike,
        current_odom: ArrayLike,
        *,
        relative_translation: float,
        absolute_translation: float,
        relative_rotation: float,
        absolute_rotation: float,
    ) -> MotionBounds:
        """Guaranteed bounds of the true step, for interval methods.

        Each component ``v`` of the decomposition is bounded by
        ``v +- (relative * |v| + absolute)``; the caller states the bounds it trusts.
        """
        delta = odometry_delta(previous_odom, current_odom)

        def around(value: float, relative: float, absolute: float) -> tuple[float, float]:
            half = relative * abs(value) + absolute
            return (value - half, value + half)

        return MotionBounds(
            rot1=around(delta.rot1, relative_rotation, absolute_rotation),
            trans=around(delta.trans, relative_translation, absolute_translation),
            rot2=around(delta.rot2, relative_rotation, absolute_rotation),
        )


def arc_of_step(previous: ArrayLike, current: ArrayLike) -> tuple[float, float]:
    """The odometry step from ``previous`` to ``current`` (``(3,)``) as one arc at constant (v, w):
    ``(length [m], turn [rad])`` (``v dt``, ``w dt``); negative length when driving backwards. The chord's
    direction is taken as the arc's (a sideways slip is not a velocity)."""
    previous = np.asarray(previous, dtype=np.float64)
    current = np.asarray(current, dtype=np.float64)
    turn = float(angle_difference(current[2], previous[2]))
    dx, dy = current[0] - previous[0], current[1] - previous[1]
    chord = float(np.hypot(dx, dy))
    if chord > 0.0 and np.cos(np.arctan2(dy, dx) - previous[2] - 0.5 * turn) < 0.0:
        chord = -chord
    return chord / float(np.sinc(turn / (2.0 * np.pi))), turn  # arc = chord / (sin(turn/2) / (turn/2))


@dataclass(frozen=True)
class VelocityMotionModel:
    """Probabilistic velocity motion model (Thrun et al., table 5.3), in arc length and turn rather than
    ``v, w, dt`` (the same model for controls constant over the step; no time step needed).

    Noise on the translational and rotational components only, as Aycard & Brouard IV-D describe it
    (the table's final rotation, alpha5-6, is left out). Variances as nav2's alphas: length
    ``alpha3 s^2 + alpha4 t^2``, turn ``alpha2 s^2 + alpha1 t^2`` (the table's alpha1-2 and alpha3-4).
    """

    alpha1: float = 0.2
    alpha2: float = 0.2
    alpha3: float = 0.2
    alpha4: float = 0.2

    def __post_init__(self) -> None:
        _check_alphas(self, ("alpha1", "alpha2", "alpha3", "alpha4"))

    def sample(
        self,
        poses: ArrayLike,
        previous_odom: ArrayLike,
        current_odom: ArrayLike,
        rng: np.random.Generator,
    ) -> NDArray[np.float64]:
        """Propagate poses ``(N, 3)`` along the odometry step's arc with sampled noise."""
        poses = np.asarray(poses, dtype=np.float64)
        count = poses.shape[0]
        length, turn = arc_of_step(previous_odom, current_odom)
        std_length = np.sqrt(self.alpha3 * length**2 + self.alpha4 * turn**2)
        std_turn = np.sqrt(self.alpha2 * length**2 + self.alpha1 * turn**2)
        length_hat = length + rng.normal(0.0, 1.0, count) * std_length
        turn_hat = turn + rng.normal(0.0, 1.0, count) * std_turn
        # an arc is its chord, travelled at half the turn
        chord = length_hat * np.sinc(turn_hat / (2.0 * np.pi))
        return apply_delta(poses, 0.5 * turn_hat, chord, 0.5 * turn_hat)


def declare_odometry_noise(model: OdometryMotionModel) -> str:
    """The declaration a bag carries of the noise its odometry was made with: the differential model's
    ``alpha1..alpha4`` (variance scales, nav2's meaning), as JSON."""
    return json.dumps({"model": "odometry", **{name: float(getattr(model, name)) for name in _ALPHA_NAMES}})


def read_odometry_noise(text: str) -> dict[str, float]:
    """``alpha1..alpha4`` of a declaration made by :func:`declare_odometry_noise`.

    Raises:
        ValueError: not such a declaration, naming what is wrong with it.
    """
    try:
        declared = json.loads(text)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"odometry noise declaration is not JSON: {text!r}") from exc
    if not isinstance(declared, dict) or declared.get("model") != "odometry":
        raise ValueError(f"odometry noise declaration must be of model 'odometry', got {text!r}")
    alphas = {name: _number(name, declared.get(name)) for name in _ALPHA_NAMES}
    OdometryMotionModel(alphas["alpha1"], alphas["alpha2"], alphas["alpha3"], alphas["alpha4"])  # its own checks
    return alphas


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"odometry noise declaration: {name} must be a number, got {value!r}")
    return float(value)
