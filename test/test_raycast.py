"""The ray caster (core/raycast.py) against analytic distances in a rectangular room."""

from __future__ import annotations

import numpy as np
import pytest

from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.raycast import (
    RAY_FREE,
    RAY_HIT,
    RAY_UNKNOWN,
    ClassifiedRayCaster,
    RayCaster,
    cast_rays,
)

RESOLUTION = 0.05
# A 10 m x 6 m map whose outermost ring of cells is wall: the free interior spans
# x in [0.05, 9.95] and y in [0.05, 5.95] (the inner faces of the walls).
WIDTH_CELLS, HEIGHT_CELLS = 200, 120
INNER = (RESOLUTION, WIDTH_CELLS * RESOLUTION - RESOLUTION, RESOLUTION, HEIGHT_CELLS * RESOLUTION - RESOLUTION)


def rectangular_room() -> GridMap:
    data = np.zeros((HEIGHT_CELLS, WIDTH_CELLS), dtype=np.int8)
    data[0, :] = data[-1, :] = data[:, 0] = data[:, -1] = 100
    return GridMap(data, RESOLUTION, (0.0, 0.0))


def analytic_range(pose: np.ndarray, angle: float) -> float:
    """Distance from ``pose`` along ``pose.theta + angle`` to the nearest inner wall face."""
    x_min, x_max, y_min, y_max = INNER
    heading = pose[2] + angle
    dx, dy = np.cos(heading), np.sin(heading)
    candidates = []
    if dx > 1e-12:
        candidates.append((x_max - pose[0]) / dx)
    if dx < -1e-12:
        candidates.append((x_min - pose[0]) / dx)
    if dy > 1e-12:
        candidates.append((y_max - pose[1]) / dy)
    if dy < -1e-12:
        candidates.append((y_min - pose[1]) / dy)
    return min(candidates)


def test_ranges_match_the_room_within_one_cell() -> None:
    grid = rectangular_room()
    caster = RayCaster(grid, max_range=30.0)
    rng = np.random.default_rng(7)
    poses = np.column_stack(
        [rng.uniform(0.5, 9.5, 200), rng.uniform(0.5, 5.5, 200), rng.uniform(-np.pi, np.pi, 200)]
    )
    angles = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    ranges = caster.cast(poses, angles)
    assert ranges.shape == (200, 90) and ranges.dtype == np.float32
    expected = np.array([[analytic_range(p, a) for a in angles] for p in poses])
    error = np.abs(ranges - expected)
    assert error.max() <= RESOLUTION
    # The caster stops where the ray enters the wall cell, which is the analytic face: far better than a cell.
    assert np.median(error) < 1e-4


def test_axis_aligned_rays_from_the_room_centre() -> None:
    caster = RayCaster(rectangular_room(), max_range=30.0)
    pose = np.array([5.0, 3.0, 0.0])
    ranges = caster.cast(pose, [0.0, np.pi / 2, np.pi, -np.pi / 2])
    # Single pose -> (B,): 4.95 m to the east and west faces, 2.95 m to the north and south ones.
    assert ranges.shape == (4,)
    np.testing.assert_allclose(ranges, [4.95, 2.95, 4.95, 2.95], atol=1e-4)


def test_no_hit_is_inf() -> None:
    open_map = GridMap(np.zeros((100, 100), np.int8), RESOLUTION)
    caster = RayCaster(open_map, max_range=3.0)
    # Leaving the map without a hit: inf, never a magic range.
    assert np.all(np.isinf(caster.cast(np.array([2.5, 2.5, 0.0]), np.linspace(-np.pi, np.pi, 8))))
    # A wall beyond max_range is not reported either.
    room = RayCaster(rectangular_room(), max_range=2.0)
    ranges = room.cast(np.array([5.0, 3.0, 0.0]), [0.0, np.pi / 2])
    assert np.isinf(ranges).all()
    # ... but one just inside max_range is.
    assert np.isfinite(RayCaster(rectangular_room(), max_range=3.0).cast(np.array([5.0, 3.0, np.pi / 2]), [0.0]))[0]


def test_start_inside_an_obstacle_is_zero_and_off_map_is_inf() -> None:
    caster = RayCaster(rectangular_room(), max_range=30.0)
    inside_wall = np.array([0.02, 3.0, 0.0])
    np.testing.assert_array_equal(caster.cast(inside_wall, [0.0, 1.0, 2.0]), [0.0, 0.0, 0.0])
    off_map = np.array([-1.0, 3.0, 0.0])
    assert np.isinf(caster.cast(off_map, [0.0])).all()


def test_unknown_cells_block_only_when_asked() -> None:
    data = np.zeros((40, 40), np.int8)
    data[:, 30] = -1  # an unknown column at x = 1.5 m
    data[:, 39] = 100  # a wall at x = 1.95 m
    grid = GridMap(data, RESOLUTION)
    pose = np.array([0.5, 1.0, 0.0])
    assert RayCaster(grid, max_range=5.0).cast(pose, [0.0])[0] == pytest.approx(1.45, abs=1e-4)
    assert RayCaster(grid, max_range=5.0, unknown_blocks=True).cast(pose, [0.0])[0] == pytest.approx(1.0, abs=1e-4)


def test_parallel_equals_serial() -> None:
    grid = rectangular_room()
    data = grid.data.copy()
    rng = np.random.default_rng(3)
    for x, y in rng.integers(5, 110, size=(60, 2)):
        data[y : y + 4, x : x + 4] = 100  # clutter, so that rays end at many different cells
    cluttered = GridMap(data, RESOLUTION)
    poses = cluttered.sample_free_poses(300, rng)
    angles = np.linspace(-np.pi, np.pi, 181)
    caster = RayCaster(cluttered, max_range=8.0)
    serial = caster.cast(poses, angles, parallel=False)
    parallel = caster.cast(poses, angles, parallel=True)
    np.testing.assert_array_equal(serial, parallel)
    # The free function gives the same answer from a raw mask.
    direct = cast_rays(cluttered.occupied_mask, RESOLUTION, (0.0, 0.0), poses, angles, 8.0, parallel=False)
    np.testing.assert_array_equal(direct, serial)


def test_bad_max_range_is_refused() -> None:
    with pytest.raises(ValueError, match="max_range.*-1"):
        cast_rays(np.zeros((2, 2), bool), 0.1, (0.0, 0.0), np.zeros(3), [0.0], -1.0)


def test_skipping_free_space_gives_the_same_ranges() -> None:
    rng = np.random.default_rng(5)
    data = np.zeros((160, 220), dtype=np.int8)
    data[rng.random(data.shape) < 0.004] = 100  # sparse posts: long open stretches to jump through
    data[rng.random(data.shape) < 0.02] = -1
    data[60:62, 20:180] = 100
    grid = GridMap(data, RESOLUTION, (0.3, -1.7))
    # Continuous poses and angles, so that no ray runs exactly through a cell corner (a tie either side may take).
    poses = np.column_stack([rng.uniform(0.3, 11.3, 400), rng.uniform(-1.7, 6.3, 400), rng.uniform(-np.pi, np.pi, 400)])
    angles = np.linspace(-np.pi, np.pi, 181) + 0.0123
    for unknown_blocks in (False, True):
        plain = RayCaster(grid, max_range=9.0, unknown_blocks=unknown_blocks).cast(poses, angles)
        skipping = RayCaster(grid, max_range=9.0, unknown_blocks=unknown_blocks, skip_free_space=True)
        np.testing.assert_allclose(skipping.cast(poses, angles, parallel=False), plain, rtol=0, atol=1e-4)
        np.testing.assert_allclose(skipping.cast(poses, angles, parallel=True), plain, rtol=0, atol=1e-4)


# -- rays that say how they ended ----------------------------------------------------------------
def _cluttered_map_with_unknown(seed: int) -> GridMap:
    """Walls, scattered obstacles and unknown specks, an unknown block and an open map edge."""
    rng = np.random.default_rng(seed)
    data = np.zeros((160, 240), dtype=np.int8)
    data[rng.random(data.shape) < 0.004] = 100
    data[rng.random(data.shape) < 0.003] = -1
    data[60:100, 120:170] = -1
    data[:, :2] = 100  # one wall; the other three edges are open
    return GridMap(data, RESOLUTION, (-2.0, 1.0))


@pytest.mark.parametrize("seed", [1, 2])
def test_classified_rays_agree_with_the_plain_caster(seed: int) -> None:
    grid = _cluttered_map_with_unknown(seed)
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.uniform(-2, 10, 400), rng.uniform(1, 9, 400), rng.uniform(-np.pi, np.pi, 400)])
    # Not exactly diagonal: a ray through a cell corner may enter either neighbour first.
    angles = np.linspace(-np.pi, np.pi, 91, endpoint=False) + 0.01
    occupied = RayCaster(grid, max_range=6.0).cast(poses, angles)
    non_free = RayCaster(grid, max_range=6.0, unknown_blocks=True).cast(poses, angles)
    x_min, x_max, y_min, y_max = grid.extent

    # Unknown cells stop the ray: a hit is the first non-free cell when it is occupied.
    ranges, outcome = ClassifiedRayCaster(grid, max_range=6.0, unknown_stops=True).cast(poses, angles)
    hit = outcome == RAY_HIT
    np.testing.assert_allclose(ranges[hit], non_free[hit], atol=1e-4)
    np.testing.assert_allclose(ranges[hit], occupied[hit], atol=1e-4)
    assert np.all(np.isinf(non_free[outcome == RAY_FREE]))  # free: nothing at all within range

    # Unknown cells are crossed: the hit is the plain caster's; no hit after an unknown cell, or
    # leaving the map, is unknown; no hit through free cells only is free.
    ranges, outcome = ClassifiedRayCaster(grid, max_range=6.0, unknown_stops=False).cast(poses, angles)
    hit = outcome == RAY_HIT
    assert hit.sum() > 1000 and (outcome == RAY_FREE).sum() > 1000 and (outcome == RAY_UNKNOWN).sum() > 1000
    np.testing.assert_allclose(ranges[hit], occupied[hit], atol=1e-4)
    assert np.all(np.isinf(occupied[~hit]))
    heading = poses[:, 2:3] + angles[None, :]
    end_x, end_y = poses[:, :1] + 6.0 * np.cos(heading), poses[:, 1:2] + 6.0 * np.sin(heading)
    leaves = (end_x < x_min) | (end_x >= x_max) | (end_y < y_min) | (end_y >= y_max)
    expected_unknown = ~hit & (np.isfinite(non_free) | leaves)
    np.testing.assert_array_equal(outcome == RAY_UNKNOWN, expected_unknown)


def test_classified_rays_jump_through_open_space_without_missing_a_thin_obstacle() -> None:
    data = np.zeros((400, 400), dtype=np.int8)
    data[:, 300] = 100  # a one-cell wall at x = 15 m, 10 m from the rays' origin, in a 20 m open square
    grid = GridMap(data, RESOLUTION)
    angles = np.linspace(-0.7, 0.7, 201)  # all reach the wall before the map's edge at y = 0 or 20 m
    ranges, outcome = ClassifiedRayCaster(grid, max_range=30.0).cast(np.array([5.0, 10.0, 0.0]), angles)
    assert np.all(outcome == RAY_HIT)
    np.testing.assert_allclose(ranges, 10.0 / np.cos(angles), rtol=1e-6, atol=1e-4)
    # Off the map from the start, or starting in an unknown cell that stops rays: unknown.
    assert ClassifiedRayCaster(grid, max_range=5.0).cast(np.array([-1.0, 1.0, 0.0]), [0.0])[1][0] == RAY_UNKNOWN
