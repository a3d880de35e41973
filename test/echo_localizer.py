"""Test double for the benchmark: a "localizer" that echoes the ground truth with a chosen error.

It is not a localization method and lives only in ``test/``. ``error(stamp)``
returns the ``(dx, dy, dtheta)`` added to the true pose at the scan's stamp,
or ``None`` for "publish nothing this time".
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from robot_localization_suite.core import metrics
from robot_localization_suite.core.localizer import Estimate, LocalizerStatus


class EchoLocalizer:
    """Implements the ``Localizer`` and ``GlobalFixer`` protocols by looking at the answer."""

    def __init__(
        self,
        truth: metrics.Trajectory,
        error: Callable[[float], ArrayLike | None],
        *,
        fields: Callable[[float, np.ndarray], dict[str, Any]] | None = None,
        decoys: int = 0,
        truth_as_candidate: bool = False,
    ) -> None:
        self.truth = truth
        self.error = error
        self.fields = fields
        self.decoys = decoys
        self.truth_as_candidate = truth_as_candidate
        self.grid_map = None
        self.initial_pose = None
        self.odometry_count = 0

    def _true_pose(self, stamp: float) -> np.ndarray:
        return metrics.interpolate_poses(self.truth, [stamp], tolerance=np.inf)[0]

    def set_map(self, grid_map: Any) -> None:
        self.grid_map = grid_map

    def on_odometry(self, stamp: float, odom_pose: np.ndarray) -> None:
        self.odometry_count += 1

    def on_scan(self, scan: Any) -> Estimate | None:
        offset = self.error(scan.stamp)
        if offset is None:
            return None
        true_pose = self._true_pose(scan.stamp)
        pose = true_pose + np.asarray(offset, dtype=np.float64)
        fields = self.fields(scan.stamp, true_pose) if self.fields else {}
        # truth_as_candidate: the truth is always the runner-up candidate (an ambiguous place).
        candidates = np.vstack([pose, true_pose]) if self.truth_as_candidate else np.zeros((0, 3))
        return Estimate(scan.stamp, pose, np.eye(3) * 0.01, LocalizerStatus.LOCALIZED, candidates=candidates,
                        **fields)

    def global_fix(self, scan: Any) -> Estimate:
        """Ranked candidates: ``decoys`` wrong poses 5 m away first, then the error-shifted truth."""
        true_pose = self._true_pose(scan.stamp)
        offset = self.error(scan.stamp)
        good = true_pose + (np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64))
        decoys = np.tile(true_pose + np.array([5.0, 0.0, 0.0]), (self.decoys, 1))
        candidates = np.vstack([decoys, good[None, :]])
        return Estimate(scan.stamp, candidates[0], np.eye(3), LocalizerStatus.AMBIGUOUS, candidates=candidates)

    def set_initial_pose(self, pose: np.ndarray, covariance: np.ndarray) -> None:
        self.initial_pose = np.asarray(pose, dtype=np.float64)

    def reinitialize(self) -> None:
        self.initial_pose = None

    def request_nomotion_update(self) -> None:
        pass
