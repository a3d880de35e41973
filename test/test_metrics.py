"""Benchmark metrics against hand-made trajectories (core/metrics.py, no ROS)."""

from __future__ import annotations

import numpy as np
import pytest

from robot_localization_suite.core import metrics

SCAN_PERIOD = 0.1  # [s] of every hand-made trajectory below


def straight_line(duration: float = 20.0, speed: float = 0.5, period: float = SCAN_PERIOD) -> metrics.Trajectory:
    """A robot driving along +x at ``speed`` m/s, one pose every ``period`` s."""
    stamps = np.arange(0.0, duration + 1e-9, period)
    poses = np.stack([speed * stamps, np.zeros_like(stamps), np.zeros_like(stamps)], axis=1)
    return metrics.Trajectory(stamps, poses)


def kidnapped_line(jump_at: float = 10.0, jump_y: float = 3.0):
    """Ground truth that jumps 3 m sideways at ``jump_at`` while odometry keeps driving straight."""
    odometry = straight_line()
    truth_poses = odometry.poses.copy()
    truth_poses[odometry.stamps >= jump_at - 1e-9, 1] += jump_y
    return metrics.Trajectory(odometry.stamps, truth_poses), odometry


def old_place_until(truth: metrics.Trajectory, odometry: metrics.Trajectory, start: float, stop: float):
    """Outputs naming the old place (where odometry says) from ``start`` to ``stop`` [s], exact otherwise."""
    outputs = truth.poses.copy()
    lost = (truth.stamps >= start - 1e-9) & (truth.stamps < stop - 1e-9)
    outputs[lost] = odometry.poses[lost]
    return outputs, lost


def test_constant_offset_is_correct_but_never_fine():
    truth = straight_line()
    outputs = truth.poses + np.array([0.3, 0.0, 0.0])  # 0.3 m: inside 0.5 m, outside 0.2 m
    fields = metrics.evaluate_outputs(truth.stamps, outputs, truth, first_input_stamp=0.0)
    assert fields["correct_rate"] == 1.0
    assert fields["fine_rate"] == 0.0
    assert fields["rmse_xy_m"] == pytest.approx(0.3, abs=1e-6)
    assert fields["rmse_theta_rad"] == pytest.approx(0.0, abs=1e-9)
    assert fields["time_to_first_fix_s"] == 0.0
    assert fields["kidnap_recovery_s"] == []


def test_heading_error_alone_decides_correct_and_fine():
    truth = straight_line(duration=2.0)
    # 0.15 rad: fine fails (> 0.1 rad), correct holds (< 25 deg = 0.436 rad).
    fields = metrics.evaluate_outputs(truth.stamps, truth.poses + [0.0, 0.0, 0.15], truth, first_input_stamp=0.0)
    assert (fields["correct_rate"], fields["fine_rate"]) == (1.0, 0.0)
    # 30 degrees: not correct anywhere, so no fix at all.
    fields = metrics.evaluate_outputs(truth.stamps, truth.poses + [0.0, 0.0, np.deg2rad(30)], truth,
                                      first_input_stamp=0.0)
    assert fields["time_to_first_fix_s"] is None
    assert fields["correct_rate"] is None


def test_kidnapping_detected_only_when_odometry_does_not_show_it():
    truth, odometry = kidnapped_line()
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    assert kidnaps.tolist() == [100]  # the pose stamped 10.0 s is the first after the jump
    # The same 3 m step shown by odometry is a fast drive, not a kidnapping.
    assert metrics.detect_kidnappings(truth, truth).size == 0
    # Without odometry every ground-truth step over 1 m counts.
    assert metrics.detect_kidnappings(truth, None).tolist() == [100]
    # A 0.9 m teleport stays under the 1 m threshold.
    small, odometry = kidnapped_line(jump_y=0.9)
    assert metrics.detect_kidnappings(small, odometry).size == 0


def test_kidnapping_recovered_after_two_seconds():
    truth, odometry = kidnapped_line(jump_at=10.0)
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    stamps = truth.stamps
    # The localizer keeps following odometry (the old place) for 2 s, then snaps to the truth.
    outputs, _ = old_place_until(truth, odometry, 10.0, 12.0)
    fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
    assert len(fields["kidnap_recovery_s"]) == 1
    assert fields["kidnap_recovery_s"][0] == pytest.approx(2.0, abs=SCAN_PERIOD)
    assert fields["time_to_first_fix_s"] == 0.0
    # 20 of 201 outputs are wrong; RMSE leaves out the 5 s after the jump, so it sees none of them.
    assert fields["correct_rate"] == pytest.approx(181 / 201, abs=1e-4)
    assert fields["rmse_xy_m"] == pytest.approx(0.0, abs=1e-9)


def test_a_kidnapping_to_the_place_a_method_already_held_is_marked_there_before():
    truth, odometry = kidnapped_line(jump_at=10.0)
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    stamps = truth.stamps
    # A look-alike method names the destination (3 m sideways) from 8 s on: wrong for 2 s, then "recovered" at once.
    outputs = truth.poses.copy()
    early = (stamps >= 8.0 - 1e-9) & (stamps < 10.0 - 1e-9)
    outputs[early, 1] += 3.0
    fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
    assert fields["kidnap_recovery_s"] == [0.0]
    assert fields["kidnap_at_destination_before"] == [True]
    # A method right before the jump that follows it at once found the destination: not marked.
    fields = metrics.evaluate_outputs(stamps, truth.poses, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
    assert fields["kidnap_recovery_s"] == [0.0]
    assert fields["kidnap_at_destination_before"] == [False]
    # No output before the jump: nothing to say.
    after = stamps >= 10.0 - 1e-9
    fields = metrics.evaluate_outputs(stamps[after], truth.poses[after], truth, first_input_stamp=0.0,
                                      kidnap_indices=kidnaps)
    assert fields["kidnap_at_destination_before"] == [None]


def test_kidnapping_never_recovered_gives_null():
    truth, odometry = kidnapped_line(jump_at=10.0)
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    outputs = odometry.poses  # never notices
    fields = metrics.evaluate_outputs(truth.stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
    assert fields["kidnap_recovery_s"] == [None]
    # Everything after an unrecovered jump is left out of the tracking RMSE (the failure is
    # the null above and the correct rate), so the RMSE sees only the perfect first 10 s.
    assert fields["correct_rate"] == pytest.approx(100 / 201, abs=1e-4)
    assert fields["rmse_xy_m"] == pytest.approx(0.0, abs=1e-9)


def test_rmse_leaves_out_a_long_recovery_but_not_the_tracking_after_it():
    truth, odometry = kidnapped_line(jump_at=5.0)
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    stamps = truth.stamps
    outputs, _ = old_place_until(truth, odometry, 5.0, 13.0)  # 8 s on the old place, longer than the 5 s minimum
    outputs[stamps >= 13.0 - 1e-9, 0] += 0.1  # then tracking 0.1 m off
    fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
    assert fields["kidnap_recovery_s"] == [pytest.approx(8.0, abs=SCAN_PERIOD)]
    # 50 outputs at 0 m before the jump, 71 at 0.1 m from 13 s to 20 s; the 8 s between are out.
    assert fields["rmse_xy_m"] == pytest.approx(0.1 * np.sqrt(71 / 121), abs=1e-3)


def test_the_shared_rmse_measures_every_run_over_the_stretch_none_of_them_leaves_out():
    truth, odometry = kidnapped_line(jump_at=5.0)
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    stamps = truth.stamps
    quick, _ = old_place_until(truth, odometry, 5.0, 6.0)  # recovered after 1 s: its window is the 5 s minimum
    quick[stamps >= 10.0 - 1e-9, 0] += 0.3  # 0.3 m off while its fresh fix settles, from 10 s to 13 s
    quick[stamps >= 13.0 - 1e-9, 0] -= 0.2  # then 0.1 m off
    slow, _ = old_place_until(truth, odometry, 5.0, 13.0)  # recovered after 8 s
    slow[stamps >= 13.0 - 1e-9, 0] += 0.1
    never = truth.poses + np.array([5.0, 0.0, 0.0])  # no fix at all
    runs, own = {}, {}
    for name, outputs in (("quick", quick), ("slow", slow), ("never", never)):
        fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
        own[name] = fields["rmse_xy_m"]
        runs[name] = metrics.RmseSample(stamps, fields["position_error_m"], fields["heading_error_rad"],
                                        fields["rmse_excluded"])
    # Each on its own outputs, the quick one looks worse: its own RMSE counts the settling the slow one leaves out.
    assert own["quick"] > 1.5 * own["slow"]
    shared = metrics.shared_rmse(runs)
    # Both over the 50 outputs before the jump and the 71 from 13 s on; the run without a fix takes no part.
    for name in ("quick", "slow"):
        assert shared[name]["shared_outputs"] == 121
        assert shared[name]["rmse_xy_m_shared"] == pytest.approx(0.1 * np.sqrt(71 / 121), abs=1e-3)
    assert shared["never"] == {"rmse_xy_m_shared": None, "rmse_theta_rad_shared": None, "shared_outputs": 0}
    assert metrics.shared_rmse({"slow": runs["slow"], "never": runs["never"]}) == {}


def test_no_output_gives_nulls_not_a_crash():
    truth, odometry = kidnapped_line()
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    fields = metrics.evaluate_outputs(np.zeros(0), np.zeros((0, 3)), truth, first_input_stamp=0.0,
                                      kidnap_indices=kidnaps)
    for key in ("time_to_first_fix_s", "correct_rate", "fine_rate", "rmse_xy_m", "rmse_theta_rad"):
        assert fields[key] is None
    assert fields["kidnap_recovery_s"] == [None]
    assert metrics.timing_fields([]) == {"update_ms_median": None, "update_ms_p95": None}


def test_fix_needs_three_correct_followers():
    truth = straight_line(duration=1.0)
    outputs = truth.poses.copy()
    outputs[[0, 2, 4], 0] += 2.0  # wrong at 0, 2 and 4: the first run of four correct starts at 5
    fields = metrics.evaluate_outputs(truth.stamps, outputs, truth, first_input_stamp=0.0)
    assert fields["time_to_first_fix_s"] == pytest.approx(0.5)
    correct = metrics.correct_mask(*metrics.pose_errors(outputs, truth.poses))
    assert metrics.first_fix_index(truth.stamps, correct) == 5
    assert metrics.first_fix_index(truth.stamps[:3], np.ones(3, dtype=bool)) is None  # too few outputs


def test_time_to_first_fix_counts_from_the_first_input():
    truth = straight_line(duration=5.0)
    outputs = truth.poses.copy()
    outputs[truth.stamps < 2.0 - 1e-9, 0] += 5.0
    fields = metrics.evaluate_outputs(truth.stamps, outputs, truth, first_input_stamp=-1.0)
    assert fields["time_to_first_fix_s"] == pytest.approx(3.0)  # fix at 2.0 s, first scan at -1.0 s
    assert fields["correct_rate"] == 1.0  # counted from the fix on


def test_interpolation_uses_the_unwrapped_heading():
    truth = metrics.Trajectory([0.0, 1.0], [[0.0, 0.0, np.pi - 0.1], [2.0, 4.0, -np.pi + 0.1]])
    middle = metrics.interpolate_poses(truth, [0.5])[0]
    assert middle[:2] == pytest.approx([1.0, 2.0])
    # Half-way through a 0.2 rad turn across +-pi is pi, not 0.
    assert abs(np.cos(middle[2]) + 1.0) < 1e-9
    # Outside the span by more than a period: no truth.
    assert np.isnan(metrics.interpolate_poses(truth, [3.0])).all()
    assert metrics.interpolate_poses(truth, [1.5])[0] == pytest.approx([2.0, 4.0, -np.pi + 0.1])


def test_interpolation_does_not_cross_a_kidnapping():
    truth = metrics.Trajectory([0.0, 1.0], [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    assert metrics.interpolate_poses(truth, [0.5], breaks=[1])[0][0] == 0.0  # the old pose holds until the jump
    assert metrics.interpolate_poses(truth, [0.5])[0][0] == pytest.approx(5.0)


def test_boxes_contain_checks_heading_modulo_two_pi():
    boxes = np.array([[[0.0, 1.0], [0.0, 1.0], [3.0, 3.5]]])  # theta interval reaches past pi
    assert metrics.boxes_contain(boxes, [0.5, 0.5, -3.0])  # -3.0 + 2 pi = 3.28 is inside
    assert not metrics.boxes_contain(boxes, [0.5, 0.5, 0.0])
    assert not metrics.boxes_contain(boxes, [1.5, 0.5, 3.2])
    assert metrics.boxes_contain(np.array([[[0, 1], [0, 1], [-10.0, 10.0]]]), [0.5, 0.5, 2.0])
    assert not metrics.boxes_contain(np.zeros((0, 3, 2)), [0.0, 0.0, 0.0])


def test_place_is_the_node_nearest_the_truth():
    nodes = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]])
    assert metrics.nearest_node_is_place([5.0, 0.0], nodes, [6.0, 1.0])
    assert not metrics.nearest_node_is_place([0.0, 0.0], nodes, [6.0, 1.0])


def test_recall_at_k_finds_the_rank_of_the_first_correct_candidate():
    truth = np.array([1.0, 1.0, 0.0])
    candidates = np.vstack([np.tile([9.0, 9.0, 0.0], (7, 1)), [1.2, 1.0, 0.1]])  # correct one at rank 8
    recall = metrics.recall_at_k(candidates, truth)
    assert recall == {1: False, 5: False, 10: True, 30: True, 50: True, 100: True}
    fields = metrics.evaluate_global_fixes([candidates[0], truth], [truth, truth], [2.0, 4.0],
                                           [recall, metrics.recall_at_k(truth[None], truth)])
    assert fields["global_correct_rate"] == 0.5
    assert fields["recall_at_k"]["1"] == 0.5 and fields["recall_at_k"]["10"] == 1.0
    assert fields["fix_ms_median"] == pytest.approx(3.0)


def test_trajectory_rejects_mismatched_lengths():
    with pytest.raises(ValueError, match="3 stamps but 2 poses"):
        metrics.Trajectory([0.0, 1.0, 2.0], np.zeros((2, 3)))


def test_containment_after_restart_leaves_out_kidnap_to_restart_only():
    from robot_localization_suite.core.metrics import outside_kidnap_until_restart

    stamps = np.arange(10.0)
    lost = np.zeros(10, dtype=bool)
    lost[6] = True  # the box list emptied at t = 6 s: the method restarts there
    keep = outside_kidnap_until_restart(stamps, lost, np.array([3.0]))
    # Outputs from the kidnapping (3 s) through the restart (6 s) are not judged; the rest are.
    assert keep.tolist() == [True, True, True, False, False, False, False, True, True, True]
    # A kidnapping never followed by a restart leaves everything after it unjudged.
    keep = outside_kidnap_until_restart(stamps, np.zeros(10, dtype=bool), np.array([8.0]))
    assert keep.tolist() == [True] * 8 + [False, False]
    # No kidnapping: every output counts.
    assert outside_kidnap_until_restart(stamps, lost, np.zeros(0)).all()


def test_recovery_counted_in_updates_and_among_candidates():
    truth, odometry = kidnapped_line(jump_at=10.0)
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    stamps = truth.stamps
    outputs, lost = old_place_until(truth, odometry, 10.0, 12.0)  # the pose names the old place for 20 updates
    # ...but from the jump on the truth is the second of the candidates (an ambiguous place).
    candidates = np.full((stamps.size, metrics.CANDIDATE_K, 3), np.nan)
    candidates[:, 0] = outputs
    candidates[lost, 1] = truth.poses[lost]
    fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps,
                                      candidates=candidates)
    assert fields["kidnap_recovery_updates"] == [21]
    assert fields["kidnap_candidate_recovery_updates"] == [1]
    # Candidates that never hold the truth do not count; without candidates there is no such field.
    candidates[lost, 1] = odometry.poses[lost] + [0.0, 1.0, 0.0]
    fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps,
                                      candidates=candidates)
    assert fields["kidnap_candidate_recovery_updates"] == [21]
    fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
    assert fields["kidnap_candidate_recovery_updates"] is None


# -- map coverage ------------------------------------------------------------------------------
def single_obstacle_map():
    """2 m x 2 m of free 5 cm cells, origin (0, 0), one occupied cell at (ix, iy) = (20, 20)."""
    from robot_localization_suite.core.grid_map import GridMap

    data = np.zeros((40, 40), dtype=np.int8)
    data[20, 20] = 100
    return GridMap(data, 0.05, (0.0, 0.0))


def centre(ix, iy) -> np.ndarray:
    """World coordinates of the centres of cells ``(ix, iy)`` (scalars or arrays) of that map."""
    return (np.stack([np.asarray(ix, float), np.asarray(iy, float)], axis=-1) + 0.5) * 0.05


def beams_to(laser_xy: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angles and ranges of beams from a laser at ``laser_xy`` with heading 0 ending at ``points``."""
    delta = points - laser_xy
    return np.arctan2(delta[:, 1], delta[:, 0]), np.hypot(delta[:, 0], delta[:, 1])


def test_map_coverage_counts_end_points_within_two_cells_of_the_occupied_cell():
    grid_map = single_obstacle_map()
    laser = centre(5, 20)
    # End points at cell centres, offset from the occupied cell (20, 20) by (dx, dy) cells:
    offsets = np.array([
        [0, 0],   # the cell itself: 0 m -> near
        [1, 1],   # diagonal neighbour: 0.071 m -> near
        [2, 0],   # two along x: 0.100 m -> near (the tolerance, inclusive)
        [0, -2],  # two along y: 0.100 m -> near
        [2, 1],   # 0.112 m -> not near
        [3, 0],   # 0.150 m -> not near
        [-10, 5], # free space far from it -> not near
    ])
    angles, ranges = beams_to(laser, centre(20 + offsets[:, 0], 20 + offsets[:, 1]))
    # Readings that are not hits are left out: no-return, NaN, at range_max; one hit lands off the map.
    off_map = np.hypot(*(np.array([2.5, 1.025]) - laser))
    angles = np.concatenate([angles, [0.0, 0.0, 0.0, 0.0]])
    ranges = np.concatenate([ranges, [np.inf, np.nan, 3.0, off_map]])
    coverage = metrics.map_coverage(grid_map, np.array([[*laser, 0.0]]), angles, ranges[None], range_max=3.0)
    assert coverage == pytest.approx([4 / 8])  # 4 near among 7 on-map hits + 1 off-map hit

    # The same end points seen from a laser turned by 90 degrees: the beam angles turn back.
    turned = metrics.map_coverage(grid_map, np.array([[*laser, np.pi / 2]]), angles - np.pi / 2, ranges[None],
                                  range_max=3.0)
    assert turned == pytest.approx(coverage)
    # A tolerance of zero keeps only the occupied cell itself.
    exact = metrics.map_coverage(grid_map, np.array([[*laser, 0.0]]), angles, ranges[None], range_max=3.0,
                                 tolerance=0.0)
    assert exact == pytest.approx([1 / 8])


def test_map_coverage_of_several_scans_in_one_call_and_a_scan_without_hits():
    grid_map = single_obstacle_map()
    laser = centre(5, 20)
    angles, ranges = beams_to(laser, np.array([centre(20, 20), centre(30, 30)]))  # one near, one not
    poses = np.array([[*laser, 0.0], [*laser, 0.0], [*laser, 0.0]])
    batch = np.vstack([ranges, [ranges[0], ranges[0]], [np.inf, np.inf]])
    per_scan_angles = np.vstack([angles, [angles[0], angles[0]], angles])  # (S, B): both beams of scan 2 near
    coverage = metrics.map_coverage(grid_map, poses, per_scan_angles, batch, range_max=np.array([3.0, 3.0, 3.0]))
    assert coverage[:2] == pytest.approx([0.5, 1.0])
    assert np.isnan(coverage[2])  # no hit at all: no coverage, not zero
    with pytest.raises(ValueError, match="2 poses but 3 scans"):
        metrics.map_coverage(grid_map, poses[:2], angles, batch, range_max=3.0)


def test_map_coverage_judges_one_scan_at_several_poses():
    # What a localizer asks: how much of this scan the map explains at each candidate pose.
    grid_map = single_obstacle_map()
    laser = centre(5, 20)
    angles, ranges = beams_to(laser, np.array([centre(20, 20), centre(30, 30)]))  # one near, one not
    poses = np.array([[*laser, 0.0], [*(laser + [0.0, 0.5]), 0.0]])  # the second shifts both ends 0.5 m away
    coverage = metrics.map_coverage(grid_map, poses, angles, ranges, range_max=3.0)
    assert coverage == pytest.approx([0.5, 0.0])
    stacked = metrics.map_coverage(grid_map, poses, angles, np.vstack([ranges, ranges]), range_max=3.0)
    assert stacked == pytest.approx(coverage)


def test_coverage_at_stamps_finds_each_output_scan_and_nothing_else():
    scan_stamps = np.array([1.0, 2.0, 3.0])
    coverage = np.array([0.9, 0.5, np.nan])
    found = metrics.coverage_at_stamps([2.0, 1.0 + 1e-4, 2.5, 3.0, 7.0], scan_stamps, coverage)
    assert found[:2] == pytest.approx([0.5, 0.9])
    assert np.isnan(found[2:]).all()  # between scans, a scan without coverage, after every scan


def test_coverage_rates_split_correct_outputs_by_coverage():
    correct = np.array([True, True, False, False, True, False])
    coverage = np.array([0.95, 0.8, 0.9, 0.3, 0.2, np.nan])
    rates = metrics.coverage_rates(correct, coverage)
    assert rates["outputs"] == 6 and rates["outputs_covered"] == 3  # 0.95, 0.8 (inclusive), 0.9
    assert rates["correct_rate"] == pytest.approx(0.5)
    assert rates["correct_rate_covered"] == pytest.approx(2 / 3, abs=1e-4)
    assert rates["correct_rate_uncovered"] == pytest.approx(0.5)  # 0.3 wrong, 0.2 right; NaN in neither
    assert rates["coverage_median"] == pytest.approx(0.8)
    empty = metrics.coverage_rates(np.zeros(0, bool), np.zeros(0))
    assert empty["correct_rate_covered"] is None and empty["coverage_median"] is None


def test_status_fields_count_every_output_and_only_localized_ones_can_be_falsely_localized() -> None:
    statuses = ["INITIALIZING", "AMBIGUOUS", "LOCALIZED", "LOCALIZED", "LOST", "LOCALIZED"]
    correct = [False, False, True, False, False, True]
    fields = metrics.status_fields(statuses, correct)
    assert fields == {"localized_outputs": 3, "localized_rate": 0.5, "false_localized_rate": 0.3333}
    assert metrics.status_fields(["AMBIGUOUS"], [False])["false_localized_rate"] is None
    with pytest.raises(ValueError, match="2 statuses but 1"):
        metrics.status_fields(["LOST", "LOST"], [True])


def test_false_localized_outside_kidnaps_leaves_out_the_unnoticed_kidnapping_only():
    truth, odometry = kidnapped_line(jump_at=5.0)
    kidnaps = metrics.detect_kidnappings(truth, odometry)
    stamps = truth.stamps
    outputs, _ = old_place_until(truth, odometry, 5.0, 13.0)  # 8 s on the old place, then the truth
    outputs[stamps >= 15.0 - 1e-9, 1] += 2.0  # and from 15 s a wrong fix of its own, 2 m off
    fields = metrics.evaluate_outputs(stamps, outputs, truth, first_input_stamp=0.0, kidnap_indices=kidnaps)
    status = metrics.status_fields(["LOCALIZED"] * len(stamps), fields["correct"], fields["recovering"])
    wrong = ~np.asarray(fields["correct"])
    assert status["false_localized_rate"] == pytest.approx(wrong.mean(), abs=1e-4)
    # Outside the window (before 5 s and from 13 s): the 2 m fix from 15 s is still counted.
    outside = (stamps < 5.0 - 1e-9) | (stamps >= 13.0 - 1e-9)
    assert status["false_localized_rate_outside_kidnaps"] == pytest.approx(wrong[outside].mean(), abs=1e-4)
    assert 0.0 < status["false_localized_rate_outside_kidnaps"] < status["false_localized_rate"]
    assert "false_localized_rate_outside_kidnaps" not in metrics.status_fields(["LOCALIZED"], [True])
