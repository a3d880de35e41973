"""PIL (core/pil*.py): learning, level functions, (x, y) and theta on-line, limited FOV, cache, bad input."""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from cache_damage import damaged
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_localization_suite.core.errors import MapError, ScanError
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.localizer import GlobalFixer, Localizer, LocalizerStatus
from robot_localization_suite.core.pil.learning import CODE_UNKNOWN, TileGrid, default_cache_dir
from robot_localization_suite.core.pil.levels import LEVEL_FUNCTION_NAMES
from robot_localization_suite.core.pil.localizer import PilLocalizer, PilSettings, make_level_functions
from robot_localization_suite.core.pil.matching import (
    LevelIndex,
    encode_features,
    profile_costs,
    rank_tiles,
    select_ranked,
)
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.scan import Scan
from robot_localization_suite.core.se2 import angle_difference

RESOLUTION = 0.05


def _asymmetric_room() -> GridMap:
    """An 8 m x 5 m room with an L-shaped partition and two boxes: no symmetry to confuse PIL."""
    data = np.zeros((100, 160), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100  # outer walls
    data[:60, 100:102] = 100  # partition from the south wall, x = 5 m, up to y = 3 m
    data[58:60, 100:130] = 100  # its foot towards the east, y = 3 m
    data[70:80, 20:40] = 100  # box at x 1-2 m, y 3.5-4 m
    data[15:25, 60:66] = 100  # pillar at x 3-3.3 m, y 0.75-1.25 m
    data[80:98, 140:158] = 100  # cupboard in the north-east corner
    return GridMap(data, RESOLUTION, (0.0, 0.0))


def _symmetric_room() -> GridMap:
    """A bare 6 m x 2.5 m rectangle: its centre looks the same facing east or west."""
    data = np.zeros((50, 120), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    return GridMap(data, RESOLUTION, (0.0, 0.0))


def _scan(
    grid_map: GridMap,
    pose: np.ndarray,
    *,
    beams: int = 360,
    fov: float = 2.0 * math.pi,
    noise: float = 0.0,
    rng: np.random.Generator | None = None,
    range_max: float = 12.0,
    stamp: float = 0.0,
) -> Scan:
    if fov >= 2.0 * math.pi:
        angles = -math.pi + np.arange(beams) * (2.0 * math.pi / beams)
    else:
        angles = -0.5 * fov + np.arange(beams) * (fov / (beams - 1))
    ranges = RayCaster(grid_map, max_range=range_max).cast(np.asarray(pose, dtype=np.float64), angles).astype(np.float64)
    if noise > 0.0:
        assert rng is not None
        hit = np.isfinite(ranges)
        ranges[hit] += rng.normal(0.0, noise, int(hit.sum()))
    return Scan.from_laser_fields(
        stamp=stamp,
        angle_min=float(angles[0]),
        angle_increment=float(angles[1] - angles[0]),
        ranges=ranges,
        range_min=0.05,
        range_max=range_max,
    )


def _settings(tmp_path: Path, **overrides: object) -> PilSettings:
    base = PilSettings(max_range=8.0, cache_dir=str(tmp_path / "cache"), show_progress=False)
    return replace(base, **overrides)


def _pose_error(estimate_pose: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    return float(np.hypot(*(estimate_pose[:2] - truth[:2]))), abs(float(angle_difference(estimate_pose[2], truth[2])))


@pytest.fixture(scope="module")
def room() -> GridMap:
    return _asymmetric_room()


@pytest.fixture(scope="module")
def learned(room: GridMap, tmp_path_factory: pytest.TempPathFactory) -> PilLocalizer:
    localizer = PilLocalizer(_settings(tmp_path_factory.mktemp("pil")))
    localizer.set_map(room)
    return localizer


# -- learning ---------------------------------------------------------------------------------
def test_tile_transform_m_round_trips_and_puts_tile_centres_on_integers() -> None:
    grid = TileGrid(origin=(-3.0, 2.0), tile_size=0.2, lines=10, columns=20)
    # Tile (L=2, C=5) has its centre at x = -3 + 5.5 * 0.2 = -1.9, y = 2 + 2.5 * 0.2 = 2.5.
    np.testing.assert_allclose(grid.tile_to_world([2, 5]), [-1.9, 2.5])
    np.testing.assert_allclose(grid.world_to_image([-1.9, 2.5]), [2.0, 5.0], atol=1e-12)
    # A point 0.09 m off the centre is still in that tile; 0.11 m is in the next column.
    assert grid.world_to_tile([-1.81, 2.5]).tolist() == [2, 5]
    assert grid.world_to_tile([-1.79, 2.5]).tolist() == [2, 6]
    np.testing.assert_allclose(grid.inverse_matrix @ grid.matrix, np.eye(3), atol=1e-12)


def test_learning_covers_free_tiles_only_with_intensities_of_equation_2(learned: PilLocalizer, room: GridMap) -> None:
    learning = learned.learning
    assert learning is not None
    # 8 m x 5 m at 0.2 m: 40 columns, 25 lines.
    assert (learning.grid.lines, learning.grid.columns) == (25, 40)
    assert np.all(room.is_free(learning.tile_centres))
    # Every free-centred tile is learned: none was left out.
    _, _, centres = learning.grid.all_centres()
    assert learning.tile_count == int(room.is_free(centres).sum())
    # 57 sensors x 4 finer directions around the circle.
    assert learning.angle_count == 57 * 4
    intensities = learning.intensities
    assert intensities.min() >= 0.0 and intensities.max() <= 1.0
    # Direction 0 (east) from the tile at x = 0.7, y = 2.5 (L=12, C=3): the east wall of the box-free
    # row is the partition at x = 5 m, 4.3 m away: I = 1 - 4.3 / 8.
    index = learning.tile_index_image()[12, 3]
    assert index >= 0
    assert intensities[index, 0] == pytest.approx(1.0 - 4.3 / 8.0, abs=2e-3)


# -- level functions -----------------------------------------------------------------------------
_ALL_LEVELS = make_level_functions(PilSettings())


@settings(max_examples=60, deadline=None)
@given(
    profile=st.lists(st.floats(0.0, 1.0, allow_nan=False), min_size=8, max_size=96),
    shift=st.integers(-200, 200),
)
def test_every_level_function_is_invariant_to_circular_shifts(profile: list[float], shift: int) -> None:
    assert [f.name for f in _ALL_LEVELS] == list(LEVEL_FUNCTION_NAMES)
    values = np.asarray(profile)
    rolled = np.roll(values, shift)
    for function in _ALL_LEVELS:
        assert float(function.evaluate(rolled)) == pytest.approx(float(function.evaluate(values)), abs=1e-9), function.name


def test_level_functions_tell_profiles_apart() -> None:
    """Invariance must not come from being constant: each function separates two different profiles."""
    angles = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    round_room = np.full(64, 0.5)
    corridor = 0.5 + 0.4 * np.cos(2.0 * angles)  # near walls on two opposite sides
    off_centre = 0.5 + 0.3 * np.cos(angles) + 0.1 * np.cos(2.0 * angles)
    small_room = np.full(64, 0.8)
    for function in _ALL_LEVELS:
        outputs = {round(float(function.evaluate(p)), 9) for p in (round_room, corridor, off_centre, small_room)}
        assert len(outputs) >= 2, function.name


def test_candidate_count_shrinks_as_sigma_shrinks(room: GridMap, tmp_path: Path) -> None:
    truth = np.array([2.5, 2.1, 0.4])
    counts = []
    for sigma in (0.3, 0.1, 0.03, 0.01):
        overrides = {f"{name}_sigma": sigma for name in LEVEL_FUNCTION_NAMES}
        # The paper: the tiles passing equation (4), one heading each (the correlation's best).
        localizer = PilLocalizer(_settings(tmp_path, min_candidates=0, refine_candidates=0, shift_hypotheses=1, coarse_block=1,
                                           fine_candidates=100_000, **overrides))
        localizer.set_map(room)
        estimate = localizer.global_fix(_scan(room, truth))
        counts.append(estimate.details["filter_count"])
        assert len(estimate.candidates) == estimate.details["filter_count"]
        image = localizer.candidate_image
        assert image is not None and int(image.sum()) == estimate.details["filter_count"]
    assert counts == sorted(counts, reverse=True)
    assert counts[-1] < counts[0] / 4


def test_min_candidates_zero_keeps_the_passing_tiles_up_to_max_candidates(room: GridMap, tmp_path: Path) -> None:
    # docs/pil.md: min_candidates 0 drops every tile failing equation (4) but keeps the max_candidates cap
    truth = np.array([2.5, 2.1, 0.4])
    wide = {f"{name}_sigma": 0.3 for name in LEVEL_FUNCTION_NAMES}  # many tiles pass
    paper = {"min_candidates": 0, "refine_candidates": 0, "shift_hypotheses": 1, "coarse_block": 1,
             "fine_candidates": 100_000, **wide}
    uncapped = PilLocalizer(_settings(tmp_path, max_candidates=10_000_000, **paper))
    uncapped.set_map(room)
    scan = _scan(room, truth)
    estimate = uncapped.global_fix(scan)
    passing = estimate.details["filter_count"]
    assert len(estimate.candidates) == passing and passing > 40
    image = uncapped.candidate_image
    assert image is not None and int(image.sum()) == passing
    capped = PilLocalizer(_settings(tmp_path, max_candidates=passing // 4, **paper))
    capped.set_map(room)
    assert len(capped.global_fix(scan).candidates) == passing // 4
    # with min_candidates > 0 tiles failing equation (4) are added up to min_candidates
    topped = PilLocalizer(_settings(tmp_path, **{**paper, **{f"{n}_sigma": 0.01 for n in LEVEL_FUNCTION_NAMES},
                                                 "min_candidates": 30, "max_candidates": 30}))
    topped.set_map(room)
    few = topped.global_fix(scan)
    assert few.details["filter_count"] < 30 and len(few.candidates) == 30


def test_match_score_correlation_picks_the_candidate_of_highest_distance_profile_correlation(
    room: GridMap, tmp_path: Path
) -> None:
    # paper 2.5: the chosen candidate maximises the correlation of D_r and D_s; reported as 1 - mean(D_r D_s) / R^2
    truth = np.array([2.5, 2.1, 0.4])
    scan = _scan(room, truth)
    ours = PilLocalizer(_settings(tmp_path, refine_candidates=0))
    ours.set_map(room)
    assert ours.global_fix(scan).details["best_score"] < 0.02  # truncated difference: a perfect match is ~0
    paper = PilLocalizer(_settings(tmp_path, refine_candidates=0, match_score="correlation", lost_score=1.0))
    paper.set_map(room)
    estimate = paper.global_fix(scan)
    profile = paper._live_profile(scan)

    def correlation(poses: np.ndarray) -> np.ndarray:
        codes = paper._pose_codes(poses, profile)
        use = profile.valid[None, :] & (codes < 255)
        return np.where(use, (1.0 - profile.intensities)[None, :] * codes / 254.0, 0.0).sum(axis=1) / use.sum(axis=1)

    values = correlation(estimate.candidates)
    # the independent correlation at the chosen pose is the reported score, and no candidate correlates better
    assert estimate.details["best_score"] == pytest.approx(1.0 - values[0], abs=2e-3)
    assert values.max() <= values[0] + 2e-3
    assert estimate.details["best_score"] > 0.5


def test_the_level_index_scores_a_few_blocks_and_finds_the_same_best_and_passing_tiles() -> None:
    """Spatially smooth level functions (as a map's are) with missing ones: the blocks whose bounds
    cannot hold a best-ranked or passing tile are skipped, and the selection is the full ranking's."""
    rng = np.random.default_rng(8)
    lines, columns = np.meshgrid(np.arange(120), np.arange(150), indexing="ij")
    keep = rng.random(lines.shape) < 0.7  # tiles over free space only
    lines, columns = lines[keep].astype(np.int32), columns[keep].astype(np.int32)
    base = 0.5 + 0.3 * np.sin(lines / 9.0)[:, None, None] * np.cos(columns[:, None] / 13.0 + np.arange(6))[:, None, :]
    values = base + 0.02 * rng.standard_normal((lines.size, 3, 6))
    values[rng.random(values.shape) < 0.02] = np.nan
    features = encode_features(values)
    index = LevelIndex(features, lines, columns)
    alphas, sigmas = np.ones(6), np.array([0.03, 0.08, 0.025, 0.02, 0.06, 0.02])
    for live in (np.full(6, 0.5), np.array([0.3, 0.7, 0.5, 0.6, 0.45, 0.55])):
        passes, rank = rank_tiles(features, live, alphas, sigmas, 9.0)
        for count in (50, 600):
            ranked = index.query(live, alphas, sigmas, 9.0, count)
            assert ranked.tiles.size < 0.5 * lines.size and not ranked.complete
            np.testing.assert_array_equal(ranked.rank, rank[ranked.tiles])
            expected = select_ranked(rank, passes, count)
            found = ranked.tiles[select_ranked(ranked.rank, ranked.passes, count)]
            np.testing.assert_array_equal(rank[found], rank[expected])  # the same ranks, in the same order
            assert set(found[passes[found]]) == set(expected[passes[expected]])
    # Passing tiles come first, then by rank.
    order = select_ranked(np.array([0.5, 3.0, 0.1, 2.0]), np.array([False, True, False, True]), 3)
    assert order.tolist() == [3, 1, 2]


# -- (x, y, theta) on-line -------------------------------------------------------------------------
def test_noise_free_scan_at_a_tile_centre_returns_that_tile_and_theta_within_one_step(room: GridMap, tmp_path: Path) -> None:
    localizer = PilLocalizer(_settings(tmp_path, refine_candidates=0))
    localizer.set_map(room)
    learning = localizer.learning
    assert learning is not None
    step = 2.0 * math.pi / 57
    for lc, theta in (((12, 3), 1.0), ((5, 20), -2.3), ((20, 33), 0.05)):
        index = learning.tile_index_image()[lc]
        assert index >= 0
        truth = np.array([*learning.tile_centres[index], theta])
        estimate = localizer.global_fix(_scan(room, truth))
        assert learning.grid.world_to_tile(estimate.pose[:2]).tolist() == list(lc)
        assert abs(angle_difference(estimate.pose[2], theta)) <= step
        assert estimate.status is LocalizerStatus.LOCALIZED


def test_noisy_scans_at_random_poses_are_localized_finely(learned: PilLocalizer, room: GridMap) -> None:
    rng = np.random.default_rng(3)
    distance = room.distance_field()
    poses = [p for p in room.sample_free_poses(200, rng) if distance[room.world_to_cell(p[:2])[1], room.world_to_cell(p[:2])[0]] > 0.3]
    fine = 0
    for truth in poses[:25]:
        estimate = learned.global_fix(_scan(room, truth, noise=0.02, rng=rng))
        dxy, dtheta = _pose_error(estimate.pose, truth)
        fine += dxy < 0.2 and dtheta < 0.1
        # Candidates come best first and the covariance is a covariance.
        assert np.allclose(estimate.candidates[0], estimate.pose)
        assert np.all(np.diff(estimate.candidate_weights) <= 1e-12)
        assert np.all(np.linalg.eigvalsh(estimate.covariance) > 0.0)
    assert fine >= 23


def test_symmetric_room_is_reported_ambiguous_with_both_headings_as_candidates(tmp_path: Path) -> None:
    corridor = _symmetric_room()
    localizer = PilLocalizer(_settings(tmp_path))
    localizer.set_map(corridor)
    truth = np.array([3.0, 1.25, 0.3])
    estimate = localizer.global_fix(_scan(corridor, truth))
    assert estimate.status is LocalizerStatus.AMBIGUOUS
    mirrored = np.array([3.0, 1.25, 0.3 + math.pi])
    near = [min(_pose_error(c, t)[0] + _pose_error(c, t)[1] for c in estimate.candidates[:10]) for t in (truth, mirrored)]
    assert max(near) < 0.3
    # The spread of the near-best candidates shows in the heading variance.
    assert estimate.covariance[2, 2] > 1.0


@pytest.mark.parametrize("global_candidates", [50, 0])
def test_kidnapping_is_recovered_in_one_update_and_the_window_is_used_otherwise(
    room: GridMap, tmp_path: Path, global_candidates: int
) -> None:
    localizer = PilLocalizer(_settings(tmp_path, global_candidates=global_candidates))
    localizer.set_map(room)
    first = localizer.on_scan(_scan(room, np.array([1.0, 1.0, 0.2]), stamp=1.0))
    assert first.details["window"] == "whole_map"
    nearby = localizer.on_scan(_scan(room, np.array([1.2, 1.1, 0.3]), stamp=2.0))
    assert nearby.details["window"] == "window"
    assert _pose_error(nearby.pose, np.array([1.2, 1.1, 0.3]))[0] < 0.2
    kidnapped = np.array([6.6, 4.0, -2.0])  # 6 m away, outside the 4 m window
    after = localizer.on_scan(_scan(room, kidnapped, stamp=3.0))
    if global_candidates:
        # Found among the global sentinels scored with the windowed search: a large advantage
        # switches at once.
        assert after.details["window"] == "window" and after.details["outside_window"]
    else:
        # The paper's hard window: a bad best score inside it widens the search to the whole map.
        assert after.details["window"] == "whole_map_after_window"
    dxy, dtheta = _pose_error(after.pose, kidnapped)
    assert dxy < 0.2 and dtheta < 0.1


def test_odometry_moves_the_window_centre(learned: PilLocalizer, room: GridMap) -> None:
    localizer = learned
    localizer.set_initial_pose(np.array([1.0, 1.0, 0.0]), np.eye(3) * 0.01)
    localizer.on_odometry(0.0, np.array([0.0, 0.0, 0.0]))
    localizer.set_initial_pose(np.array([1.0, 1.0, 0.0]), np.eye(3) * 0.01)
    localizer.on_odometry(1.0, np.array([3.5, 2.0, 0.0]))  # moved to (4.5, 3.0) in the map
    truth = np.array([4.5, 3.6, 0.0])
    estimate = localizer.on_scan(_scan(room, truth, stamp=4.0))
    # 3.5 m away from the last estimate: found inside the moved window, not by a whole-map search.
    assert estimate.details["window"] == "window"
    assert _pose_error(estimate.pose, truth)[0] < 0.2


# -- limited field of view ------------------------------------------------------------------------
def test_a_180_degree_scanner_localizes_with_heading_sheets(room: GridMap, tmp_path: Path) -> None:
    localizer = PilLocalizer(_settings(tmp_path, field_of_view=math.pi))
    localizer.set_map(room)
    # The learned angular step stays 2 pi / (57 x 4): 114 sensors around the circle, 2 directions each.
    assert localizer.layout.angle_count == 114 * 2
    rng = np.random.default_rng(5)
    poses = [np.array([1.0, 2.0, 0.3]), np.array([3.9, 3.0, -1.9]), np.array([6.5, 1.4, 2.8]), np.array([7.0, 3.6, -0.7])]
    for truth in poses:
        estimate = localizer.global_fix(_scan(room, truth, beams=181, fov=math.pi, noise=0.01, rng=rng))
        assert "warning" not in estimate.details
        assert estimate.details["sheets"] == 8
        dxy, dtheta = _pose_error(estimate.pose, truth)
        assert dxy < 0.2 and dtheta < 0.1, (truth, estimate.pose)


def test_a_scan_with_another_field_of_view_warns_and_relearns(room: GridMap, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    localizer = PilLocalizer(_settings(tmp_path))  # learned for 360 degrees
    localizer.set_map(room)
    truth = np.array([6.5, 1.4, 2.8])
    with caplog.at_level(logging.WARNING):
        estimate = localizer.global_fix(_scan(room, truth, beams=241, fov=math.radians(240.0)))
    # Scan.field_of_view counts one increment beyond the end-to-end span: 240 + 1 degrees.
    assert "the scan covers 241.0 deg but PIL learned 360.0 deg: relearning" in estimate.details["warning"]
    assert any("relearning" in record.getMessage() for record in caplog.records)
    assert localizer.layout.field_of_view == pytest.approx(math.radians(241.0), abs=1e-6)
    dxy, dtheta = _pose_error(estimate.pose, truth)
    assert dxy < 0.2 and dtheta < 0.1
    # The same geometry again: no new warning.
    again = localizer.global_fix(_scan(room, truth, beams=241, fov=math.radians(240.0)))
    assert "warning" not in again.details


def test_a_half_circle_scanner_reuses_the_rays_learned_for_the_full_circle(room: GridMap, tmp_path: Path) -> None:
    """57 sensors over 180 degrees are 114 around the circle at 2 learned directions each: the same
    228 directions as 57 sensors over 360 degrees at 4, so only the level functions change."""
    localizer = PilLocalizer(_settings(tmp_path))  # learned for 360 degrees in set_map
    localizer.set_map(room)
    learning = localizer.learning
    truth = np.array([3.9, 3.0, -1.9])
    # 180 beams 1 degree apart cover 180 degrees (Scan.field_of_view counts one increment past the end).
    estimate = localizer.global_fix(_scan(room, truth, beams=180, fov=math.radians(179.0)))
    assert "the learned rays serve for 180.0 deg" in estimate.details["warning"]
    assert "relearned" not in estimate.details and localizer.learning is learning
    assert estimate.details["sheets"] == 8
    dxy, dtheta = _pose_error(estimate.pose, truth)
    assert dxy < 0.2 and dtheta < 0.1


def test_a_shorter_range_max_relearns_with_that_range(room: GridMap, tmp_path: Path) -> None:
    localizer = PilLocalizer(_settings(tmp_path))
    localizer.set_map(room)
    truth = np.array([2.5, 2.1, 0.4])
    estimate = localizer.global_fix(_scan(room, truth, range_max=4.0))
    assert "range_max" in estimate.details["warning"]
    assert localizer.max_range == pytest.approx(4.0)
    assert _pose_error(estimate.pose, truth)[0] < 0.2


def test_a_range_max_shorter_than_a_cell_is_refused_before_any_relearning(room: GridMap, tmp_path: Path) -> None:
    # a LaserScan with range_max 1e-44 (every beam a no-return) made PIL relearn the map for R = 1e-44 m
    localizer = PilLocalizer(_settings(tmp_path))
    localizer.set_map(room)
    learning = localizer.learning
    junk = _scan(room, np.array([2.5, 2.1, 0.4]))
    junk = Scan(junk.stamp, junk.angles, np.full(junk.beam_count, np.inf), 0.0, 1e-44)
    assert localizer.prepared_for(junk)  # nothing to prepare for it: on_scan says why
    with pytest.raises(ScanError, match="shorter than a map cell"):
        localizer.on_scan(junk)
    assert localizer.learning is learning


def test_a_map_coarser_than_the_tiles_is_learned_a_cell_a_tile(tmp_path: Path) -> None:
    # a map published in the wrong unit (1000 m cells) asked for 2.4e11 tiles of 0.2 m and never ended
    data = np.zeros((80, 120), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    coarse = GridMap(data, 1000.0, (0.0, 0.0))
    localizer = PilLocalizer(_settings(tmp_path))
    localizer.set_map(coarse)
    assert localizer.tile_size == 1000.0
    assert localizer.learning is not None and localizer.learning.tile_count == int((data == 0).sum())


# -- cache ---------------------------------------------------------------------------------------
def test_cached_learning_reloads_identically_and_a_corrupt_cache_is_rebuilt(
    room: GridMap, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    settings_ = _settings(tmp_path)
    first = PilLocalizer(settings_)
    first.set_map(room)
    assert first.learning is not None and not first.learning.from_cache
    files = list((tmp_path / "cache" / "pil").glob("pil_*.npz"))
    assert len(files) == 1 and room.fingerprint() in files[0].name

    second = PilLocalizer(settings_)
    second.set_map(room)
    assert second.learning is not None and second.learning.from_cache
    assert np.array_equal(second.learning.codes, first.learning.codes)
    assert np.array_equal(second.learning.intensities, first.learning.intensities)
    assert np.array_equal(second.learning.tile_centres, first.learning.tile_centres)
    scan = _scan(room, np.array([2.5, 2.1, 0.4]))
    np.testing.assert_array_equal(first.global_fix(scan).candidates, second.global_fix(scan).candidates)

    for how, damage in damaged(files[0].read_bytes()).items():
        files[0].write_bytes(damage)
        third = PilLocalizer(settings_)
        with caplog.at_level(logging.WARNING):
            caplog.clear()
            third.set_map(room)
        warnings = [record.getMessage() for record in caplog.records if record.levelno >= logging.WARNING]
        assert len(warnings) == 1 and str(files[0]) in warnings[0] and "relearning" in warnings[0], (how, warnings)
        assert third.learning is not None and not third.learning.from_cache
        assert np.array_equal(third.learning.codes, first.learning.codes)
    fourth = PilLocalizer(settings_)
    fourth.set_map(room)
    assert fourth.learning is not None and fourth.learning.from_cache  # the rebuilt file is sound


def test_cache_directory_comes_from_rls_cache_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("RLS_CACHE_DIR", str(tmp_path / "env_cache"))
    assert default_cache_dir() == tmp_path / "env_cache"
    localizer = PilLocalizer(PilSettings(max_range=8.0, show_progress=False))
    localizer.set_map(_symmetric_room())
    assert list((tmp_path / "env_cache" / "pil").glob("pil_*.npz"))


def test_pil_cache_stays_within_its_budget(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, room: GridMap) -> None:
    monkeypatch.setenv("RLS_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("RLS_CACHE_BUDGET_MB", "0.000001")  # one byte: only the file just written survives
    PilLocalizer(PilSettings(max_range=8.0, show_progress=False)).set_map(room)
    first = list((tmp_path / "pil").glob("pil_*.npz"))
    PilLocalizer(PilSettings(max_range=8.0, show_progress=False)).set_map(_symmetric_room())
    second = list((tmp_path / "pil").glob("pil_*.npz"))
    assert len(first) == 1 and len(second) == 1 and second != first


# -- bad input -----------------------------------------------------------------------------------
def test_bad_readings_are_ignored_and_unusable_scans_raise_scan_error(learned: PilLocalizer, room: GridMap) -> None:
    truth = np.array([2.5, 2.1, 0.4])
    scan = _scan(room, truth)
    ranges = scan.ranges.copy()
    ranges[::7] = np.nan
    ranges[3::11] = -1.0
    ranges[5::13] = -np.inf
    ranges[6::17] = 1e6  # beyond range_max: a no-return
    damaged = Scan(1.0, scan.angles, ranges, scan.range_min, scan.range_max)
    estimate = learned.global_fix(damaged)
    dxy, dtheta = _pose_error(estimate.pose, truth)
    assert dxy < 0.25 and dtheta < 0.1

    with pytest.raises(ScanError, match="valid beam"):
        learned.global_fix(Scan(2.0, scan.angles, np.full(scan.beam_count, np.nan), scan.range_min, scan.range_max))
    mostly_bad = np.full(scan.beam_count, np.nan)
    mostly_bad[:40] = 2.0
    with pytest.raises(ScanError, match="valid beam"):
        learned.on_scan(Scan(3.0, scan.angles, mostly_bad, scan.range_min, scan.range_max))
    with pytest.raises(ScanError, match="at least 2 beams"):
        learned.global_fix(Scan(4.0, scan.angles[:1], scan.ranges[:1], scan.range_min, scan.range_max))


def test_a_changing_beam_count_is_followed(learned: PilLocalizer, room: GridMap) -> None:
    truth = np.array([6.5, 1.4, 2.8])
    for beams in (360, 720, 90, 360):
        estimate = learned.global_fix(_scan(room, truth, beams=beams))
        dxy, dtheta = _pose_error(estimate.pose, truth)
        assert dxy < 0.2 and dtheta < 0.1, beams


def test_no_map_and_a_map_without_free_tiles_raise_map_error(tmp_path: Path) -> None:
    localizer = PilLocalizer(_settings(tmp_path))
    scan = _scan(_symmetric_room(), np.array([3.0, 1.25, 0.0]))
    with pytest.raises(MapError, match="no map"):
        localizer.global_fix(scan)
    with pytest.raises(MapError, match="free space"):
        localizer.set_map(GridMap(np.full((20, 20), 100, dtype=np.int8), 0.05))


@pytest.mark.parametrize(
    ("field", "value"),
    [("tile_size", 0.0), ("sensor_count", 2), ("max_range", 100.0), ("energy_sigma", -0.1), ("pq_low", 0.9),
     ("beam_mapping", "median"), ("field_of_view", 7.0), ("max_candidates", 0)],
)
def test_settings_refuse_bad_values_naming_them(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        PilSettings(**{field: value})


def test_sector_min_beam_mapping_localizes_too(room: GridMap, tmp_path: Path) -> None:
    localizer = PilLocalizer(_settings(tmp_path, beam_mapping="sector_min"))
    localizer.set_map(room)
    truth = np.array([3.9, 3.0, -1.9])
    dxy, dtheta = _pose_error(localizer.global_fix(_scan(room, truth, beams=720)).pose, truth)
    assert dxy < 0.2 and dtheta < 0.1


def test_the_protocol_calls_centre_keep_and_forget_the_window(room: GridMap, tmp_path: Path) -> None:
    localizer = PilLocalizer(_settings(tmp_path, global_candidates=0))
    assert isinstance(localizer, Localizer) and isinstance(localizer, GlobalFixer)
    localizer.set_map(room)
    start, truth = np.array([1.3, 1.2, 0.2]), np.array([1.4, 1.1, 0.3])
    localizer.set_initial_pose(start, np.eye(3))
    scan = _scan(room, truth, stamp=1.0)
    tracked = localizer.on_scan(scan)
    # set_initial_pose centres the window: every candidate (hard window) inside it, the truth found
    assert tracked.details["window"] == "window"
    half = 0.5 * localizer.settings.window_size + localizer.settings.tile_size
    assert np.all(np.abs(tracked.candidates[:, :2] - start[:2]) <= half)
    assert _pose_error(tracked.pose, truth)[0] < 0.2
    # global_fix searches the whole map and leaves the tracking alone
    assert localizer.global_fix(scan).details["window"] == "whole_map"
    # PIL updates on every scan: the same scan again, no motion, no request, gives an estimate
    again = localizer.on_scan(_scan(room, truth, stamp=2.0))
    assert again is not None and again.details["window"] == "window"
    localizer.reinitialize()
    assert localizer.on_scan(_scan(room, truth, stamp=3.0)).details["window"] == "whole_map"


def test_the_window_leaves_a_twin_place_once_the_scans_tell_them_apart(tmp_path: Path) -> None:
    """A 12 m x 3 m corridor, point-symmetric about its centre but for one cabinet: tracking the
    twin (12 - x, 3 - y, theta + pi), the estimate stays there while the scans cannot tell the
    twins apart and moves to the truth once the cabinet is in view."""
    data = np.zeros((60, 240), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[2:10, 70:80] = data[50:58, 160:170] = 100  # boxes at x 3.5-4.0 south and 8.0-8.5 north (twins)
    data[2:10, 116:124] = data[50:58, 116:124] = 100  # boxes at x 5.8-6.2 on both walls
    data[2:12, 20:34] = 100  # cabinet at x 1.0-1.7 on the south wall: the only asymmetry
    corridor = GridMap(data, RESOLUTION, (0.0, 0.0))
    range_m = 3.5  # from x = 6.6 neither the truth nor its twin at 5.4 sees the cabinet (or its mirror)
    localizer = PilLocalizer(_settings(tmp_path, max_range=range_m))
    localizer.set_map(corridor)
    localizer.on_odometry(0.0, np.zeros(3))
    start = 6.6
    twin = np.array([12.0 - start, 1.5, 0.0])
    localizer.set_initial_pose(twin, np.eye(3) * 0.01)
    errors = {}
    for step, x in enumerate(np.arange(start, 2.0, -0.25)):
        # The robot drives west facing west; its twin hypothesis drives east, in step with the odometry.
        localizer.on_odometry(float(step + 1), np.array([start - x, 0.0, 0.0]))
        truth = np.array([x, 1.5, math.pi])
        estimate = localizer.on_scan(_scan(corridor, truth, stamp=float(step + 1)))
        if step == 0:
            assert _pose_error(estimate.pose, twin)[0] < 0.2  # equal scores: the window keeps the twin
            assert estimate.status is LocalizerStatus.AMBIGUOUS
        errors[round(x, 2)] = _pose_error(estimate.pose, truth)
    # The cabinet's corner (1.7, 0.6) is in range from x < 5.2; a metre later the truth has won for good.
    late = [error for x, error in errors.items() if x < 4.0]
    assert late and all(dxy < 0.2 and dtheta < 0.1 for dxy, dtheta in late)


# -- large maps: memory ----------------------------------------------------------------------------
def test_learning_a_large_map_holds_one_byte_a_ray_and_memory_maps_it_beyond_the_budget(tmp_path: Path) -> None:
    """A 150 m x 100 m map of streets between blocks, half of it unknown: every array PIL keeps is
    bounded by the free tiles x learned directions (one byte each) or the map cells (a few bytes each)."""
    data = np.full((2000, 3000), -1, dtype=np.int8)
    for y in range(0, 2000, 400):  # streets 5 m wide every 20 m, both ways, walls on their sides
        data[y + 100 : y + 200, :] = 0
        data[y + 100 : y + 102, :] = data[y + 198 : y + 200, :] = 100
    for x in range(0, 3000, 400):
        data[:, x + 100 : x + 200] = 0
    large = GridMap(data, RESOLUTION, (0.0, 0.0))
    settings_ = _settings(tmp_path, tile_size=0.5, sensor_count=16, max_range=6.0, cache_mmap_mb=1.0)
    localizer = PilLocalizer(settings_)
    localizer.set_map(large)
    learning = localizer.learning
    assert learning is not None and localizer._sheet_features is not None and localizer._caster is not None
    tiles, rays = learning.tile_count, learning.angle_count
    # Tiles over free space only: fewer than half of the 300 x 200 the map would hold.
    _, _, centres = learning.grid.all_centres()
    assert (learning.grid.lines, learning.grid.columns) == (200, 300)
    assert tiles == int(large.is_free(centres).sum()) < 0.5 * 300 * 200
    # One byte a learned ray, read from the cache file rather than held (over the 1 MB budget).
    assert learning.codes.dtype == np.uint8 and learning.codes.shape == (tiles, rays)
    assert learning.memory_mapped and isinstance(learning.codes, np.memmap)
    assert learning._intensities is None  # no float copy of the rays
    # Level functions: one byte per tile, sheet and function.
    features = localizer._sheet_features
    assert features.dtype == np.uint8 and features.shape == (tiles, 1, len(localizer.level_functions))
    # Per map cell: 2 bytes to cast rays, 4 for the distance field (no float64 gradients).
    cells = large.data.size
    assert localizer._caster.nbytes == 2 * cells
    assert localizer._distance_field is not None and localizer._distance_field.nbytes == 4 * cells
    # A scan still matches from the memory-mapped learning: a place about as good as the truth (the
    # streets repeat, so which one is not the point here; rays into the unknown blocks cost
    # unknown_cost at the truth too).
    truth = np.array([67.75, 47.25, 0.7])  # a tile centre
    scan = _scan(large, truth, range_max=6.0)
    estimate = localizer.global_fix(scan)
    profile = localizer._live_profile(scan)
    at_truth = profile_costs(localizer._pose_codes(truth[None, :], profile), localizer._table(profile), profile.valid)
    assert estimate.details["best_score"] <= at_truth[0] + 0.05  # a heading between learned directions


# -- a partial, outdated map -----------------------------------------------------------------------
def _room_open_to_unknown() -> GridMap:
    """The asymmetric room whose east part (x > 6 m, walls included) was never mapped: unknown cells."""
    data = _asymmetric_room().data.copy()
    data[:, 120:] = -1
    return GridMap(data, RESOLUTION, (0.0, 0.0))


def test_a_learned_ray_into_unknown_space_is_no_evidence(room: GridMap, tmp_path: Path) -> None:
    partial = _room_open_to_unknown()
    truth = np.array([3.0, 3.5, 0.0])  # facing east, into the part the map does not know
    scan = _scan(room, truth)  # the real room: the partition at x = 5 m, then the east wall
    localizer = PilLocalizer(_settings(tmp_path, refine_candidates=0))
    localizer.set_map(partial)
    learning = localizer.learning
    assert learning is not None
    index = learning.tile_index_image()[tuple(learning.grid.world_to_tile(truth[:2]))]
    # East (direction 0) from x = 3.1, y = 3.5: over the partition's top, free up to the unknown part
    # at x = 6 m, nothing mapped beyond: unknown. West: the box at x = 2 m, 1.1 m away, is a range.
    assert learning.codes[index, 0] == CODE_UNKNOWN
    assert learning.codes[index, learning.angle_count // 2] != CODE_UNKNOWN
    # The score at the truth does not depend on what the live scan reads along the unknown rays:
    # the same scan with every eastward beam reading 0.5 m, or nothing, scores the same there.
    localizer.prepare(scan)
    profile = localizer._live_profile(scan)
    pose_codes = localizer._pose_codes(truth[None, :], profile)[0]
    unknown = pose_codes == CODE_UNKNOWN
    # About -15 to +25 degrees (the partition below, the north wall above): 4 to 7 sensors of 57.
    assert 4 <= unknown.sum() <= 8 and np.all(np.cos(profile.sensor_angles[unknown]) > 0.8)
    costs = []
    for reading in (0.5, np.inf, None):
        ranges = scan.ranges.copy()
        if reading is not None:
            beams = np.abs(angle_difference(scan.angles, 0.0)) < 0.5 * math.pi - 0.35
            ranges[beams] = reading
        live = localizer._live_profile(Scan(0.0, scan.angles, ranges, scan.range_min, scan.range_max))
        table = localizer._table(live)
        per_sensor = table[np.arange(table.shape[0]), pose_codes]
        assert np.all(per_sensor[unknown] == localizer.settings.unknown_cost)
        costs.append(float(per_sensor[unknown].sum()))
    assert costs[0] == costs[1] == costs[2]
    # Global localization on the partial map still finds the truth.
    estimate = localizer.global_fix(scan)
    dxy, dtheta = _pose_error(estimate.pose, truth)
    assert dxy < 0.25 and dtheta < 0.1
    # The paper's learning (rays read what they find) takes the unknown part as open space.
    legacy = PilLocalizer(_settings(tmp_path, refine_candidates=0, mark_unknown_rays=False))
    legacy.set_map(partial)
    assert legacy.learning is not None and not np.any(legacy.learning.codes == CODE_UNKNOWN)


def test_a_scan_the_map_explains_poorly_is_a_best_guess_not_localized(learned: PilLocalizer, room: GridMap) -> None:
    # 40 % of the readings replaced by junk: the best place is still right, but its score is past
    # kidnap_score (what the window search takes for a kidnapping), so the node does not stand behind it.
    truth = np.array([2.5, 2.1, 0.4])
    clean = _scan(room, truth)
    rng = np.random.default_rng(0)
    ranges = clean.ranges.copy()
    junk = rng.choice(ranges.size, int(0.4 * ranges.size), replace=False)
    ranges[junk] = rng.uniform(0.3, 6.0, junk.size)
    scan = Scan.from_laser_fields(stamp=0.0, angle_min=float(clean.angles[0]),
                                  angle_increment=float(clean.angles[1] - clean.angles[0]), ranges=ranges,
                                  range_min=0.05, range_max=12.0)
    estimate = learned.global_fix(scan)
    settings = learned.settings
    assert settings.kidnap_score < estimate.details["best_score"] < settings.lost_score
    assert _pose_error(estimate.pose, truth)[0] < 0.2 and estimate.status is LocalizerStatus.AMBIGUOUS
    assert learned.global_fix(clean).status is LocalizerStatus.LOCALIZED


def _scan_with_unmapped_box(room: GridMap, truth: np.ndarray) -> Scan:
    """The scan at ``truth`` with a 1 m x 0.6 m box 0.8 m in front of the robot that the map lacks."""
    cluttered = room.data.copy()
    centre = truth[:2] + 1.1 * np.array([math.cos(truth[2]), math.sin(truth[2])])
    ix, iy = room.world_to_cell(centre)
    cluttered[iy - 10 : iy + 10, ix - 6 : ix + 6] = 100
    return _scan(GridMap(cluttered, RESOLUTION, (0.0, 0.0)), truth)


def test_a_scan_with_an_unmapped_box_in_front_still_localizes(room: GridMap, tmp_path: Path) -> None:
    """A 1 m x 0.6 m box 0.8 m in front of the robot, absent from the map: it hides a fifth of the
    scan, whose readings are shorter than the learned ranges, not longer."""
    truth = np.array([2.5, 2.1, 0.4])
    scan = _scan_with_unmapped_box(room, truth)
    original = _scan(room, truth)
    shorter = scan.ranges < original.ranges - 0.3
    assert 0.1 < shorter.mean() < 0.3
    localizer = PilLocalizer(_settings(tmp_path))
    localizer.set_map(room)
    estimate = localizer.global_fix(scan)
    dxy, dtheta = _pose_error(estimate.pose, truth)
    assert dxy < 0.2 and dtheta < 0.1
    assert estimate.status is not LocalizerStatus.LOST


def test_a_place_the_map_cannot_vouch_for_is_a_best_guess_with_the_same_pose(room: GridMap, tmp_path: Path) -> None:
    # The box of the test above hides a fifth of the scan: the fix is right and scores well, but the map
    # explains under 0.9 of the scan there, so the node does not stand behind it; the pose is the same.
    truth = np.array([2.5, 2.1, 0.4])
    scan = _scan_with_unmapped_box(room, truth)
    estimates, localizers = {}, {}
    for share in (0.9, 0.0):
        localizers[share] = PilLocalizer(_settings(tmp_path, localized_min_explained=share))
        localizers[share].set_map(room)
        estimates[share] = localizers[share].global_fix(scan)
    assert estimates[0.0].status is LocalizerStatus.LOCALIZED
    assert estimates[0.9].status is LocalizerStatus.AMBIGUOUS
    np.testing.assert_allclose(estimates[0.9].pose, estimates[0.0].pose)
    assert _pose_error(estimates[0.9].pose, truth)[0] < 0.2
    assert localizers[0.9].global_fix(_scan(room, truth)).status is LocalizerStatus.LOCALIZED
