"""Measure the ray caster: rays per second on one core and on all cores.

The reference case of the foundation issue: a 20 m x 20 m office-like map at
5 cm, 10 m maximum range, random free poses, 360 beams each.

    raycast_benchmark [--map MAP_YAML] [--poses 5000] [--beams 360] [--max-range 10]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from ..core.grid_map import GridMap, load_map_yaml
from ..core.raycast import RayCaster


def synthetic_office(size_m: float = 20.0, resolution: float = 0.05, seed: int = 0) -> GridMap:
    """Outer walls, a grid of inner walls with doors, and scattered boxes."""
    cells = int(round(size_m / resolution))
    data = np.zeros((cells, cells), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    rng = np.random.default_rng(seed)
    for k in range(1, 4):
        wall = k * cells // 4
        data[wall : wall + 2, :] = 100
        data[:, wall : wall + 2] = 100
        for door in rng.integers(10, cells - 30, size=3):
            data[wall : wall + 2, door : door + 20] = 0
            data[door : door + 20, wall : wall + 2] = 0
    for _ in range(40):
        x, y = rng.integers(5, cells - 15, size=2)
        data[y : y + 8, x : x + 8] = 100
    return GridMap(data, resolution, (0.0, 0.0))


def measure(caster: RayCaster, poses: np.ndarray, angles: np.ndarray, parallel: bool, repeats: int = 3) -> float:
    caster.cast(poses[:10], angles, parallel=parallel)  # compile outside the timing
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        caster.cast(poses, angles, parallel=parallel)
        best = min(best, time.perf_counter() - start)
    return poses.shape[0] * angles.shape[0] / best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--map", help="nav2 map YAML (default: a synthetic 20 m x 20 m office at 5 cm)")
    parser.add_argument("--poses", type=int, default=5000)
    parser.add_argument("--beams", type=int, default=360)
    parser.add_argument("--max-range", type=float, default=10.0)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    grid_map = load_map_yaml(args.map) if args.map else synthetic_office()
    caster = RayCaster(grid_map, max_range=args.max_range)
    poses = grid_map.sample_free_poses(args.poses, np.random.default_rng(1))
    angles = np.linspace(-np.pi, np.pi, args.beams, endpoint=False)
    result = {
        "map_cells": [grid_map.width, grid_map.height],
        "resolution_m": grid_map.resolution,
        "max_range_m": args.max_range,
        "rays": args.poses * args.beams,
        "rays_per_s_one_core": measure(caster, poses, angles, parallel=False),
        "rays_per_s_all_cores": measure(caster, poses, angles, parallel=True),
        "cores": os.cpu_count(),
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"{result['map_cells'][0]} x {result['map_cells'][1]} cells at {grid_map.resolution} m, "
            f"max range {args.max_range} m, {result['rays']} rays\n"
            f"  one core : {result['rays_per_s_one_core'] / 1e6:.2f} M rays/s\n"
            f"  all cores: {result['rays_per_s_all_cores'] / 1e6:.2f} M rays/s ({result['cores']} cores)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
