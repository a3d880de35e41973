"""PIL's success rate over a map, as the paper's section 4 measures it (figure 8, top right).

The paper puts the simulated robot at random known poses, searches a 4 m square
window around it and counts a success when the selected place is within 20 cm.
Here: ``--positions`` free positions drawn uniformly on the map, ``--headings``
random headings at each, one simulated scan per pose (the shared ray caster,
Gaussian range noise ``--noise``), each localized alone by PIL

* ``window``: after :meth:`set_initial_pose` at the truth, so the search is the
  ``window_size`` square around it (the paper's setting);
* ``whole map``: :meth:`global_fix`, no window (a global start, a kidnapping).

for each profile asked (``ours``: ``config/pil_localizer.yaml``; ``paper``:
``config/pil_localizer_paper.yaml``). Rows give the success rate (position
error <= 0.2 m), the share of positions at >= 80 % and < 50 % success (the
paper's red and blue areas) and the fix time; ``--plot`` draws the map with
each position coloured by its success rate.

    python -m robot_localization_suite.tools.pil_success --map config/maps/office.yaml --plot docs/pil_success_office.png
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .. import registry
from ..core.grid_map import GridMap, load_map_yaml
from ..core.raycast import RayCaster
from ..core.scan import Scan

__all__ = ["SuccessRow", "measure", "main"]

PROFILES = {"ours": "pil_localizer.yaml", "paper": "pil_localizer_paper.yaml"}
SEARCHES = ("window", "whole map")
SUCCESS_M = 0.2  # the paper's criterion (figure 8: "error < 20cm")


@dataclass(frozen=True)
class SuccessRow:
    """One profile and search over every pose: per-position success rates and the fix times."""

    profile: str
    search: str
    position_success: NDArray[np.float64]  # (P,) share of the headings localized within SUCCESS_M
    fix_ms: NDArray[np.float64]

    @property
    def success_rate(self) -> float:
        return float(self.position_success.mean())


def simulated_scans(grid_map: GridMap, poses: NDArray[np.float64], *, beams: int, max_range: float, noise: float,
                    rng: np.random.Generator) -> list[Scan]:
    """One 360-degree scan per pose ``(N, 3)``; no return beyond ``max_range``."""
    angles = np.linspace(-math.pi, math.pi, beams, endpoint=False, dtype=np.float64)
    caster = RayCaster(grid_map, max_range=max_range)
    scans = []
    for k, pose in enumerate(poses):
        ranges = caster.cast(pose, angles).astype(np.float64)
        hit = np.isfinite(ranges) & (ranges < max_range)
        ranges[hit] += rng.normal(0.0, noise, int(hit.sum()))
        ranges[~hit] = np.inf
        scans.append(Scan(float(k), angles, ranges, 0.05, max_range))
    return scans


def measure(grid_map: GridMap, profile: str, poses: NDArray[np.float64], scans: Sequence[Scan], headings: int,
            cache_dir: str | None = None) -> list[SuccessRow]:
    """Both searches of one profile over ``poses`` (``headings`` consecutive poses per position)."""
    plugin = registry.plugin("pil_localizer")
    overrides = {"show_progress": False, **({"cache_dir": cache_dir} if cache_dir else {})}
    _, settings = plugin.load_settings(overrides, params_file=registry.config_dir() / PROFILES[profile])
    pil = plugin.create(settings)
    pil.set_map(grid_map)
    pil.prepare(scans[0])
    rows = []
    for search in SEARCHES:
        good, times = np.zeros(len(poses), dtype=bool), np.zeros(len(poses))
        for k, (pose, scan) in enumerate(zip(poses, scans, strict=True)):
            start = time.perf_counter()
            if search == "window":
                pil.set_initial_pose(pose, np.eye(3))
                estimate = pil.on_scan(scan)
            else:
                estimate = pil.global_fix(scan)
            times[k] = 1000.0 * (time.perf_counter() - start)
            good[k] = bool(np.all(np.isfinite(estimate.pose))
                           and math.hypot(*(estimate.pose[:2] - pose[:2])) <= SUCCESS_M)
        rows.append(SuccessRow(profile, search, good.reshape(-1, headings).mean(axis=1), times))
    return rows


def format_table(rows: Sequence[SuccessRow]) -> str:
    lines = ["| profile | search | success rate | positions >= 80 % | positions < 50 % | fix median [ms] |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row.profile} | {row.search} | {row.success_rate:.3f} | "
                     f"{np.mean(row.position_success >= 0.8):.3f} | {np.mean(row.position_success < 0.5):.3f} | "
                     f"{np.median(row.fix_ms):.1f} |")
    return "\n".join(lines)


def plot(grid_map: GridMap, positions: NDArray[np.float64], rows: Sequence[SuccessRow], path: Path) -> None:
    """The map once per row, each position coloured by its success rate (red >= 0.8, blue < 0.5, as the paper)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap

    from .map_plots import save_figure, show_map

    colours, norm = ListedColormap(["tab:blue", "gold", "tab:red"]), BoundaryNorm([0.0, 0.5, 0.8, 1.01], 3)
    figure, axes = plt.subplots(1, len(rows), figsize=(4.5 * len(rows), 4.5), squeeze=False)
    for ax, row in zip(axes[0], rows, strict=True):
        show_map(ax, grid_map)
        ax.scatter(positions[:, 0], positions[:, 1], c=row.position_success, cmap=colours, norm=norm, s=9)
        ax.set_title(f"{row.profile}, {row.search}: {row.success_rate:.2f}", fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    figure.suptitle("PIL success (error <= 0.2 m): red >= 80 %, yellow 50-80 %, blue < 50 %", fontsize=10)
    figure.tight_layout()
    save_figure(figure, path)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="pil_success", description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", type=Path, default=Path("config/maps/office.yaml"), help="map YAML")
    parser.add_argument("--positions", type=int, default=200, help="free positions drawn on the map")
    parser.add_argument("--headings", type=int, default=3, help="random headings at each position")
    parser.add_argument("--beams", type=int, default=360, help="beams of the simulated 360-degree scanner")
    parser.add_argument("--max-range", type=float, default=10.0, help="scanner range [m]")
    parser.add_argument("--noise", type=float, default=0.01, help="range noise standard deviation [m]")
    parser.add_argument("--profiles", nargs="+", default=list(PROFILES), choices=list(PROFILES))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cache-dir", default=None, help="PIL's learning cache (default: the package's)")
    parser.add_argument("--plot", type=Path, default=None, help="write the success map here (PNG)")
    args = parser.parse_args(argv)
    if args.positions < 1 or args.headings < 1:
        parser.error(f"--positions and --headings must be >= 1, got {args.positions} and {args.headings}")
    grid_map = load_map_yaml(args.map)
    rng = np.random.default_rng(args.seed)
    positions = grid_map.sample_free_poses(args.positions, rng)
    poses = np.repeat(positions, args.headings, axis=0)
    poses[:, 2] = rng.uniform(-math.pi, math.pi, len(poses))
    scans = simulated_scans(grid_map, poses, beams=args.beams, max_range=args.max_range, noise=args.noise, rng=rng)
    rows = [row for profile in args.profiles for row in measure(grid_map, profile, poses, scans, args.headings,
                                                                args.cache_dir)]
    print(f"{args.map}: {args.positions} positions x {args.headings} headings, {args.beams} beams, "
          f"range {args.max_range:g} m, noise {args.noise:g} m, seed {args.seed}")
    print(format_table(rows))
    if args.plot is not None:
        plot(grid_map, positions, rows, args.plot)
        print(f"written: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
