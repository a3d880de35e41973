"""The IR initialiser (core/ir*.py): patterns, the two-level index, steps 1 and 2, idf, cache, tracking, bad input.

A small hand-made floor (12 m x 9 m, rooms, doors, pillars) and coarse
settings (10 cm positions, 2-degree rays, 10-degree headings) keep the
precomputation to a few seconds.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from cache_damage import damaged

from robot_localization_suite.core import metrics
from robot_localization_suite.core.errors import CacheError, ScanError
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.ir.index import (
    FanModel,
    HitIndex,
    IndexSettings,
    IRIndex,
    _invert,
    candidate_positions,
    cast_fans,
    pattern_blocks,
)
from robot_localization_suite.core.ir.localizer import IRLocalizer, IRSettings
from robot_localization_suite.core.ir.patterns import NO_RETURN, extract_runs, pattern_terms
from robot_localization_suite.core.ir.query import LiveScan, step2_poses, suppress_duplicates
from robot_localization_suite.core.localizer import GlobalFixer, Localizer, LocalizerStatus
from robot_localization_suite.core.metrics import recall_at_k
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.scan import Scan
from robot_localization_suite.core.se2 import angle_difference, compose, relative, wrap_angle

RES = 0.05
SCAN_BEAMS = 181  # 180 degrees at 1 degree, as the Orebro log
SCAN_RANGE = 10.0


def floor_map() -> GridMap:
    """12 m x 9 m: three rooms off a corridor, doors, pillars and a box; nothing symmetric."""
    width, height = int(12 / RES), int(9 / RES)
    data = np.zeros((height, width), dtype=np.int8)

    def wall(x0: float, y0: float, x1: float, y1: float) -> None:
        data[int(y0 / RES) : max(int(y1 / RES), int(y0 / RES) + 1), int(x0 / RES) : max(int(x1 / RES), int(x0 / RES) + 1)] = 100

    wall(0, 0, 12, 0.1)
    wall(0, 8.9, 12, 9)
    wall(0, 0, 0.1, 9)
    wall(11.9, 0, 12, 9)
    wall(0, 3.0, 2.0, 3.1)  # corridor wall with doors
    wall(3.0, 3.0, 6.5, 3.1)
    wall(7.6, 3.0, 12, 3.1)
    wall(4.0, 3.0, 4.1, 9)  # room dividers
    wall(8.5, 3.0, 8.6, 6.0)
    wall(8.5, 7.2, 8.6, 9)
    wall(1.0, 6.0, 1.6, 6.6)  # pillar in room 1
    wall(6.0, 7.0, 7.2, 7.5)  # desk in room 2
    wall(10.0, 4.5, 10.4, 4.9)  # pillar in room 3
    wall(5.0, 1.2, 5.3, 1.5)  # pillar in the corridor
    wall(9.5, 0.8, 11.0, 1.0)  # bench in the corridor
    return GridMap(data, RES, (0.0, 0.0))


def settings(**changes: object) -> IRSettings:
    base = IRSettings(
        grid_resolution=0.1,
        angular_resolution=math.radians(2.0),
        heading_step=math.radians(10.0),
        min_clearance=0.15,
        step1_positions=150,
        refine_candidates=100,
        use_cache=False,
        progress=False,
        update_min_d=0.5,
        update_min_a=math.radians(20.0),
    )
    return replace(base, **changes)


def scan_at(grid_map: GridMap, pose: np.ndarray, *, noise: float = 0.0, rng: np.random.Generator | None = None,
            stamp: float = 0.0) -> Scan:
    angles = np.linspace(-math.pi / 2, math.pi / 2, SCAN_BEAMS)
    ranges = RayCaster(grid_map, max_range=SCAN_RANGE).cast(np.asarray(pose, float), angles).astype(np.float64)
    if noise and rng is not None:
        finite = np.isfinite(ranges)
        ranges[finite] += rng.normal(0.0, noise, finite.sum())
    return Scan(stamp, angles, ranges, 0.05, SCAN_RANGE)


@pytest.fixture(scope="module")
def world() -> GridMap:
    return floor_map()


@pytest.fixture(scope="module")
def localizer(world: GridMap) -> IRLocalizer:
    ir = IRLocalizer(settings(), world)
    ir.prepare(scan_at(world, np.array([2.0, 1.5, 0.0])))
    return ir


def _share_index(target: IRLocalizer, source: IRLocalizer) -> None:
    """Give ``target`` the map and the (costly) index of ``source`` without building them again."""
    target.grid_map = source.grid_map
    target.fixer.grid_map, target.fixer.index, target.fixer.field = source.grid_map, source.index, source.fixer.field
    target.fixer.evidence = source.fixer.evidence


def close(a: np.ndarray, b: np.ndarray, distance: float = 0.5, angle: float = math.radians(25.0)) -> bool:
    return bool(np.hypot(a[0] - b[0], a[1] - b[1]) <= distance and abs(angle_difference(a[2], b[2])) <= angle)


# -- patterns and hits ------------------------------------------------------------------------
def test_patterns_are_runs_between_no_returns_and_jumps_with_anchored_ends() -> None:
    # codes: a 4-beam run, a jump of 28 codes inside the next run, a no-return, a run to the edge
    codes = np.array([10, 10, 11, 12, NO_RETURN, 40, 41, 12, 13, NO_RETURN, 20, 21, 22], dtype=np.uint8)
    valid = np.ones(codes.size, dtype=bool)
    starts, lengths, anchors = extract_runs(codes, valid, cap_code=110, jump_codes=0, min_len=1, circular=False)
    # the first run starts at the edge of the view (no delimiter), the last one ends there
    assert starts.tolist() == [0, 5, 10] and lengths.tolist() == [4, 4, 3]
    assert anchors.tolist() == [2, 3, 1]
    starts, lengths, anchors = extract_runs(codes, valid, cap_code=110, jump_codes=10, min_len=1, circular=False)
    assert starts.tolist() == [0, 5, 7, 10] and lengths.tolist() == [4, 2, 2, 3]
    # on a full circle the edge run wraps around: 10..12 then 0..3
    starts, lengths, anchors = extract_runs(codes, valid, cap_code=110, jump_codes=0, min_len=1, circular=True)
    assert sorted(zip(starts.tolist(), lengths.tolist(), strict=True)) == [(5, 4), (10, 7)]
    # readings beyond the pattern range are no-returns for patterns; min_len drops short runs
    starts, _, _ = extract_runs(codes, valid, cap_code=30, jump_codes=0, min_len=3, circular=False)
    assert starts.tolist() == [0, 10]
    # nothing delimits a circle of hits: no pattern
    assert len(extract_runs(np.full(8, 30, np.uint8), np.ones(8, bool), cap_code=110, jump_codes=0, min_len=1,
                            circular=True)[0]) == 0


def test_a_first_level_hit_does_not_depend_on_the_heading(world: GridMap, localizer: IRLocalizer) -> None:
    from robot_localization_suite.core.ir.query import live_pattern_terms, resample_scan

    index = localizer.index
    assert index is not None
    pose = np.array([6.0, 5.0, 0.3])
    turned = pose + np.array([0.0, 0.0, math.radians(30.0)])
    terms_a, _ = live_pattern_terms(resample_scan(scan_at(world, pose), index.fan), index)
    terms_b, _ = live_pattern_terms(resample_scan(scan_at(world, turned), index.fan), index)
    # a pattern fully inside both views yields the same hits (both ends delimited)
    both = lambda terms: {tuple(t) for t in terms}  # noqa: E731
    assert both(terms_a) & both(terms_b)


def test_pattern_terms_count_from_each_delimited_end_only() -> None:
    codes = np.array([NO_RETURN, 10, 20, 30, NO_RETURN, 40, 50], dtype=np.uint8)
    valid = np.ones(codes.size, dtype=bool)
    valid[2] = False  # an invalid reading continues the run but yields no hit
    starts, lengths, anchors = extract_runs(codes, valid, cap_code=110, jump_codes=0, min_len=1, circular=False)
    terms = pattern_terms(codes, valid, starts, lengths, anchors, per_end=2, divisor=1, circular=False)
    bins = 255
    first, last = terms
    # run 1..3 is delimited on both sides: offsets 0, 1 from the start and from the end
    # (offset 1 from either end is the invalid reading: no hit)
    assert first.tolist() == [0 * bins + 10, (2 + 0) * bins + 30, -1, -1]
    # run 5..6 ends at the edge of the view: only hits counted from its start
    assert last.tolist() == [0 * bins + 40, 1 * bins + 50]


# -- the index ----------------------------------------------------------------------------------
def test_the_two_level_index_links_hits_to_patterns_to_positions(localizer: IRLocalizer) -> None:
    index = localizer.index
    assert index is not None
    hits = index.hit_patterns
    assert hits.term_count == index.term_count and hits.nnz > 0
    # patterns are deduplicated: the frequencies add up to the occurrences
    assert index.pattern_frequency.sum() == index.pattern_positions.sum()
    assert index.pattern_positions.shape == (hits.pattern_count, len(index.positions))
    # every position is a free cell away from walls
    assert np.all(localizer.grid_map.is_free(index.positions))
    assert index.fans.dtype == np.uint8 and index.fans.shape[1] == 180
    # which patterns a hit links to: every pattern of a position's fan, cut and hashed independently here,
    # is reached from its hits (level 1) by a pattern stored at that position (level 2), once per occurrence
    cols = index.pattern_positions.tocsc()
    checked = 0
    for p in np.random.default_rng(4).choice(len(index.positions), 25, replace=False):
        fan = index.fans[p]
        valid = np.ones(fan.size, dtype=bool)
        starts, lengths, anchors = extract_runs(fan, valid, cap_code=index.pattern_cap_code,
                                                jump_codes=index.jump_codes,
                                                min_len=index.settings.min_pattern_beams, circular=True)
        at_p = set(cols[:, p].nonzero()[0].tolist())
        assert cols[:, p].sum() == len(starts), p
        for terms in pattern_terms(fan, valid, starts, lengths, anchors, per_end=index.settings.pattern_terms_per_end,
                                   divisor=index.pattern_divisor, circular=True):
            linked = set.intersection(*(set(hits.row(int(t)).tolist()) for t in terms if t >= 0))
            assert linked & at_p, (p, terms)
            checked += 1
    assert checked > 25


def test_two_240_degree_views_cut_a_positions_patterns_at_the_view_edges_as_the_papers_scanner() -> None:
    """Paper IV-B-1: each position seen as two 240-degree views (0 and 180 degrees). One fan at 1 degree:
    a run at rays 70-90 lies inside both views, a run at rays 100-140 crosses the first view's edge (120)."""
    fan = FanModel(rays=360, max_range=10.0, range_resolution=0.05)
    codes = np.full((1, 360), NO_RETURN, dtype=np.uint8)
    codes[0, 70:91] = 100  # 5 m
    codes[0, 100:141] = np.linspace(40, 80, 41).astype(np.uint8)  # 2-4 m, a slanted wall
    positions = np.zeros((1, 2))
    base = settings(split_at_jump=0.0)
    circle = IRIndex.from_fans(positions, codes, fan, base.index_settings())
    views = IRIndex.from_fans(positions, codes, fan, replace(base, pattern_views="two_240").index_settings())
    # one circle: two patterns, each once
    assert circle.hit_patterns.pattern_count == 2 and circle.pattern_positions.sum() == 2
    # two views: the inner run twice (one pattern, frequency 2 at this position), the crossing run whole
    # (second view) and cut at 120 degrees, delimited at its start only (first view)
    assert views.hit_patterns.pattern_count == 3 and views.pattern_positions.sum() == 4
    assert sorted(views.pattern_positions.toarray().ravel().tolist()) == [1.0, 1.0, 2.0]
    per_end, bins = views.settings.pattern_terms_per_end, views.term_bins
    start_terms = [k * bins + int(codes[0, 100 + k]) // views.pattern_divisor for k in range(21)]  # rays 100-120
    end_terms = [(per_end + k) * bins + int(codes[0, 140 - k]) // views.pattern_divisor for k in range(per_end)]
    linked_start = [set(views.hit_patterns.row(t).tolist()) for t in start_terms]
    linked_end = [set(views.hit_patterns.row(t).tolist()) for t in end_terms]
    # the cut run and the whole one share their start's hits; only the whole one has the end's (past 120)
    assert all(len(linked) == 2 for linked in linked_start), linked_start
    whole = set.intersection(*linked_end)
    assert len(whole) == 1 and whole < linked_start[0]
    # a hit 21 beams in from the start (ray 121) is beyond the first view: the cut run stops before it
    assert (set(views.hit_patterns.row(21 * bins + int(codes[0, 121]) // views.pattern_divisor).tolist())
            == whole)


def test_two_views_still_find_a_noise_free_grid_pose(world: GridMap, localizer: IRLocalizer) -> None:
    views = IRLocalizer(settings(pattern_views="two_240"), world)
    views.prepare(scan_at(world, np.array([2.0, 1.5, 0.0])))
    for x, y, heading in GRID_POSES:
        pose = np.array([x, y, math.radians(heading)])
        estimate = views.global_fix(scan_at(world, pose))
        assert close(estimate.candidates[0], pose, 0.1, math.radians(3.0)), (pose, estimate.candidates[:3])


# Grid poses (positions on the 10 cm lattice, headings on the 10-degree steps) with a view that tells
# them apart: the pillar of room 1, the desk of room 2, the pillar of room 3, the corridor's pillar
# and bench, a doorway.
GRID_POSES = [
    (1.55, 5.05, 80.0),  # room 1 facing north: pillar ahead on the left
    (2.95, 7.45, 190.0),  # room 1 facing west along the top wall, pillar in view
    (6.45, 5.05, 60.0),  # room 2 facing the desk
    (10.75, 5.75, 250.0),  # room 3 facing south past its pillar
    (4.55, 1.95, 0.0),  # corridor facing east: pillar, then the bench far ahead
    (7.05, 2.45, 90.0),  # corridor facing the door of room 2
]


def test_a_noise_free_scan_at_a_grid_pose_comes_back_top_1(world: GridMap, localizer: IRLocalizer) -> None:
    index = localizer.index
    assert index is not None
    for x, y, heading in GRID_POSES:
        pose = np.array([x, y, math.radians(heading)])
        assert np.min(np.hypot(*(index.positions - pose[:2]).T)) < 1e-6, "the pose is on the position grid"
        estimate = localizer.global_fix(scan_at(world, pose))
        assert "fallback" not in estimate.details, estimate.details
        assert close(estimate.candidates[0], pose, 0.1, math.radians(3.0)), (pose, estimate.candidates[:3])
        assert estimate.candidates.shape[1] == 3 and len(estimate.candidates) <= localizer.settings.max_candidates
        assert estimate.status is LocalizerStatus.AMBIGUOUS and np.allclose(estimate.pose, estimate.candidates[0])


def test_the_papers_ranking_alone_also_puts_a_noise_free_grid_pose_first(world: GridMap, localizer: IRLocalizer) -> None:
    # nms_angle stays at its default: nms_distance = 0 alone must keep every pose of step 2's list
    paper = IRLocalizer(settings(refine_candidates=0, nms_distance=0.0), None)
    no_angle = IRLocalizer(settings(refine_candidates=0, nms_distance=0.0, nms_angle=0.0), None)
    _share_index(paper, localizer)
    _share_index(no_angle, localizer)
    turned_neighbours = 0
    index = localizer.index
    assert index is not None
    angle, distance = paper.settings.nms_angle, IRSettings().nms_distance
    assert angle > 0.0 and distance > 0.0
    for x, y, heading in GRID_POSES:
        pose = np.array([x, y, math.radians(heading)])
        estimate = paper.global_fix(scan_at(world, pose))
        # unrefined: the candidate is a grid pose itself; the true one or a neighbour
        assert close(estimate.candidates[0], pose, 0.15, math.radians(10.5)), (pose, estimate.candidates[:3])
        # nothing suppressed: the same list as with no angle at all, and it holds the best pose's grid
        # neighbours (next position or next heading) that the default suppression drops
        assert np.array_equal(estimate.candidates, no_angle.global_fix(scan_at(world, pose)).candidates)
        best = estimate.candidates[0]
        near = np.hypot(*(estimate.candidates[1:, :2] - best[:2]).T) <= distance
        turn = np.abs(angle_difference(estimate.candidates[1:, 2], best[2]))
        assert np.any(near & (turn <= angle)), (pose, estimate.candidates[:5])
        turned_neighbours += int(np.any(near & (turn > 0.0) & (turn <= angle)))
    assert turned_neighbours > 0, "no list held a turned neighbour: the test would not see the angle"


def test_nms_distance_zero_keeps_every_pose_whatever_the_angle() -> None:
    # three headings at one position, 5 degrees apart, and one pose 0.1 m away
    poses = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, math.radians(5.0)], [1.0, 1.0, math.radians(10.0)],
                      [1.1, 1.0, 0.0]])
    for angle in (0.0, math.radians(15.0), math.pi):
        assert suppress_duplicates(poses, distance=0.0, angle=angle, limit=10).tolist() == [0, 1, 2, 3]
    assert suppress_duplicates(poses, distance=0.0, angle=math.pi, limit=2).tolist() == [0, 1]
    # with a distance, the angle decides: within 15 degrees of the first -> dropped
    assert suppress_duplicates(poses, distance=0.3, angle=math.radians(15.0), limit=10).tolist() == [0]
    assert suppress_duplicates(poses, distance=0.3, angle=math.radians(7.0), limit=10).tolist() == [0, 2]
    assert suppress_duplicates(poses, distance=0.05, angle=math.radians(7.0), limit=10).tolist() == [0, 2, 3]


@pytest.mark.parametrize("initial_particles", ["one_per_candidate", "rank"])
def test_an_initialisation_puts_one_particle_on_each_candidate_or_draws_them_by_rank(
    world: GridMap, localizer: IRLocalizer, initial_particles: str
) -> None:
    count = 40
    ir = IRLocalizer(settings(initial_particles=initial_particles, particle_count=count, max_candidates=count), None)
    _share_index(ir, localizer)
    x, y, heading = GRID_POSES[2]
    estimate = ir.on_scan(scan_at(world, np.array([x, y, math.radians(heading)])))
    assert estimate is not None and ir.particles is not None and len(estimate.candidates) == count
    on = [int(np.sum(np.all(np.isclose(ir.particles, c), axis=1))) for c in estimate.candidates]
    if initial_particles == "one_per_candidate":
        assert on == [1] * count  # paper IV-D: each found pose is a particle, no copies
    else:
        assert on[0] == 1 and sum(on) < count  # the first is drawn several times, its copies spread
        spread = np.hypot(*(ir.particles[:, :2] - estimate.candidates[0, :2]).T) <= 0.5 * ir.index.grid_step * 1.5
        assert spread.sum() > 3


def test_noisy_scans_off_the_grid_are_found_within_the_papers_tolerance(world: GridMap, localizer: IRLocalizer) -> None:
    # continuous poses, 2 cm range noise; correct = 0.5 m and 25 degrees (the paper's criterion)
    rng = np.random.default_rng(7)
    poses = world.sample_free_poses(400, rng)
    cells = world.world_to_cell(poses[:, :2])
    poses = poses[world.distance_field()[cells[:, 1], cells[:, 0]] > 0.3][:30]
    recalls = [recall_at_k(localizer.global_fix(scan_at(world, p, noise=0.02, rng=rng)).candidates, p, (1, 10))
               for p in poses]
    # this floor repeats itself (corridor ends, bare room corners): measured 0.80 / 1.00 here
    assert np.mean([r[1] for r in recalls]) >= 0.65
    assert np.mean([r[10] for r in recalls]) >= 0.9


def test_a_place_step_1_missed_is_found_by_the_wide_search(
    world: GridMap, localizer: IRLocalizer, monkeypatch: pytest.MonkeyPatch
) -> None:
    # On a partial map step 1 can miss the place (the scan's pattern ends are not the map's): here it is
    # made to miss by dropping every position within 2 m of the truth from its answer.
    from robot_localization_suite.core.ir import global_fix

    pose = np.array([6.0, 5.0, 0.3])
    scan = scan_at(world, pose)
    found = localizer.global_fix(scan)
    assert close(found.candidates[0], pose, 0.2) and "wide_search_positions" not in found.details  # explained: no search
    step1 = global_fix.step1_positions

    def missing_the_place(index: IRIndex, terms: list[np.ndarray], **kwargs: object) -> tuple[np.ndarray, np.ndarray]:
        ids, scores = step1(index, terms, **kwargs)  # type: ignore[arg-type]
        away = np.hypot(*(index.positions[ids] - pose[:2]).T) > 2.0
        return ids[away], scores[away]

    monkeypatch.setattr(global_fix, "step1_positions", missing_the_place)
    narrow = IRLocalizer(settings(wide_search_below=0.0), None)
    _share_index(narrow, localizer)
    assert not close(narrow.global_fix(scan).candidates[0], pose)
    wide = localizer.global_fix(scan)
    assert wide.details["wide_search_positions"] > 0
    assert close(wide.candidates[0], pose, 0.2, math.radians(5.0))
    # a lattice coarser than the refinement can close (here 0.2 m apart, 2 x 0.05 m reach) is not searched
    short_reach = IRLocalizer(settings(refine_max_shift=0.05), None)
    _share_index(short_reach, localizer)
    assert "wide_search_positions" not in short_reach.global_fix(scan).details


def test_patterns_end_at_the_sensors_range_so_a_hall_whose_walls_are_all_far_is_placed_from_its_patterns() -> None:
    """The paper's 5.5 m was its laser's range (II): with that figure on a longer-range sensor every far reading is a
    no-return, and a place seen only beyond 5.5 m has no pattern (the campus: 0.23 correct against 0.59)."""
    width, height = int(20 / RES), int(14 / RES)
    data = np.zeros((height, width), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    for x, y, size in ((4.0, 3.0, 0.6), (15.5, 10.5, 0.4), (16.0, 2.5, 1.0), (3.5, 11.0, 0.3), (12.0, 12.5, 0.8)):
        data[int(y / RES) : int((y + size) / RES), int(x / RES) : int((x + size) / RES)] = 100
    hall = GridMap(data, RES, (0.0, 0.0))
    pose = np.array([10.0, 6.0, math.radians(60.0)])
    scan = scan_at(hall, pose)
    assert np.nanmin(scan.ranges) > 5.5, "every reading of the test scan lies beyond the paper's 5.5 m"
    sensors_range = IRLocalizer(settings(), hall)
    sensors_range.prepare(scan)
    estimate = sensors_range.global_fix(scan)
    assert "fallback" not in estimate.details, estimate.details
    assert close(estimate.candidates[0], pose, 0.2, math.radians(5.0)), estimate.candidates[:3]
    papers = IRLocalizer(settings(pattern_max_range=5.5), hall)
    papers.prepare(scan)
    assert "no pattern" in papers.global_fix(scan).details["fallback"]


def test_a_place_whose_walls_a_scan_would_see_through_ranks_below_the_true_one() -> None:
    # Two identical rooms; the second has a pillar. A scan taken in the first room ends on the second
    # room's walls as well from the same spot there, but some of its beams would pass through the pillar.
    data = np.zeros((int(4 / RES), int(10 / RES)), dtype=np.int8)
    for x0 in (0.5, 5.5):
        ix0, ix1, iy0, iy1 = int(x0 / RES), int((x0 + 4.0) / RES), int(0.5 / RES), int(3.5 / RES)
        data[iy0 : iy1 + 2, [ix0, ix0 + 1, ix1, ix1 + 1]] = 100
        data[[iy0, iy0 + 1, iy1, iy1 + 1], ix0 : ix1 + 2] = 100
    data[int(1.8 / RES) : int(2.2 / RES), int(8.0 / RES) : int(8.4 / RES)] = 100  # the pillar
    rooms = GridMap(data, RES, (0.0, 0.0))
    truth, twin = np.array([1.5, 2.0, 0.0]), np.array([6.5, 2.0, 0.0])
    scan = scan_at(rooms, truth)
    ir = IRLocalizer(settings(), rooms)
    ir.prepare(scan)
    blind = ir.fixer.variant(replace(ir.settings, see_through_margin=0.0))
    at_truth, at_twin = blind.refined_scores(scan, np.vstack([truth, twin]))
    assert abs(at_truth - at_twin) < 0.01  # by its end points alone the twin explains the scan as well
    at_truth, at_twin = ir.fixer.refined_scores(scan, np.vstack([truth, twin]))
    assert at_truth - at_twin > 0.05
    assert close(ir.global_fix(scan).candidates[0], truth, 0.2)


def _hand_index(fans: np.ndarray) -> IRIndex:
    """An index over hand-made fans (no map): step 2 reads only positions and fans."""
    count = len(fans)
    terms = 2 * IRSettings().pattern_terms_per_end * (254 // 2 + 1)  # 10 cm bins of 5 cm codes
    return IRIndex(
        positions=np.column_stack([np.arange(count, dtype=float), np.zeros(count)]),
        fans=fans.astype(np.uint8),
        fan=FanModel(rays=fans.shape[1], max_range=10.0, range_resolution=0.05),
        settings=IRSettings().index_settings(),
        hit_patterns=HitIndex(np.zeros(terms + 1, np.int64), np.zeros(0, np.uint16), 0),
        pattern_positions=sp.csr_matrix((0, count), dtype=np.float32),
        pattern_frequency=np.zeros(0, dtype=np.int64),
    )


def test_idf_ranks_the_right_pose_above_a_decoy_that_shares_the_common_patterns() -> None:
    x = NO_RETURN
    live_codes = np.array([10, 20, 30, 30, 30, 30, 40, 50], dtype=np.uint8)
    fans = np.array(
        [
            [10, 20, 99, 99, 99, 99, 40, 50],  # the true position: 4 hits, three of them held by no other pose
            [10, 99, 30, 30, 30, 30, 99, 99],  # decoy: 5 hits, all common
            *[[99, 99, 30, 30, 30, 30, x, 99]] * 6,  # the corridor-like rest: the common 30s
        ]
    )
    live = LiveScan(
        codes=live_codes,
        valid=np.ones(8, dtype=bool),
        offsets=np.arange(8, dtype=float),
        angles=np.arange(8) * (2 * math.pi / 8),
        ranges=live_codes * 0.05,
        circular=True,
    )
    index = _hand_index(fans)
    common = dict(heading_count=1, range_bin=0.05, tolerance_bins=0, no_return_terms=False)
    counted, count_scores = step2_poses(index, live, np.arange(len(fans)), use_idf=False, **common)
    weighted, idf_scores = step2_poses(index, live, np.arange(len(fans)), use_idf=True, **common)
    assert counted[0][0] == 1.0 and count_scores[0] == 5  # plain counting prefers the decoy
    assert weighted[0][0] == 0.0  # idf: rare hits outweigh common ones
    # the paper's weight: indexed poses / poses holding the hit; beam 1 is held by pose 0 only
    assert idf_scores[0] == pytest.approx(8 / 2 + 8 + 8 + 8)


# -- large maps: memory -------------------------------------------------------------------------
def _campus_size_map() -> GridMap:
    """5,200 x 5,500 cells at 5 cm (the Freiburg campus map's size): streets 4 m wide every 40 m
    between unknown blocks, walls on both sides, pillars along them."""
    data = np.full((5200, 5500), -1, dtype=np.int8)
    for start in range(200, 5200, 800):
        data[start : start + 80, 100:5400] = 0
        data[start : start + 2, 100:5400] = data[start + 78 : start + 80, 100:5400] = 100
        data[start + 30 : start + 34, 300:5400:137] = 100
    for start in range(200, 5500, 800):
        data[100:5100, start : start + 80] = 0
        data[100:5100, start : start + 2] = data[100:5100, start + 78 : start + 80] = 100
    return GridMap(data, RES, (-30.0, -180.0))


def test_the_blocked_hit_index_keeps_every_link_past_65536_patterns() -> None:
    """Pattern ids beyond 16 bits: each hit's row is stored block by block as 16-bit offsets."""
    rng = np.random.default_rng(2)
    pattern_count, terms_per_pattern, term_count = 70_000 * 3, 3, 500
    terms = rng.integers(0, term_count, size=pattern_count * terms_per_pattern).astype(np.uint16)
    offsets = np.arange(pattern_count + 1, dtype=np.int64) * terms_per_pattern
    blocks = pattern_blocks(pattern_count)
    indptr, patterns = _invert(offsets, terms, term_count, blocks)
    hits = HitIndex(indptr, patterns, pattern_count, blocks)
    assert blocks == 4 and hits.patterns.dtype == np.uint16 and hits.nbytes == 2 * len(terms) + 8 * (term_count * 4 + 1)
    expected = sp.csr_matrix(
        (np.ones(len(terms), dtype=np.float32), (terms.astype(np.int64), np.repeat(np.arange(pattern_count), terms_per_pattern))),
        shape=(term_count, pattern_count),
    )
    expected.sum_duplicates()
    expected.data[:] = 1.0
    got = hits.as_csr()
    got.sum_duplicates()
    got.data[:] = 1.0
    assert (got != expected).nnz == 0
    # Every link, a pattern holding the hit twice twice, ids ascending.
    assert np.array_equal(hits.row(7), np.repeat(np.arange(pattern_count), terms_per_pattern)[terms == 7])


def test_a_campus_size_index_stays_within_its_budget_and_is_memory_mapped_past_it(tmp_path: Path) -> None:
    """A map of the campus's 28.6 million cells: the lattice is widened to ``max_positions``, the
    index holds about one byte a precomputed ray, the map-sized fields are not made by the build,
    and past ``index_memory_mb`` the index is read from its cache file, with the same answers."""
    campus = _campus_size_map()
    limit = 20_000
    base = settings(max_positions=limit, grid_resolution=0.05, use_cache=True, cache_dir=str(tmp_path),
                    step1_positions=80, refine_candidates=40)
    scan = scan_at(campus, np.array([-10.0, -168.0, 0.3]))
    in_memory = IRLocalizer(replace(base, index_memory_mb=1e6), campus)
    in_memory.prepare(scan)
    index = in_memory.index
    assert index is not None and not index.memory_mapped
    rays = index.fan.rays
    # The lattice: widened from 5 cm until at most max_positions remain, all in free cells.
    assert 0.5 * limit < len(index.positions) <= limit and index.grid_step > 0.05
    assert campus.is_free(index.positions).all()
    # Compact arrays: a byte a precomputed ray, 16-bit hit links, 32-bit ids and counts.
    assert index.fans.dtype == np.uint8 and index.fans.shape == (len(index.positions), rays)
    assert index.hit_patterns.patterns.dtype == np.uint16
    assert index.pattern_positions.indices.dtype == np.int32 and index.pattern_positions.data.dtype == np.float32
    assert index.pattern_frequency.dtype == np.int32
    # All of it: the rays, the positions, and a few bytes per pattern occurrence and hit link.
    occurrences = int(index.pattern_frequency.sum())
    budget = len(index.positions) * (rays + 16) + 12 * occurrences + 2 * index.hit_patterns.nnz
    budget += index.hit_patterns.indptr.nbytes + 8 * (index.pattern_positions.shape[0] + 1)
    assert index.nbytes() <= budget
    # At the default max_positions and 1 degree rays that is at most ~0.3 GB on any map.
    assert IRSettings().max_positions * (360 + 16 + 12 * occurrences / len(index.positions)) < 0.5e9
    # The map-sized distance field and score evidence are made at the first fix, not with the index.
    assert in_memory.fixer._field is None and in_memory.fixer._evidence is None
    before = in_memory.global_fix(scan)

    mapped = IRLocalizer(replace(base, index_memory_mb=0.5), campus)
    mapped.prepare(scan)
    assert mapped.index is not None and mapped.index.memory_mapped and mapped.index.build_seconds == 0.0
    assert isinstance(mapped.index.fans, np.memmap)  # arrays of 1 MB and more are mapped
    after = mapped.global_fix(scan)
    np.testing.assert_array_equal(before.candidates, after.candidates)
    np.testing.assert_array_equal(before.candidate_weights, after.candidate_weights)


# -- cache --------------------------------------------------------------------------------------
def test_a_reloaded_cache_gives_identical_rankings(world: GridMap, tmp_path: Path) -> None:
    cached = settings(use_cache=True, cache_dir=str(tmp_path), step1_positions=80, refine_candidates=40)
    first = IRLocalizer(cached, world)
    scans = [scan_at(world, np.array(p)) for p in ([2.0, 1.5, 0.4], [6.3, 5.2, 2.0], [10.2, 7.0, -1.0])]
    before = [first.global_fix(s) for s in scans]
    assert first.index is not None and first.index.build_seconds > 0.0
    assert first.index.cache_path is not None and first.index.cache_path.is_file()
    assert first.index.cache_path.parent.parent == tmp_path
    second = IRLocalizer(cached, world)
    after = [second.global_fix(s) for s in scans]
    assert second.index is not None and second.index.build_seconds == 0.0  # loaded, not rebuilt
    for a, b in zip(before, after, strict=True):
        np.testing.assert_array_equal(a.candidates, b.candidates)
        np.testing.assert_array_equal(a.candidate_weights, b.candidate_weights)


def test_a_corrupt_cache_is_rebuilt_after_one_warning_naming_it(world: GridMap, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    cached = settings(use_cache=True, cache_dir=str(tmp_path), step1_positions=80, refine_candidates=40)
    scan = scan_at(world, np.array([6.3, 5.2, 2.0]))
    reference = IRLocalizer(cached, world).global_fix(scan)
    path = next((tmp_path / "ir").glob("*.npz"))
    for how, damage in damaged(path.read_bytes()).items():
        path.write_bytes(damage)
        with pytest.raises(CacheError, match="unreadable"):
            IRIndex.load(path, IRLocalizer(cached, None).settings.fan_model(math.radians(1.0), SCAN_RANGE),
                         cached.index_settings())
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            rebuilt = IRLocalizer(cached, world)
            estimate = rebuilt.global_fix(scan)
        warnings = [record.getMessage() for record in caplog.records if record.levelno >= logging.WARNING]
        assert len(warnings) == 1 and str(path) in warnings[0] and "rebuilding" in warnings[0], (how, warnings)
        assert rebuilt.index is not None and rebuilt.index.build_seconds > 0.0
        np.testing.assert_array_equal(estimate.candidates, reference.candidates)
        # and the rebuilt file is good again
        assert IRIndex.load(path, rebuilt.index.fan, cached.index_settings()).fans.shape == rebuilt.index.fans.shape


def test_the_cache_key_follows_the_map_and_the_settings(world: GridMap) -> None:
    fan = FanModel(rays=180, max_range=10.0, range_resolution=0.05)
    defaults = IRSettings().index_settings()
    key = IRIndex.cache_key(world, fan, defaults)
    assert key == IRIndex.cache_key(world, fan, IRSettings().index_settings())
    assert key != IRIndex.cache_key(world, fan, replace(defaults, split_at_jump=0.0))
    assert key != IRIndex.cache_key(world, replace(fan, rays=360), defaults)
    moved = GridMap(world.data, world.resolution, (1.0, 0.0))
    assert key != IRIndex.cache_key(moved, fan, defaults)
    # the same map from /map (float32 resolution) shares the fingerprint but casts differently: its own index
    from_topic = GridMap(world.data, float(np.float32(world.resolution)), world.origin)
    assert from_topic.fingerprint() == world.fingerprint() and from_topic.resolution != world.resolution
    assert key != IRIndex.cache_key(from_topic, fan, defaults)


def test_an_index_cached_by_other_code_is_not_read_as_this_codes(world: GridMap, localizer: IRLocalizer,
                                                                  tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Another commit (or a scratch worktree sharing the cache directory) built the file: same map, fan and
    # settings, other ray caster. Its key and its stored meta name other code, so this code rebuilds.
    from robot_localization_suite.core.ir import index as index_module

    built = localizer.index
    key = IRIndex.cache_key(world, built.fan, built.settings)
    path = tmp_path / f"{key}.npz"
    built.save(path)
    assert IRIndex.load(path, built.fan, built.settings).fans.shape == built.fans.shape
    monkeypatch.setattr(index_module, "source_digest", lambda *modules: "other-code")
    assert IRIndex.cache_key(world, built.fan, built.settings) != key
    with pytest.raises(CacheError, match="other settings"):
        IRIndex.load(path, built.fan, built.settings)


def test_index_settings_come_from_ir_settings_and_only_index_parameters_change_the_key(world: GridMap) -> None:
    with pytest.raises(TypeError):
        IndexSettings()  # no second set of defaults to drift from IRSettings'
    fan = FanModel(rays=180, max_range=10.0, range_resolution=0.05)
    base = IRSettings()
    key = IRIndex.cache_key(world, fan, base.index_settings())
    changed = {
        "grid_resolution": 0.1,
        "max_positions": 1000,
        "min_clearance": 0.3,
        "unknown_blocks": True,
        "pattern_max_range": 4.0,
        "pattern_range_bin": 0.2,
        "pattern_terms_per_end": 12,
        "min_pattern_beams": 5,
        "split_at_jump": 0.0,
        "pattern_views": "two_240",
    }
    assert set(changed) == {f.name for f in fields(IndexSettings)}
    for name, value in changed.items():
        assert getattr(base, name) != value
        index_settings = replace(base, **{name: value}).index_settings()
        assert getattr(index_settings, name) == value
        assert IRIndex.cache_key(world, fan, index_settings) != key, name
    # query and tracking settings leave the index (and its cache file) alone
    for name, value in {"particle_count": 50, "heading_step": math.radians(10.0), "use_idf": False, "progress": False}.items():
        assert IRIndex.cache_key(world, fan, replace(base, **{name: value}).index_settings()) == key, name


def test_writing_an_index_prunes_the_least_recently_used_ones_beyond_the_budget(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = np.zeros((40, 60), dtype=np.int8)  # a 3 m x 2 m room with a pillar: a small, fast index
    data[[0, -1], :] = data[:, [0, -1]] = 100
    data[15:20, 20:25] = 100
    room = GridMap(data, RES, (0.0, 0.0))
    fan = FanModel(rays=90, max_range=5.0, range_resolution=0.05)
    index_settings = replace(settings(), grid_resolution=0.2).index_settings()
    directory = tmp_path / "ir"
    directory.mkdir()
    stale = []
    for number in range(3):  # indexes of other maps, last used long ago (oldest first)
        stale.append(directory / f"other{number}.npz")
        stale[-1].write_bytes(b"x" * 2**20)  # 1 MB each
        os.utime(stale[-1], (1000.0 + number, 1000.0 + number))
    with caplog.at_level(logging.INFO, logger="robot_localization_suite.core.ir.index"):
        index = IRIndex.load_or_build(room, fan, index_settings, cache_dir=tmp_path, progress=False,
                                      cache_budget_mb=1.5)
    written = index.cache_path
    assert written is not None and written.is_file() and written.stat().st_size < 0.4 * 2**20
    # 3 MB + the new index (< 0.4 MB) over a 1.5 MB budget: the two oldest files go, never the one just written
    assert [path.exists() for path in stale] == [False, False, True]
    assert sum(f"deleted the least recently used {path}" in caplog.text for path in stale) == 2
    # a cache hit counts as a use: the loaded index outlives a newer file at the next pruning
    os.utime(written, (2000.0, 2000.0))
    os.utime(stale[2], (3000.0, 3000.0))
    assert IRIndex.load_or_build(room, fan, index_settings, cache_dir=tmp_path, progress=False).build_seconds == 0.0
    other = IRIndex.load_or_build(room, fan, replace(index_settings, split_at_jump=0.0), cache_dir=tmp_path,
                                  progress=False, cache_budget_mb=0.9)
    # 1 MB + two indexes (< 0.4 MB each) over 0.9 MB: the file unused longest goes, and that is the 1 MB one now
    assert other.cache_path is not None and other.cache_path != written
    assert sorted(directory.iterdir()) == sorted([written, other.cache_path])


@pytest.mark.parametrize(("tqdm_disable", "progress", "shown"),
                         [(None, True, True), ("1", True, False), (None, False, False), ("0", True, True)])
def test_the_precomputation_bar_follows_the_setting_unless_tqdm_disable_is_set(
    tqdm_disable: str | None, progress: bool, shown: bool, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # rls_bench's child runs set TQDM_DISABLE=1; an interactive run (unset) shows the bar when progress is on
    if tqdm_disable is None:
        monkeypatch.delenv("TQDM_DISABLE", raising=False)
    else:
        monkeypatch.setenv("TQDM_DISABLE", tqdm_disable)
    data = np.zeros((20, 20), dtype=np.int8)
    data[[0, -1], :] = data[:, [0, -1]] = 100
    room = GridMap(data, RES, (0.0, 0.0))
    positions = candidate_positions(room, 0.1, 0.0)
    cast_fans(room, positions, FanModel(rays=16, max_range=2.0, range_resolution=0.05), progress=progress)
    assert ("IR ray fans" in capsys.readouterr().err) == shown


# -- bad input ----------------------------------------------------------------------------------
def test_a_scan_with_no_pattern_returns_no_candidates_and_says_why(world: GridMap, localizer: IRLocalizer) -> None:
    angles = np.linspace(-math.pi / 2, math.pi / 2, SCAN_BEAMS)
    nothing = Scan(1.0, angles, np.full(SCAN_BEAMS, np.inf), 0.05, SCAN_RANGE)
    estimate = localizer.global_fix(nothing)
    assert len(estimate.candidates) == 0 and estimate.status is LocalizerStatus.LOST
    assert "every reading is a no-return" in estimate.details["reason"]
    invalid = Scan(1.0, angles, np.full(SCAN_BEAMS, np.nan), 0.05, SCAN_RANGE)
    assert "no valid reading" in localizer.global_fix(invalid).details["reason"]
    # a wall at one range everywhere, nothing delimiting it: no pattern, step 2 over a coarse lattice instead
    flat = Scan(1.0, angles, np.full(SCAN_BEAMS, 2.0), 0.05, SCAN_RANGE)
    assert "no pattern" in localizer.global_fix(flat).details["fallback"]
    strict = IRLocalizer(settings(fallback_positions=0), None)
    _share_index(strict, localizer)
    refused = strict.global_fix(flat)
    assert len(refused.candidates) == 0 and "no delimiting no-return" in refused.details["reason"]
    # the tracker refuses the same scan with the reason (the adapter logs it and skips the scan) ...
    fresh = IRLocalizer(settings(), None)
    _share_index(fresh, localizer)
    with pytest.raises(ScanError, match="every reading is a no-return"):
        fresh.on_scan(nothing)
    assert not fresh.initialized
    # ... and, once tracking, keeps its particles when a scan has no hit to score them with
    fresh.set_initial_pose(np.array([6.0, 5.0, 0.5]), np.diag([0.01, 0.01, 0.01]))
    before = fresh.particles.copy()
    fresh.request_nomotion_update()
    with pytest.raises(ScanError, match="no hit"):
        fresh.on_scan(nothing)
    np.testing.assert_array_equal(fresh.particles, before)


def test_invalid_readings_are_skipped(world: GridMap, localizer: IRLocalizer) -> None:
    pose = np.array([2.5, 5.0, 1.0])
    scan = scan_at(world, pose)
    ranges = scan.ranges.copy()
    ranges[::7] = np.nan
    ranges[3::11] = -1.0
    ranges[5::13] = 0.01  # below range_min
    damaged = Scan(scan.stamp, scan.angles, ranges, scan.range_min, scan.range_max)
    estimate = localizer.global_fix(damaged)
    assert close(estimate.candidates[0], pose, 0.2, math.radians(5.0))


def test_settings_refuse_bad_values_naming_them() -> None:
    with pytest.raises(ValueError, match="grid_resolution"):
        IRSettings(grid_resolution=0.0)
    with pytest.raises(ValueError, match="particle_count"):
        IRSettings(particle_count=0)
    with pytest.raises(ValueError, match="lost_score_threshold"):
        IRSettings(lost_score_threshold=1.5)
    with pytest.raises(ValueError, match="pattern_range_bin"):
        IRSettings(pattern_range_bin=0.01)
    with pytest.raises(ValueError, match="max_range"):
        FanModel(rays=360, max_range=20.0, range_resolution=0.05)  # beyond one-byte codes


# -- tracking -----------------------------------------------------------------------------------
def _drive(world: GridMap, waypoints: list[tuple[float, float]], step: float = 0.2) -> np.ndarray:
    """Poses every ``step`` metres along straight legs between waypoints, heading along the leg."""
    poses = []
    for (x0, y0), (x1, y1) in zip(waypoints[:-1], waypoints[1:], strict=True):
        length = math.hypot(x1 - x0, y1 - y0)
        heading = math.atan2(y1 - y0, x1 - x0)
        for s in np.arange(0.0, length, step):
            poses.append([x0 + s * math.cos(heading), y0 + s * math.sin(heading), heading])
    return np.array(poses)


def _run(localizer: Localizer, world: GridMap, truth: np.ndarray, rng: np.random.Generator, odom_origin: np.ndarray,
         odom_truth: np.ndarray | None = None) -> list:
    """Feed odometry (truth in another frame, 2 % noise on each step) and noisy scans; the estimates."""
    odom_truth = truth if odom_truth is None else odom_truth
    odom = odom_origin.copy()
    estimates = []
    for k in range(len(truth)):
        if k:
            step = relative(odom_truth[k - 1], odom_truth[k])
            step[:2] *= 1.0 + rng.normal(0.0, 0.02)
            step[2] += rng.normal(0.0, 0.01)
            odom = compose(odom, step)
        localizer.on_odometry(0.1 * k, odom)
        estimates.append(localizer.on_scan(scan_at(world, truth[k], noise=0.02, rng=rng, stamp=0.1 * k)))
    return estimates


@pytest.mark.parametrize("motion_model", ["odometry", "velocity"])
def test_tracking_converges_after_initialisation(world: GridMap, localizer: IRLocalizer, motion_model: str) -> None:
    """With ours (nav2's odometry model) and with the paper's velocity model (IV-D)."""
    tracker = IRLocalizer(settings(seed=1, motion_model=motion_model), None)
    _share_index(tracker, localizer)
    assert isinstance(tracker, Localizer) and isinstance(tracker, GlobalFixer)
    # from room 1 through its door into the corridor, east, a U-turn, back west
    truth = _drive(world, [(2.5, 7.5), (2.5, 2.0), (9.0, 2.0), (9.0, 2.4), (4.5, 2.3)])
    estimates = _run(tracker, world, truth, np.random.default_rng(11), np.array([3.0, -2.0, 1.0]))
    first = estimates[0]
    assert first.details["phase"] == "initialization" and len(first.candidates) > 1
    assert sum(1 for e in estimates if e.details.get("updated")) >= 15
    # after the first third of the drive every estimate is correct and most are fine
    tail = len(estimates) // 3
    errors = np.array([math.hypot(*(e.pose[:2] - truth[k][:2])) for k, e in enumerate(estimates)])[tail:]
    turns = np.array([abs(angle_difference(e.pose[2], truth[k][2])) for k, e in enumerate(estimates)])[tail:]
    # an estimate off by more is not LOCALIZED and lists the truth (the velocity model's U-turn, while the
    # global check's better place waits for its confirmation)
    nearest = np.array([np.hypot(*(e.candidates[:, :2] - truth[k][:2]).T).min() for k, e in enumerate(estimates)])[tail:]
    off = errors >= 0.5
    assert all(estimates[tail + k].status is not LocalizerStatus.LOCALIZED for k in np.flatnonzero(off))
    assert (nearest[off] < 0.2).all() and off.sum() <= 3 and np.median(errors) < 0.2, errors
    assert np.degrees(turns[~off].max()) < 10.0
    assert estimates[-1].status is LocalizerStatus.LOCALIZED
    assert estimates[-1].candidates.shape == (tracker.settings.particle_count, 3)
    reinitialised = [k for k, e in enumerate(estimates) if k and "initialized_because" in e.details]
    # The velocity model reads a step with a turn on the spot (the U-turn) as one arc: it loses the robot
    # there once and finds it again from the scan (the tail above is right); the odometry model never.
    assert len(reinitialised) <= (1 if motion_model == "velocity" else 0), reinitialised


@pytest.mark.parametrize(("global_check_updates", "expected"), [(0, {"lost"}), (2, {"lost", "better global fix"})])
def test_a_kidnapped_tracker_reinitialises_by_itself(
    world: GridMap, localizer: IRLocalizer, global_check_updates: int, expected: set[str]
) -> None:
    # 0: only the LOST rule (end-point scores collapse); 2: also the periodic global check
    tracker = IRLocalizer(settings(seed=6, lost_update_count=2, global_check_updates=global_check_updates), None)
    _share_index(tracker, localizer)
    before = _drive(world, [(1.0, 1.5), (8.0, 1.6)])
    after = _drive(world, [(5.5, 4.0), (5.5, 8.0), (2.5, 8.0)])
    # odometry sees one continuous drive; the scans jump from the corridor to room 2
    odom_truth = np.vstack([before, compose(before[-1], relative(after[0], after))])
    estimates = _run(tracker, world, np.vstack([before, after]), np.random.default_rng(8), np.zeros(3), odom_truth)
    reasons = [e.details.get("initialized_because") for e in estimates]
    assert reasons[0] == "start"
    assert set(reasons[len(before) :]) & expected
    assert not set(reasons[1 : len(before)]) - {None}  # no restart before the kidnapping
    final = estimates[-1]
    assert math.hypot(*(final.pose[:2] - after[-1][:2])) < 0.3


@pytest.mark.parametrize(("confirmations", "restarted"), [(0, True), (1, False)])
def test_one_scan_that_fits_elsewhere_does_not_restart_the_tracker(
    world: GridMap, localizer: IRLocalizer, confirmations: int, restarted: bool
) -> None:
    # One scan of the corridor drive is taken in room 2 (what a person in front of the laser or an outdated
    # map can make of a single scan): the global check finds room 2 clearly better. Without a confirmation the
    # tracker restarts there; with one, the next scan (the corridor again) refutes it and the tracking goes on.
    tracker = IRLocalizer(settings(seed=6, global_check_updates=1, global_check_confirmations=confirmations), None)
    _share_index(tracker, localizer)
    path = _drive(world, [(1.0, 1.5), (8.0, 1.6)])
    seen, ghost = path.copy(), len(path) // 2
    seen[ghost] = [5.5, 6.0, 1.2]
    estimates = _run(tracker, world, seen, np.random.default_rng(8), np.zeros(3), path)
    reasons = [e.details.get("initialized_because") for e in estimates]
    assert reasons[0] == "start" and not set(reasons[1:ghost]) - {None}
    assert ("better global fix" in reasons[ghost:]) is restarted
    errors = [math.hypot(*(e.pose[:2] - path[k][:2])) for k, e in enumerate(estimates)]
    if not restarted:
        assert max(errors[ghost:]) < 0.3, errors[ghost:]
        assert any(e.details.get("challenger_refuted") for e in estimates[ghost:])
    else:
        assert max(errors[ghost:]) > 2.0  # what the confirmation prevents


def _point_symmetric_corridor() -> GridMap:
    """12 m x 3 m, its pillars and niches repeated by a half turn about the centre (6, 1.5): a pose and its
    mirror (12 - x, 3 - y, heading + pi) see the same scan."""
    data = np.zeros((int(3 / RES), int(12 / RES)), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    for x0, y0, x1, y1 in [(1.5, 0.4, 1.8, 0.7), (4.0, 2.3, 4.6, 2.6), (2.5, 0.0, 3.2, 0.3)]:
        data[int(y0 / RES):int(y1 / RES), int(x0 / RES):int(x1 / RES)] = 100
    return GridMap(np.maximum(data, data[::-1, ::-1]), RES, (0.0, 0.0))


def test_the_mirrored_track_passing_the_truth_in_a_symmetric_corridor_is_never_localized() -> None:
    # The tracker follows the mirror of the robot's drive (heading reversed): every scan fits it as well as the
    # truth. Where the two cross, the truth's position is within 0.5 m of the estimate but its heading is half a
    # turn off; the global check finds it there too, as a look-alike, so no output there is LOCALIZED.
    world = _point_symmetric_corridor()
    # a margin no noise reaches: the scans cannot tell the two apart, so no restart onto the truth by chance
    tracker = IRLocalizer(settings(seed=3, global_check_updates=1, global_check_margin=0.2), world)
    truth = _drive(world, [(9.5, 1.5), (2.5, 1.5)], step=0.1)
    mirror = np.array([12.0 - truth[0, 0], 3.0 - truth[0, 1], wrap_angle(truth[0, 2] + math.pi)])
    tracker.prepare(scan_at(world, truth[0]))
    tracker.set_initial_pose(mirror, np.diag([0.01, 0.01, 0.001]))
    estimates = _run(tracker, world, truth, np.random.default_rng(4), np.zeros(3))
    poses = np.array([e.pose for e in estimates])
    dxy, dtheta = metrics.pose_errors(poses, truth)
    crossing = np.flatnonzero((dxy < 0.5) & (dtheta > math.radians(150.0)))  # the mirror at the truth's position
    assert len(crossing) >= 3 and any(estimates[k].details.get("updated") for k in crossing)  # a check there
    assert all(estimates[k].details["lookalikes"] >= 1 for k in crossing)
    localized = np.array([e.status is LocalizerStatus.LOCALIZED for e in estimates])
    first_check = next(k for k, e in enumerate(estimates) if e.details.get("updated"))
    assert localized[:first_check].all()  # the initial pose, before any check has seen the mirror
    wrong = localized & ~metrics.correct_mask(dxy, dtheta)
    assert not wrong[first_check:].any(), np.flatnonzero(wrong)


def test_a_tracker_carried_away_while_standing_still_reinitialises_without_waiting_for_motion(
    world: GridMap, localizer: IRLocalizer
) -> None:
    # The robot drives down the corridor, stops, and is carried into room 2: the wheels see nothing, so no
    # update is due by motion. The scans no longer fit any particle: it updates anyway and finds itself again.
    tracker = IRLocalizer(settings(seed=6, global_check_updates=0), None)
    _share_index(tracker, localizer)
    before = _drive(world, [(1.0, 1.5), (8.0, 1.6)])
    rng = np.random.default_rng(8)
    estimates = _run(tracker, world, before, rng, np.zeros(3))
    assert estimates[-1].status is LocalizerStatus.LOCALIZED and close(estimates[-1].pose, before[-1])
    odom = tracker.odometry.latest
    carried = np.array([5.5, 6.0, 1.2])
    after = []
    for k in range(len(before), len(before) + 8):
        tracker.on_odometry(0.1 * k, odom)
        after.append(tracker.on_scan(scan_at(world, carried, noise=0.02, rng=rng, stamp=0.1 * k)))
    assert after[0].status is not LocalizerStatus.LOCALIZED  # the first scan there already says so
    first_back = next(k for k, e in enumerate(after) if e.details.get("initialized_because") == "lost")
    assert first_back <= tracker.settings.lost_update_count
    assert close(after[-1].pose, carried) and after[-1].status is not LocalizerStatus.LOST


def test_reinitialize_and_initial_pose(world: GridMap, localizer: IRLocalizer) -> None:
    tracker = IRLocalizer(settings(seed=2), None)
    _share_index(tracker, localizer)
    pose = np.array([6.0, 5.0, 0.5])
    tracker.set_initial_pose(pose, np.diag([0.1**2, 0.1**2, 0.05**2]))
    assert tracker.initialized and tracker.particles is not None
    assert np.allclose(tracker.particles.mean(axis=0)[:2], pose[:2], atol=0.1)
    estimate = tracker.on_scan(scan_at(world, pose))
    assert estimate is not None and estimate.details["phase"] == "tracking"
    tracker.request_nomotion_update()
    updated = tracker.on_scan(scan_at(world, pose))
    assert updated is not None and updated.details["updated"]
    tracker.reinitialize()
    assert not tracker.initialized
    again = tracker.on_scan(scan_at(world, pose))
    assert again is not None and again.details["phase"] == "initialization"


def test_a_scan_resampled_onto_another_fan_keeps_each_readings_own_angle(world: GridMap) -> None:
    # A 361-beam scan on a 359-ray fan (an RPLIDAR's count varies): readings were placed at the grid angles,
    # up to half a beam off, and the refinement fitted the pose to that distortion.
    from robot_localization_suite.core.ir.query import resample_scan

    pose = np.array([3.0, 1.5, 0.2])
    angles = -math.pi + 2.0 * math.pi / 361 * np.arange(361)
    ranges = RayCaster(world, max_range=SCAN_RANGE).cast(pose, angles).astype(np.float64)
    live = resample_scan(Scan(0.0, angles, ranges, 0.05, SCAN_RANGE), FanModel(359, SCAN_RANGE, 0.05))
    assert live.angles.size == 359 and np.all(np.isin(live.angles, angles))  # the beams' own angles
    grid = live.offsets * (2.0 * math.pi / 359)
    assert np.max(np.abs(live.angles - grid)) > 0.4 * (2.0 * math.pi / 361)  # not the grid's
    hits = np.isfinite(live.ranges)
    np.testing.assert_allclose(live.ranges[hits], ranges[np.isin(angles, live.angles)][hits])
