"""Benchmark metrics: localizer outputs against ground truth, as plain arrays.

An output is *correct* within 0.5 m and 25 degrees of the ground truth
interpolated at its stamp (never across a kidnapping), *fine* within 0.2 m and
0.1 rad; a *fix* is a correct output followed by ``FIX_FOLLOWERS`` more. A
*kidnapping* is a ground-truth step of more than ``KIDNAP_JUMP_M`` that
odometry does not show. From these: time to first fix, kidnap recovery (in
seconds, in outputs, and with the truth among the first ``CANDIDATE_K``
candidates), correct and fine rates from the first fix on, the tracking RMSE
leaving out each recovery (and over the stretch no run of a bag leaves out, to
compare methods on the same outputs), recall@k of global fixes, and IAL's containment.

Everything here is numpy only; nothing knows about bags or ROS.

Definitions in full: docs/benchmark.md (and README ``## Benchmark``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .se2 import angle_difference, relative, wrap_angle

if TYPE_CHECKING:
    from .grid_map import GridMap
    from .scan import Scan

__all__ = [
    "outside_kidnap_until_restart",
    "CORRECT_XY_M",
    "CORRECT_THETA_RAD",
    "FINE_XY_M",
    "FINE_THETA_RAD",
    "FIX_FOLLOWERS",
    "KIDNAP_JUMP_M",
    "KIDNAP_EXCLUSION_S",
    "RECALL_KS",
    "CANDIDATE_K",
    "candidates_correct",
    "Trajectory",
    "interpolate_poses",
    "detect_kidnappings",
    "pose_errors",
    "correct_mask",
    "fine_mask",
    "first_fix_index",
    "evaluate_outputs",
    "RmseSample",
    "shared_rmse",
    "status_fields",
    "timing_fields",
    "boxes_contain",
    "nearest_node_is_place",
    "recall_at_k",
    "evaluate_global_fixes",
    "COVERAGE_TOLERANCE_CELLS",
    "COVERED_FRACTION",
    "map_coverage",
    "scan_explained",
    "coverage_at_stamps",
    "coverage_rates",
]

CORRECT_XY_M = 0.5
CORRECT_THETA_RAD = float(np.deg2rad(25.0))
FINE_XY_M = 0.2
FINE_THETA_RAD = 0.1
FIX_FOLLOWERS = 3
KIDNAP_JUMP_M = 1.0
KIDNAP_EXCLUSION_S = 5.0
RECALL_KS = (1, 5, 10, 30, 50, 100)
CANDIDATE_K = 10
COVERAGE_TOLERANCE_CELLS = 2  # an end point is explained within 2 cells (0.1 m on 5 cm maps) of an occupied cell
COVERED_FRACTION = 0.8  # an output is "covered" when at least this share of its scan's end points is explained


@dataclass(frozen=True)
class Trajectory:
    """Time-stamped poses: ``stamps`` ``(N,)`` [s] increasing, ``poses`` ``(N, 3)`` [m, m, rad]."""

    stamps: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps, dtype=np.float64).reshape(-1)
        poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)
        if stamps.shape[0] != poses.shape[0]:
            raise ValueError(f"trajectory has {stamps.shape[0]} stamps but {poses.shape[0]} poses")
        order = np.argsort(stamps, kind="stable")
        object.__setattr__(self, "stamps", stamps[order])
        object.__setattr__(self, "poses", poses[order])

    def __len__(self) -> int:
        return int(self.stamps.shape[0])

    @property
    def period(self) -> float:
        """Median time between poses [s] (0 with fewer than two poses)."""
        return float(np.median(np.diff(self.stamps))) if len(self) > 1 else 0.0


def interpolate_poses(
    trajectory: Trajectory,
    query: ArrayLike,
    *,
    breaks: ArrayLike = (),
    tolerance: float | None = None,
) -> NDArray[np.float64]:
    """Poses ``(Q, 3)`` of ``trajectory`` at stamps ``query`` [s]; NaN rows where it has none.

    x, y and the unwrapped heading are interpolated linearly. ``breaks`` are indices
    ``i`` where the step from pose ``i - 1`` to ``i`` is a jump: between those two the
    earlier pose holds. Queries up to ``tolerance`` (default: one period) outside the
    trajectory's span take its first or last pose.
    """
    query = np.atleast_1d(np.asarray(query, dtype=np.float64))
    out = np.full((query.shape[0], 3), np.nan)
    count = len(trajectory)
    if count == 0:
        return out
    stamps = trajectory.stamps
    tolerance = trajectory.period if tolerance is None else float(tolerance)
    theta = np.unwrap(trajectory.poses[:, 2])
    left = np.searchsorted(stamps, query, side="right") - 1
    inside = (left >= 0) & (left < count - 1)
    before = (left < 0) & (query >= stamps[0] - tolerance)
    after = (left >= count - 1) & (query <= stamps[-1] + tolerance)
    out[before] = trajectory.poses[0]
    out[after] = trajectory.poses[-1]
    if np.any(inside):
        i = left[inside]
        t0, t1 = stamps[i], stamps[i + 1]
        span = np.where(t1 > t0, t1 - t0, 1.0)
        w = np.clip((query[inside] - t0) / span, 0.0, 1.0)
        jump = np.isin(i + 1, np.asarray(breaks, dtype=np.int64))
        w = np.where(jump, 0.0, w)
        p0, p1 = trajectory.poses[i], trajectory.poses[i + 1]
        out[inside, 0] = p0[:, 0] + w * (p1[:, 0] - p0[:, 0])
        out[inside, 1] = p0[:, 1] + w * (p1[:, 1] - p0[:, 1])
        out[inside, 2] = wrap_angle(theta[i] + w * (theta[i + 1] - theta[i]))
    return out


def detect_kidnappings(
    ground_truth: Trajectory,
    odometry: Trajectory | None = None,
    *,
    jump_m: float = KIDNAP_JUMP_M,
) -> NDArray[np.int64]:
    """Indices ``i`` of ground-truth steps ``i - 1 -> i`` that are kidnappings (docs/benchmark.md)."""
    if len(ground_truth) < 2:
        return np.zeros(0, dtype=np.int64)
    previous, current = ground_truth.poses[:-1], ground_truth.poses[1:]
    step = np.hypot(current[:, 0] - previous[:, 0], current[:, 1] - previous[:, 1])
    candidates = np.nonzero(step > jump_m)[0] + 1
    if odometry is None or len(odometry) < 2 or candidates.size == 0:
        return candidates.astype(np.int64)
    odom_before = interpolate_poses(odometry, ground_truth.stamps[candidates - 1], tolerance=np.inf)
    odom_after = interpolate_poses(odometry, ground_truth.stamps[candidates], tolerance=np.inf)
    truth_step = relative(ground_truth.poses[candidates - 1], ground_truth.poses[candidates])
    odom_step = relative(odom_before, odom_after)
    unexplained = np.hypot(truth_step[:, 0] - odom_step[:, 0], truth_step[:, 1] - odom_step[:, 1])
    return candidates[unexplained > jump_m].astype(np.int64)


def pose_errors(estimates: ArrayLike, truth: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position error [m] and absolute heading error [rad] of poses ``(N, 3)`` against ``(N, 3)``."""
    estimates = np.asarray(estimates, dtype=np.float64).reshape(-1, 3)
    truth = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    dxy = np.hypot(estimates[:, 0] - truth[:, 0], estimates[:, 1] - truth[:, 1])
    dtheta = np.abs(np.asarray(angle_difference(estimates[:, 2], truth[:, 2]), dtype=np.float64))
    return dxy, dtheta


def correct_mask(dxy: NDArray[np.float64], dtheta: NDArray[np.float64]) -> NDArray[np.bool_]:
    with np.errstate(invalid="ignore"):
        return (dxy <= CORRECT_XY_M) & (dtheta <= CORRECT_THETA_RAD)


def fine_mask(dxy: NDArray[np.float64], dtheta: NDArray[np.float64]) -> NDArray[np.bool_]:
    with np.errstate(invalid="ignore"):
        return (dxy <= FINE_XY_M) & (dtheta <= FINE_THETA_RAD)


def candidates_correct(candidates: ArrayLike, truth: ArrayLike) -> NDArray[np.bool_]:
    """Per output: is one of its candidates correct? ``candidates`` ``(N, K, 3)`` (NaN rows: none), ``truth`` ``(N, 3)``."""
    candidates = np.asarray(candidates, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    if candidates.size == 0:
        return np.zeros(truth.shape[0], dtype=bool)
    count, k = candidates.shape[:2]
    dxy, dtheta = pose_errors(candidates.reshape(-1, 3), np.repeat(truth, k, axis=0))
    return np.asarray(correct_mask(dxy, dtheta).reshape(count, k).any(axis=1), dtype=bool)


def first_fix_index(
    stamps: NDArray[np.float64],
    correct: NDArray[np.bool_],
    *,
    start: float = -np.inf,
    stop: float = np.inf,
    followers: int = FIX_FOLLOWERS,
) -> int | None:
    """Index of the first output stamped in ``[start, stop)`` that is correct along with the next ``followers``."""
    correct = np.asarray(correct, dtype=bool)
    window = followers + 1
    if correct.size < window:
        return None
    # runs[j] is True when correct[j : j + window] are all True.
    runs = np.convolve(correct.astype(np.int64), np.ones(window, dtype=np.int64), mode="valid") == window
    eligible = runs & (stamps[: runs.size] >= start) & (stamps[: runs.size] < stop)
    found = np.nonzero(eligible)[0]
    return int(found[0]) if found.size else None


def _rounded(value: float | None, digits: int = 4) -> float | None:
    if value is None or not np.isfinite(value):
        return None
    return round(float(value), digits)


def status_fields(statuses: Sequence[str], correct: ArrayLike, recovering: ArrayLike | None = None) -> dict[str, Any]:
    """How far a localizer's own verdict can be trusted, over all its outputs.

    ``localized_rate``: outputs reported LOCALIZED over all outputs; ``false_localized_rate``:
    LOCALIZED outputs that are not correct over all LOCALIZED outputs (null when none is); both
    count every output, before the first fix too: a robot acts on LOCALIZED whenever it is said.
    Given ``recovering`` (per output: inside a kidnapping's window, from the jump to the recovery
    fix), also ``false_localized_rate_outside_kidnaps``: the same over the LOCALIZED outputs
    outside those windows, to tell a kidnapping the method has not noticed yet from a wrong fix.
    """
    localized = np.asarray([s == "LOCALIZED" for s in statuses], dtype=bool)
    good = np.asarray(correct, dtype=bool).reshape(-1)
    if localized.size != good.size:
        raise ValueError(f"status_fields: {localized.size} statuses but {good.size} correctness flags")
    count = int(localized.sum())
    fields: dict[str, Any] = {
        "localized_outputs": count,
        "localized_rate": _rounded(count / localized.size) if localized.size else None,
        "false_localized_rate": _rounded(float(np.mean(~good[localized]))) if count else None,
    }
    if recovering is not None:
        outside = localized & ~np.asarray(recovering, dtype=bool).reshape(-1)
        fields["false_localized_rate_outside_kidnaps"] = (_rounded(float(np.mean(~good[outside])))
                                                          if outside.any() else None)
    return fields


def timing_fields(update_ms: ArrayLike) -> dict[str, float | None]:
    """``update_ms_median`` and ``update_ms_p95`` of update times [ms] (None without updates)."""
    update_ms = np.asarray(update_ms, dtype=np.float64)
    if update_ms.size == 0:
        return {"update_ms_median": None, "update_ms_p95": None}
    return {
        "update_ms_median": _rounded(np.median(update_ms), 3),
        "update_ms_p95": _rounded(np.percentile(update_ms, 95), 3),
    }


def evaluate_outputs(
    output_stamps: ArrayLike,
    output_poses: ArrayLike,
    ground_truth: Trajectory,
    *,
    first_input_stamp: float | None,
    kidnap_indices: ArrayLike = (),
    candidates: ArrayLike | None = None,
) -> dict[str, Any]:
    """The accuracy fields of ``summary.json`` for one run (docs/benchmark.md).

    Returns ``correct``, ``fine`` (per-output booleans, for plots), ``position_error_m``,
    ``heading_error_rad`` (NaN without truth), and the scalar fields
    ``time_to_first_fix_s``, ``kidnap_recovery_s``, ``correct_rate``, ``fine_rate``,
    ``rmse_xy_m``, ``rmse_theta_rad``, ``kidnap_recovery_updates`` and, given
    ``candidates`` ``(N, K, 3)`` (each output's first K candidates, NaN-padded),
    ``kidnap_candidate_recovery_updates``; ``kidnap_at_destination_before``, per kidnapping whether the last
    output before the jump was already correct for the pose the robot was carried to (its recovery is then the
    kidnapping coming to a place the method held wrongly, not a finding; null without an output before the jump);
    nulls where a value does not exist; ``recovering``, per output
    whether it lies in a kidnapping's window (from the jump to its recovery fix, at least 5 s); and
    ``rmse_excluded``, the intervals ``[start, stop)`` of stamps the RMSE leaves out (before the first fix,
    each kidnapping's window; everything without a fix), for :func:`shared_rmse`.
    """
    stamps = np.asarray(output_stamps, dtype=np.float64).reshape(-1)
    poses = np.asarray(output_poses, dtype=np.float64).reshape(-1, 3)
    kidnaps = np.asarray(kidnap_indices, dtype=np.int64).reshape(-1)
    kidnap_stamps = ground_truth.stamps[kidnaps] if kidnaps.size else np.zeros(0)
    truth = interpolate_poses(ground_truth, stamps, breaks=kidnaps)
    dxy, dtheta = pose_errors(poses, truth)
    has_truth = np.isfinite(dxy)
    correct = correct_mask(dxy, dtheta) & has_truth
    fine = fine_mask(dxy, dtheta) & has_truth

    fix = first_fix_index(stamps, correct)
    time_to_first_fix = None
    if fix is not None and first_input_stamp is not None:
        time_to_first_fix = _rounded(stamps[fix] - first_input_stamp)

    proposed = None
    if candidates is not None:
        proposed = correct | (candidates_correct(candidates, truth) & has_truth)
    recoveries: list[float | None] = []
    recovery_updates: list[int | None] = []
    candidate_updates: list[int | None] = []
    at_destination: list[bool | None] = []
    recovering = np.zeros(stamps.size, dtype=bool)  # from each jump to its recovery fix (>= 5 s)
    excluded = [(-np.inf, np.inf if fix is None else float(stamps[fix]))]
    for k, jump_stamp in enumerate(kidnap_stamps):
        next_jump = kidnap_stamps[k + 1] if k + 1 < kidnap_stamps.size else np.inf
        first_after = int(np.searchsorted(stamps, jump_stamp, side="left"))
        index = first_fix_index(stamps, correct, start=jump_stamp, stop=next_jump)
        recoveries.append(None if index is None else _rounded(stamps[index] - jump_stamp))
        recovery_updates.append(None if index is None else index - first_after + 1)
        if first_after == 0:
            at_destination.append(None)
        else:  # the last output before the jump against the pose the robot was carried to
            held = correct_mask(*pose_errors(poses[first_after - 1], ground_truth.poses[kidnaps[k]]))
            at_destination.append(bool(held[0]))
        if proposed is not None:
            found = first_fix_index(stamps, proposed, start=jump_stamp, stop=next_jump)
            candidate_updates.append(None if found is None else found - first_after + 1)
        recovered_at = next_jump if index is None else max(stamps[index], jump_stamp + KIDNAP_EXCLUSION_S)
        recovering |= (stamps >= jump_stamp) & (stamps < recovered_at)
        excluded.append((float(jump_stamp), float(recovered_at)))

    fields: dict[str, Any] = {
        "time_to_first_fix_s": time_to_first_fix,
        "kidnap_recovery_s": recoveries,
        "kidnap_recovery_updates": recovery_updates,
        "kidnap_at_destination_before": at_destination,
        "kidnap_candidate_recovery_updates": candidate_updates if proposed is not None else None,
        "correct_rate": None,
        "fine_rate": None,
        "rmse_xy_m": None,
        "rmse_theta_rad": None,
    }
    if fix is not None:
        after_fix = (np.arange(stamps.size) >= fix) & has_truth
        fields["correct_rate"] = _rounded(np.mean(correct[after_fix]))
        fields["fine_rate"] = _rounded(np.mean(fine[after_fix]))
        fields["rmse_xy_m"], fields["rmse_theta_rad"] = _rmse(dxy, dtheta, after_fix & ~recovering)
    fields.update(
        correct=correct,
        fine=fine,
        position_error_m=dxy,
        heading_error_rad=dtheta,
        recovering=recovering,
        rmse_excluded=excluded,
    )
    return fields


@dataclass(frozen=True)
class RmseSample:
    """One run's outputs for :func:`shared_rmse`: their stamps and errors (NaN: no truth), and the intervals
    ``[start, stop)`` its own RMSE leaves out (``evaluate_outputs``'s ``rmse_excluded``)."""

    stamps: NDArray[np.float64]
    position_error_m: NDArray[np.float64]
    heading_error_rad: NDArray[np.float64]
    excluded: Sequence[tuple[float, float]]

    @property
    def fixed(self) -> bool:
        return not any(start == -np.inf and stop == np.inf for start, stop in self.excluded)


def shared_rmse(runs: Mapping[str, RmseSample]) -> dict[str, dict[str, Any]]:
    """Each run's RMSE over the stretch of the bag that none of ``runs`` leaves out of its own RMSE.

    A run's own ``rmse_xy_m`` leaves out its own recoveries, so a method that recovers sooner is measured over
    more of the bag, the fresh fix after each recovery included: two methods' RMSE then compare different
    outputs. Here every run leaves out the union of all runs' intervals (before each first fix, each kidnapping
    until the slowest recovery). Runs that never fixed do not take part (null), so they cannot empty the
    stretch. Fields: ``rmse_xy_m_shared``, ``rmse_theta_rad_shared``, ``shared_outputs``; empty with fewer
    than two runs taking part.
    """
    taking_part = {name: run for name, run in runs.items() if run.fixed}
    if len(taking_part) < 2:
        return {}
    fields: dict[str, dict[str, Any]] = {
        name: {"rmse_xy_m_shared": None, "rmse_theta_rad_shared": None, "shared_outputs": 0} for name in runs}
    intervals = [interval for run in taking_part.values() for interval in run.excluded]
    for name, run in taking_part.items():
        stamps = np.asarray(run.stamps, dtype=np.float64)
        dxy = np.asarray(run.position_error_m, dtype=np.float64)
        dtheta = np.asarray(run.heading_error_rad, dtype=np.float64)
        kept = np.isfinite(dxy)
        for start, stop in intervals:
            kept &= ~((stamps >= start) & (stamps < stop))
        fields[name]["shared_outputs"] = int(kept.sum())
        fields[name]["rmse_xy_m_shared"], fields[name]["rmse_theta_rad_shared"] = _rmse(dxy, dtheta, kept)
    return fields


def _rmse(dxy: NDArray[np.float64], dtheta: NDArray[np.float64],
          counted: NDArray[np.bool_]) -> tuple[float | None, float | None]:
    """Position and heading RMSE over the ``counted`` outputs; nulls when none is."""
    if not counted.any():
        return None, None
    return _rounded(np.sqrt(np.mean(dxy[counted] ** 2))), _rounded(np.sqrt(np.mean(dtheta[counted] ** 2)))


def boxes_contain(boxes: ArrayLike, pose: ArrayLike) -> bool:
    """Whether any box ``(K, 3, 2)`` (``[lo, hi]`` of x, y, theta) contains ``pose`` ``(3,)``.

    Heading intervals may extend beyond ``[-pi, pi]``; containment is checked modulo 2 pi.
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 3, 2)
    pose = np.asarray(pose, dtype=np.float64)
    if boxes.shape[0] == 0 or not np.all(np.isfinite(pose)):
        return False
    inside_xy = (
        (boxes[:, 0, 0] <= pose[0]) & (pose[0] <= boxes[:, 0, 1]) & (boxes[:, 1, 0] <= pose[1]) & (pose[1] <= boxes[:, 1, 1])
    )
    width = boxes[:, 2, 1] - boxes[:, 2, 0]
    offset = np.mod(pose[2] - boxes[:, 2, 0], 2.0 * np.pi)
    inside_theta = (width >= 2.0 * np.pi) | ((width >= 0.0) & (offset <= width))
    return bool(np.any(inside_xy & inside_theta))


def nearest_node_is_place(place_xy: ArrayLike, node_xy: ArrayLike, true_xy: ArrayLike, tolerance: float = 1e-6) -> bool:
    """Whether ``place_xy`` ``(2,)`` is the node of ``node_xy`` ``(N, 2)`` nearest to ``true_xy``."""
    nodes = np.asarray(node_xy, dtype=np.float64).reshape(-1, 2)
    place = np.asarray(place_xy, dtype=np.float64).reshape(2)
    truth = np.asarray(true_xy, dtype=np.float64).reshape(-1)[:2]
    if nodes.shape[0] == 0 or not np.all(np.isfinite(truth)):
        return False
    nearest = nodes[np.argmin(np.hypot(nodes[:, 0] - truth[0], nodes[:, 1] - truth[1]))]
    return bool(np.hypot(*(nearest - place)) <= tolerance)


def recall_at_k(candidates: ArrayLike, truth: ArrayLike, ks: Sequence[int] = RECALL_KS) -> dict[int, bool]:
    """For each k: is a correct candidate (0.5 m, 25 deg) among the first k of ``candidates`` ``(K, 3)``?"""
    candidates = np.asarray(candidates, dtype=np.float64).reshape(-1, 3)
    if candidates.shape[0] == 0:
        return {k: False for k in ks}
    dxy, dtheta = pose_errors(candidates, np.broadcast_to(np.asarray(truth, dtype=np.float64), candidates.shape))
    correct = correct_mask(dxy, dtheta)
    first = int(np.argmax(correct)) if correct.any() else None
    return {k: first is not None and first < k for k in ks}


def evaluate_global_fixes(
    estimates: ArrayLike,
    truths: ArrayLike,
    fix_ms: ArrayLike,
    recalls: Sequence[dict[int, bool]],
    ks: Sequence[int] = RECALL_KS,
) -> dict[str, Any]:
    """Fields of ``--global-fixes``: success rates of single-scan fixes, their time, recall@k.

    ``estimates`` ``(F, 3)`` (NaN rows for failed fixes), ``truths`` ``(F, 3)``, ``fix_ms`` ``(F,)``,
    ``recalls`` one :func:`recall_at_k` result per fix. Fixes without truth are left out.
    """
    estimates = np.asarray(estimates, dtype=np.float64).reshape(-1, 3)
    truths = np.asarray(truths, dtype=np.float64).reshape(-1, 3)
    fix_ms = np.asarray(fix_ms, dtype=np.float64).reshape(-1)
    with_truth = np.all(np.isfinite(truths), axis=1)
    dxy, dtheta = pose_errors(estimates, truths)
    fields: dict[str, Any] = {"fixes": int(fix_ms.size), "fixes_with_truth": int(with_truth.sum())}
    if with_truth.any():
        fields["global_correct_rate"] = _rounded(float(np.mean(correct_mask(dxy, dtheta)[with_truth])))
        fields["global_fine_rate"] = _rounded(float(np.mean(fine_mask(dxy, dtheta)[with_truth])))
        kept = [r for r, keep in zip(recalls, with_truth, strict=True) if keep]
        fields["recall_at_k"] = {str(k): _rounded(float(np.mean([r[k] for r in kept]))) for k in ks}
    else:
        fields["global_correct_rate"] = None
        fields["global_fine_rate"] = None
        fields["recall_at_k"] = {str(k): None for k in ks}
    if fix_ms.size:
        fields["fix_ms_median"] = _rounded(np.median(fix_ms), 3)
        fields["fix_ms_p95"] = _rounded(np.percentile(fix_ms, 95), 3)
    else:
        fields["fix_ms_median"] = fields["fix_ms_p95"] = None
    return fields


def outside_kidnap_until_restart(
    stamps: NDArray[np.float64], lost: NDArray[np.bool_], kidnap_stamps: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """Mask of outputs outside ``[kidnapping, first LOST output after it]`` (both ends excluded from the rate).

    A kidnapping no sensor can notice breaks the bounds a guaranteed method rests on;
    its promise holds again from the restart that an empty set (status LOST) triggers.
    A kidnapping never followed by a LOST output masks everything after it.
    """
    keep = np.ones(stamps.shape, dtype=bool)
    for kidnap in np.asarray(kidnap_stamps, dtype=np.float64):
        after = stamps >= kidnap
        restarts = np.flatnonzero(after & lost)
        end = stamps[restarts[0]] if restarts.size else np.inf
        keep &= ~(after & (stamps <= end))
    return keep


def map_coverage(
    grid_map: GridMap,
    laser_poses: ArrayLike,
    angles: ArrayLike,
    ranges: ArrayLike,
    *,
    range_max: ArrayLike,
    range_min: ArrayLike = 0.0,
    tolerance: float | None = None,
) -> NDArray[np.float64]:
    """Per scan, the fraction of its hit end points that lie near an occupied cell of ``grid_map``.

    Args:
        grid_map: the map the scans are judged against.
        laser_poses: ``(S, 3)`` true laser poses in the map frame [m, m, rad].
        angles: ``(B,)`` or ``(S, B)`` beam angles in the laser frame [rad].
        ranges: ``(S, B)`` raw readings [m] (NaN-pad scans with fewer beams), or ``(B,)``: one scan judged
            at every pose. A hit is finite and in ``[range_min, range_max)`` (REP 117, as ``core.scan.Scan``);
            other readings are left out.
        range_max, range_min: scalars or ``(S,)`` [m].
        tolerance: [m], default ``COVERAGE_TOLERANCE_CELLS * grid_map.resolution`` (0.1 m at 5 cm).
            Measured from the centre of the end point's cell to the nearest occupied cell centre
            (``GridMap.distance_field``): at 2 cells, the cell itself, its 8 neighbours and the
            4 cells two steps away along an axis.

    Returns:
        ``(S,)`` fractions in ``[0, 1]``; NaN for a scan without hits. End points off the map count
        as not explained.
    """
    poses = np.asarray(laser_poses, dtype=np.float64).reshape(-1, 3)
    ranges = np.atleast_2d(np.asarray(ranges, dtype=np.float64))
    if np.ndim(ranges) == 2 and ranges.shape[0] == 1:
        ranges = np.broadcast_to(ranges, (poses.shape[0], ranges.shape[1]))
    if ranges.shape[0] != poses.shape[0]:
        raise ValueError(f"map_coverage: {poses.shape[0]} poses but {ranges.shape[0]} scans of ranges")
    angles = np.broadcast_to(np.asarray(angles, dtype=np.float64), ranges.shape)
    tolerance = COVERAGE_TOLERANCE_CELLS * grid_map.resolution if tolerance is None else float(tolerance)
    if not np.isfinite(tolerance) or tolerance < 0.0:
        raise ValueError(f"map_coverage: tolerance must be >= 0 m, got {tolerance!r}")
    upper = np.asarray(range_max, dtype=np.float64).reshape(-1, 1) if np.ndim(range_max) else float(np.asarray(range_max))
    lower = np.asarray(range_min, dtype=np.float64).reshape(-1, 1) if np.ndim(range_min) else float(np.asarray(range_min))
    with np.errstate(invalid="ignore"):
        hit = np.isfinite(ranges) & (ranges >= lower) & (ranges < upper)
    length = np.where(hit, ranges, 0.0)
    heading = poses[:, 2:3] + angles
    ends = np.stack([poses[:, 0:1] + length * np.cos(heading), poses[:, 1:2] + length * np.sin(heading)], axis=-1)
    cells = grid_map.world_to_cell(ends)
    inside = hit & grid_map.in_bounds(cells)
    near = np.zeros(ranges.shape, dtype=bool)
    # float32 field: a cell exactly `tolerance` away must count (2 * 0.05 m is 0.1000000015 in float32).
    near[inside] = grid_map.distance_field()[cells[..., 1][inside], cells[..., 0][inside]] <= tolerance + 1e-6
    hits = hit.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(hits > 0, near.sum(axis=1) / hits, np.nan)


def scan_explained(grid_map: GridMap, poses: ArrayLike, scan: Scan) -> NDArray[np.float64]:
    """Per laser pose ``(P, 3)``, the share of ``scan``'s hit end points the map explains there: :func:`map_coverage`
    of the one scan at every pose (NaN without a hit). What a localizer asks before standing behind a pose."""
    return map_coverage(grid_map, poses, scan.angles, scan.ranges, range_max=scan.range_max,
                        range_min=scan.range_min)


def coverage_at_stamps(
    query_stamps: ArrayLike, scan_stamps: ArrayLike, coverage: ArrayLike, *, max_gap_s: float = 5e-4
) -> NDArray[np.float64]:
    """Coverage ``(Q,)`` of the scan nearest each query stamp [s], NaN where none is within ``max_gap_s``.

    Outputs carry their input scan's stamp, so a localizer's outputs find their scans exactly.
    """
    query = np.atleast_1d(np.asarray(query_stamps, dtype=np.float64))
    stamps: NDArray[np.float64] = np.asarray(scan_stamps, dtype=np.float64).reshape(-1)
    values: NDArray[np.float64] = np.asarray(coverage, dtype=np.float64).reshape(-1)
    if stamps.shape != values.shape:
        raise ValueError(f"coverage_at_stamps: {stamps.size} scan stamps but {values.size} coverages")
    out = np.full(query.shape, np.nan)
    if stamps.size == 0:
        return out
    order = np.argsort(stamps, kind="stable")
    stamps, values = stamps[order], values[order]
    right = np.clip(np.searchsorted(stamps, query), 1, max(stamps.size - 1, 1))
    left = right - 1
    nearest = np.where(np.abs(stamps[right] - query) < np.abs(query - stamps[left]), right, left)
    close = np.abs(stamps[nearest] - query) <= max_gap_s
    out[close] = values[nearest[close]]
    return out


def coverage_rates(
    correct: ArrayLike, coverage: ArrayLike, *, threshold: float = COVERED_FRACTION
) -> dict[str, Any]:
    """Correct rates split by map coverage, for the outputs given (pass ``correct[after_fix]`` and its
    coverage for the from-first-fix convention of ``correct_rate``).

    Returns ``coverage_median`` (over outputs with a coverage), ``outputs``, ``outputs_covered``
    (coverage >= ``threshold``), ``correct_rate``, ``correct_rate_covered`` and
    ``correct_rate_uncovered`` (coverage known and below ``threshold``); None where there is nothing.
    """
    correct = np.asarray(correct, dtype=bool).reshape(-1)
    coverage = np.asarray(coverage, dtype=np.float64).reshape(-1)
    if correct.shape != coverage.shape:
        raise ValueError(f"coverage_rates: {correct.size} outputs but {coverage.size} coverages")
    known = np.isfinite(coverage)
    with np.errstate(invalid="ignore"):
        covered = known & (coverage >= threshold)
    uncovered = known & ~covered

    def rate(mask: NDArray[np.bool_]) -> float | None:
        return _rounded(np.mean(correct[mask])) if mask.any() else None

    return {
        "coverage_threshold": float(threshold),
        "coverage_median": _rounded(np.median(coverage[known])) if known.any() else None,
        "outputs": int(correct.size),
        "outputs_covered": int(covered.sum()),
        "correct_rate": rate(np.ones_like(correct)),
        "correct_rate_covered": rate(covered),
        "correct_rate_uncovered": rate(uncovered),
    }
