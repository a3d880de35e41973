"""Measure interval-analysis localization: first global iteration, tracking iteration, codac vs numba.

    python -m robot_localization_suite.tools.ial_benchmark [--map config/maps/office.yaml]
        [--trials 10] [--beams 36] [--range-error 0.05] [--outliers 5] [--seed 0] [--codac]

For each trial a free laser pose is drawn on the map, a 360-beam scan is cast
with the shared ray caster, each reading gets uniform noise inside
``+-range_error`` (rounded to float32 as a LaserScan carries it), and
``--outliers`` of the ``--beams`` readings IAL uses are replaced by random
ranges. Measured (wall time, best of the run):

* ``global``: one iteration of Algorithm 1 from the whole map x [-pi, pi]
  (:meth:`IntervalLocalizer.global_fix`), whether its boxes contain the truth, and the half widths of the
  box holding it (the paper's Table 1 precision);
* ``tracking``: one iteration from a 0.5 m x 0.5 m x 10 degree box that
  contains the truth (the setting of the paper's section 5.2);
* ``numba_box``: one contraction of a tracking-size box by every beam with
  :func:`..core.ial_kernels.contract_box`, timed over 200 boxes in one call;
* ``--codac``: the same forward-backward contraction written with codac 2.x
  (one ``CtcInverse`` per beam over ``[x, y, theta, w1, w2]``, built once per
  scan; our summed-area table for the obstacle hull; the q-intersection in numpy). codac is not a dependency
  of the package: ``pip install codac==2.1.2`` to run this part.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numba
import numpy as np

from ..core.errors import MapError
from ..core.grid_map import GridMap, load_map_yaml
from ..core.ial.kernels import contract_box, obstacle_hull
from ..core.ial.localizer import IALSettings, IntervalLocalizer, ObstacleGrid, beam_intervals
from ..core.metrics import boxes_contain
from ..core.raycast import RayCaster
from ..core.scan import Scan

__all__ = ["simulate_scan", "measure", "codac_contractors", "codac_contract_box", "main"]


def simulate_scan(
    grid_map: GridMap,
    pose: np.ndarray,
    rng: np.random.Generator,
    *,
    range_error: float,
    outliers: int,
    used_beams: int,
    range_max: float = 12.0,
    beams: int = 360,
) -> Scan:
    """A bounded-noise scan from ``pose`` with ``outliers`` corrupted readings among the ``used_beams`` used."""
    angles = -math.pi + 2.0 * math.pi * np.arange(beams) / beams
    exact = RayCaster(grid_map, max_range=range_max).cast(pose, angles).astype(np.float64)
    ranges = exact + rng.uniform(-range_error, range_error, beams)
    ranges[~np.isfinite(exact)] = np.inf
    valid = np.flatnonzero(np.isfinite(ranges) & (ranges > 0.1) & (ranges < range_max))
    used = valid[np.unique(np.round(np.linspace(0, valid.size - 1, min(used_beams, valid.size))).astype(np.int64))]
    corrupt = rng.choice(used, size=min(outliers, used.size), replace=False)
    ranges[corrupt] = rng.uniform(0.2, range_max - 0.5, corrupt.size)
    return Scan(0.0, angles, ranges.astype(np.float32).astype(np.float64), 0.1, range_max)


def codac_contractors(angles, range_lo, range_hi) -> list:
    """One codac 2.x ``CtcInverse`` per beam over ``[x, y, theta, w1, w2]`` (built once per scan)."""
    import codac

    contractors = []
    for gamma, lo, hi in zip(angles, range_lo, range_hi, strict=True):
        v = codac.VectorVar(5)
        r = codac.Interval(float(lo), float(hi))
        f = codac.AnalyticFunction(
            [v], codac.vec(v[3] - v[0] - r * codac.cos(v[2] + float(gamma)), v[4] - v[1] - r * codac.sin(v[2] + float(gamma)))
        )
        contractors.append(codac.CtcInverse(f, codac.IntervalVector([[0.0, 0.0], [0.0, 0.0]])))
    return contractors


def codac_contract_box(box: np.ndarray, contractors: list, max_outliers: int, grid: ObstacleGrid) -> bool:
    """One forward-backward contraction of ``box`` by every beam with codac 2.x; False if empty."""
    import codac

    per_beam = []
    res = grid.resolution
    for ctc in contractors:
        b = codac.IntervalVector([[box[0], box[1]], [box[2], box[3]], [box[4], box[5]], [-1e9, 1e9], [-1e9, 1e9]])
        ctc.contract(b)  # forward: [w]
        if b.is_empty():
            continue
        c0 = int(math.floor((b[3].lb() - grid.origin[0]) / res))
        c1 = int(math.floor((b[3].ub() - grid.origin[0]) / res))
        r0 = int(math.floor((b[4].lb() - grid.origin[1]) / res))
        r1 = int(math.floor((b[4].ub() - grid.origin[1]) / res))
        found, hc0, hc1, hr0, hr1 = obstacle_hull(grid.sat, c0, c1, r0, r1)
        if not found:
            continue
        b[3] &= codac.Interval(grid.origin[0] + hc0 * res, grid.origin[0] + (hc1 + 1) * res)
        b[4] &= codac.Interval(grid.origin[1] + hr0 * res, grid.origin[1] + (hr1 + 1) * res)
        ctc.contract(b)  # backward to the pose
        if not b.is_empty():
            per_beam.append([b[0].lb(), b[0].ub(), b[1].lb(), b[1].ub(), b[2].lb(), b[2].ub()])
    required = len(contractors) - max_outliers
    if len(per_beam) < required:
        return False
    bounds = np.array(per_beam)
    lower = np.sort(bounds[:, 0::2], axis=0)[required - 1]
    upper = -np.sort(-bounds[:, 1::2], axis=0)[required - 1]
    return bool(np.all(lower <= upper))


@numba.njit(cache=True)
def _contract_batch(boxes, angles, range_lo, range_hi, outliers, sat, free_sat, certain_sat, samples, ox, oy, res,
                    margin):
    n = angles.shape[0]
    scratch, beam_ok, top = np.empty((n, 12)), np.empty(n, dtype=np.bool_), np.empty((6, outliers + 1))
    kept = 0
    for k in range(boxes.shape[0]):
        box = boxes[k].copy()
        if contract_box(box, angles, range_lo, range_hi, outliers, sat, free_sat, certain_sat, samples, ox, oy, res,
                        margin, scratch, beam_ok, top) >= 0:
            kept += 1
    return kept


def _contract_many(boxes, angles, range_lo, range_hi, outliers, grid, settings) -> int:
    return _contract_batch(boxes, angles, range_lo, range_hi, outliers, grid.sat, grid.free_sat, grid.certain_sat,
                           settings.free_space_samples, grid.origin[0], grid.origin[1], grid.resolution,
                           settings.map_margin)


def measure(grid_map: GridMap, *, trials: int, beams: int, range_error: float, outliers: int, seed: int,
            with_codac: bool) -> dict[str, list[float]]:
    """Run the trials; returns lists of timings [s] and outcomes."""
    rng = np.random.default_rng(seed)
    settings = IALSettings(max_beams=beams, max_outliers=outliers, range_error=range_error)
    localizer = IntervalLocalizer(settings, grid_map)
    results: dict[str, list[float]] = {k: [] for k in ("global_s", "global_boxes", "global_contains",
                                                          "global_half_x", "global_half_y", "global_half_theta",
                                                          "tracking_s", "tracking_contains", "numba_box_s",
                                                          "codac_box_s")}
    warm = simulate_scan(grid_map, grid_map.sample_free_poses(1, rng)[0], rng, range_error=range_error,
                         outliers=outliers, used_beams=beams)
    localizer.global_fix(warm)  # compile (cached on disk after the first run)
    for _ in range(trials):
        pose = grid_map.sample_free_poses(1, rng)[0]
        scan = simulate_scan(grid_map, pose, rng, range_error=range_error, outliers=outliers, used_beams=beams)
        start = time.perf_counter()
        estimate = localizer.global_fix(scan)
        results["global_s"].append(time.perf_counter() - start)
        results["global_boxes"].append(estimate.details["box_count"])
        results["global_contains"].append(estimate.boxes is not None and boxes_contain(estimate.boxes, pose))
        if estimate.boxes is not None and len(estimate.boxes):
            # precision as the paper's Table 1 gives it: half the widths of the box holding the truth
            boxes = np.asarray(estimate.boxes, dtype=np.float64).reshape(-1, 3, 2)
            holding = [box for box in boxes if boxes_contain(box[None], pose)]
            if holding:
                half = 0.5 * (holding[0][:, 1] - holding[0][:, 0])
                for key, value in zip(("global_half_x", "global_half_y", "global_half_theta"), half, strict=True):
                    results[key].append(float(value))

        offset = rng.uniform(-0.5, 0.5, 3) * np.array([0.5, 0.5, math.radians(10.0)])
        centre = pose + offset
        box = np.array([[centre[0] - 0.25, centre[0] + 0.25, centre[1] - 0.25, centre[1] + 0.25,
                         centre[2] - math.radians(5.0), centre[2] + math.radians(5.0)]])
        angles, range_lo, range_hi = beam_intervals(scan, range_error=range_error, max_beams=beams)
        start = time.perf_counter()
        result = localizer.iterate(box, angles, range_lo, range_hi)
        results["tracking_s"].append(time.perf_counter() - start)
        results["tracking_contains"].append(boxes_contain(result.boxes, pose))

        # One contraction per box, many boxes per call: the per-box cost without Python's dispatch.
        grid = localizer.obstacles
        if grid is None:  # built by IntervalLocalizer(settings, grid_map) above
            raise MapError("the interval localizer has no obstacle grid although it was given a map")
        probes = box + rng.uniform(-0.02, 0.02, (200, 6))
        probes[:, 0::2], probes[:, 1::2] = np.minimum(probes[:, 0::2], probes[:, 1::2]), np.maximum(
            probes[:, 0::2], probes[:, 1::2])
        start = time.perf_counter()
        _contract_many(probes, angles, range_lo, range_hi, outliers, grid, settings)
        results["numba_box_s"].append((time.perf_counter() - start) / len(probes))
        if with_codac:
            contractors = codac_contractors(angles, range_lo, range_hi)
            start = time.perf_counter()
            for probe in probes[:20]:
                codac_contract_box(probe, contractors, outliers, grid)
            results["codac_box_s"].append((time.perf_counter() - start) / 20)
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ial_benchmark", description=__doc__.split("\n\n")[0])
    root = Path(__file__).resolve().parents[2]
    parser.add_argument("--map", default=str(root / "config" / "maps" / "office.yaml"), help="nav2 map YAML")
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--beams", type=int, default=36)
    parser.add_argument("--range-error", type=float, default=0.05)
    parser.add_argument("--outliers", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--codac", action="store_true", help="also time the codac 2.x contractor (pip install codac)")
    args = parser.parse_args(argv)
    grid_map = load_map_yaml(args.map)
    results = measure(grid_map, trials=args.trials, beams=args.beams, range_error=args.range_error,
                      outliers=args.outliers, seed=args.seed, with_codac=args.codac)

    def stats(name: str, scale: float = 1e3, unit: str = "ms") -> str:
        values = np.asarray(results[name], dtype=np.float64) * scale
        if values.size == 0:
            return f"{name}: -"
        return f"{name}: median {np.median(values):.3g} {unit}, min {values.min():.3g}, max {values.max():.3g}"

    print(f"map {args.map}: {grid_map.width} x {grid_map.height} cells at {grid_map.resolution} m; "
          f"{args.beams} beams, eps {args.range_error} m, {args.outliers} outliers, {args.trials} trials")
    print(stats("global_s"))
    print(f"global_boxes: median {np.median(results['global_boxes']):.0f}, max {np.max(results['global_boxes']):.0f}; "
          f"contains truth {int(np.sum(results['global_contains']))}/{args.trials}")
    if results["global_half_x"]:
        print(f"global box holding the truth, half widths (median): x +-{1000 * np.median(results['global_half_x']):.0f} mm, "
              f"y +-{1000 * np.median(results['global_half_y']):.0f} mm, "
              f"theta +-{math.degrees(float(np.median(results['global_half_theta']))):.2f} deg")
    print(stats("tracking_s") + f"; contains truth {int(np.sum(results['tracking_contains']))}/{args.trials}")
    print(stats("numba_box_s", 1e6, "us"))
    if args.codac:
        print(stats("codac_box_s", 1e6, "us"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
