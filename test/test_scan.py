"""The laser scan type (core/scan.py): its end points, from one pose or many."""

from __future__ import annotations

import math

import numpy as np

from robot_localization_suite.core.scan import Scan


def test_end_points_from_many_poses_are_those_from_each_pose() -> None:
    angles = np.linspace(-math.pi / 2, math.pi / 2, 7)
    ranges = np.array([1.0, np.inf, 2.0, 0.5, np.nan, 3.0, 1.5])  # two readings without a hit
    scan = Scan(0.0, angles, ranges, 0.05, 10.0)
    poses = np.array([[0.0, 0.0, 0.0], [1.0, -2.0, math.pi / 2], [-3.0, 4.0, -2.5]])
    batch = scan.hit_endpoints(poses)
    assert batch.shape == (3, 5, 2)
    for pose, ends in zip(poses, batch, strict=True):
        np.testing.assert_allclose(ends, scan.hit_endpoints(pose))
    # the third hit is the beam straight ahead (0.5 m): along x from the first pose, along y from the second
    np.testing.assert_allclose(batch[0, 2], [0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(batch[1, 2], [1.0, -1.5], atol=1e-12)
