"""Turn a corrected CARMEN log into a rosbag2 MCAP bag and an occupancy map.

    carmen_to_bag LOG OUT_DIR [--map-out MAP_YAML] [--alpha1 A] ... [--seed S] [--resolution 0.05]
    carmen_to_bag LOG OUT_DIR --blocks K [--name NAME]     (cross-validation split, tools/carmen_cv.py)

Input: a (gzipped) corrected CARMEN log (Radish datasets); only the front laser's ``FLASER`` or
``ROBOTLASER1`` lines are used (``tools/carmen_log.py`` parses them and chooses the stamps). Output: ``/map`` once, then per scan
``/odom`` (the corrected trajectory through the seeded odometry noise model), ``/ground_truth``
(the corrected pose) and ``/scan``. The map is a 5 cm log-odds occupancy grid built from the scans
at the corrected poses. Every choice the logs leave open (beam geometry, no-returns, time,
odometry noise, map building): docs/real_logs.md.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
from numpy.typing import NDArray

from ..core.errors import LocalizationSuiteError
from ..core.grid_map import MIN_RESOLUTION_M, GridMap
from ..core.motion import ODOMETRY_NOISE_KEY, OdometryMotionModel, declare_odometry_noise, odometry_delta
from .carmen_log import (
    MIN_STAMP_STEP_S,
    CarmenLog,
    CarmenLogError,
    CarmenScan,
    _report_to_stderr,
    assign_stamps,
    beam_geometry,
    choose_stamps,
    detect_max_range,
    parse_carmen_log,
    scan_geometry,
)

__all__ = [
    "CarmenLogError",
    "CarmenScan",
    "CarmenLog",
    "ConversionSettings",
    "ConversionReport",
    "PreparedLog",
    "parse_carmen_log",
    "beam_geometry",
    "detect_max_range",
    "assign_stamps",
    "choose_stamps",
    "simulate_odometry",
    "build_occupancy_map",
    "prepare_log",
    "build_log_map",
    "write_bag",
    "convert_log",
    "main",
]

# Log-odds of one observation (Thrun et al., Probabilistic Robotics, table 9.1 / 9.2):
# p(occ | hit) = 0.7, p(occ | beam passed) = 0.4, and the clamp of long-lived maps.
LOG_ODDS_HIT = math.log(0.7 / 0.3)
LOG_ODDS_MISS = math.log(0.4 / 0.6)
LOG_ODDS_MIN, LOG_ODDS_MAX = -2.0, 3.5

DEFAULT_ALPHAS = (1.2e-3, 1e-4, 4e-4, 1e-4)  # alpha1..alpha4, see the module docstring
# A bag holds scan stamps from 4 us (/map, /odom and /ground_truth are logged up to 4 us before their scan,
# and log times are unsigned) to the last whole second of a ROS time's int32 seconds.
_MICROSECOND_NS = 1000
MIN_STAMP_S = 4 * _MICROSECOND_NS * 1e-9
MAX_STAMP_S = 2.0**31 - 1.0
MAX_RESOLUTION_M = 100.0  # --resolution: cells coarser than this hold no room
# A log whose map would have more cells is refused: 1 km^2 at 5 cm (14 times the Freiburg campus), ~5 GB to build.
MAX_MAP_CELLS = 400_000_000

def simulate_odometry(
    poses: NDArray[np.float64], model: OdometryMotionModel, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Odometry poses ``(N, 3)`` starting at the origin: each true step perturbed by ``model``."""
    poses = np.asarray(poses, dtype=np.float64)
    odom = np.zeros_like(poses)
    for i in range(1, poses.shape[0]):
        odom[i] = model.sample(odom[i - 1 : i], poses[i - 1], poses[i], rng)[0]
    return odom


@numba.njit(cache=True, nogil=True)
def _integrate_beams(log_odds, seen, x0, y0, x1, y1, endpoint_hit, miss, hit, lo, hi):  # pragma: no cover - compiled
    """Bresenham from cell (x0, y0) to (x1, y1), endpoint excluded: ``miss``; endpoint: ``hit`` or ``miss``."""
    height, width = log_odds.shape
    for k in range(x0.shape[0]):
        cx, cy, ex, ey = x0[k], y0[k], x1[k], y1[k]
        dx = abs(ex - cx)
        dy = -abs(ey - cy)
        sx = 1 if cx < ex else -1
        sy = 1 if cy < ey else -1
        err = dx + dy
        while cx != ex or cy != ey:
            if 0 <= cx < width and 0 <= cy < height:
                value = log_odds[cy, cx] + miss
                log_odds[cy, cx] = lo if value < lo else value
                seen[cy, cx] = True
            e2 = 2 * err
            if e2 >= dy:
                err += dy
                cx += sx
            if e2 <= dx:
                err += dx
                cy += sy
        if 0 <= ex < width and 0 <= ey < height:
            value = log_odds[ey, ex] + (hit if endpoint_hit[k] else miss)
            log_odds[ey, ex] = hi if value > hi else (lo if value < lo else value)
            seen[ey, ex] = True


def build_occupancy_map(
    poses: NDArray[np.float64],
    angle_sets: list[NDArray[np.float64]],
    range_sets: list[NDArray[np.float64]],
    max_range: float,
    *,
    resolution: float = 0.05,
    map_max_range: float = 40.0,
    margin: float = 1.0,
) -> GridMap:
    """Log-odds occupancy grid from scans at known laser poses (see the module docstring).

    Args:
        poses: ``(S, 3)`` laser poses in the map [m, m, rad].
        angle_sets, range_sets: per scan, beam angles [rad] and raw ranges [m].
        max_range: readings at or above it are no-returns [m].
        resolution: cell size [m].
        map_max_range: hits farther than this add no endpoint; free space is traced up to it [m].
        margin: free border around everything observed [m].
    """
    if resolution <= 0.0 or not np.isfinite(resolution):
        raise ValueError(f"map resolution must be positive, got {resolution!r}")
    starts, ends, hits = [], [], []
    for pose, angles, ranges in zip(poses, angle_sets, range_sets, strict=True):
        valid = np.isfinite(ranges) & (ranges > 0.0) & (ranges < max_range)
        is_hit = valid & (ranges <= map_max_range)
        length = np.where(is_hit, ranges, map_max_range)[valid]
        heading = pose[2] + angles[valid]
        end = np.stack([pose[0] + length * np.cos(heading), pose[1] + length * np.sin(heading)], axis=-1)
        starts.append(np.broadcast_to(pose[:2], end.shape))
        ends.append(end)
        hits.append(is_hit[valid])
    start_xy = np.concatenate(starts) if starts else np.zeros((0, 2))
    end_xy = np.concatenate(ends) if ends else np.zeros((0, 2))
    endpoint_hit = np.concatenate(hits) if hits else np.zeros(0, dtype=bool)

    # The map spans the trajectory and every hit; far free-space traces are clipped to it.
    extent_points = np.vstack([poses[:, :2], end_xy[endpoint_hit]])
    low = np.floor((extent_points.min(axis=0) - margin) / resolution) * resolution
    high = np.ceil((extent_points.max(axis=0) + margin) / resolution) * resolution
    cells = np.round((high - low) / resolution) + 1
    if float(np.prod(cells)) > MAX_MAP_CELLS:
        raise ValueError(f"the map would be {cells[0]:.0f} x {cells[1]:.0f} cells ({high[0] - low[0]:.6g} m x "
                         f"{high[1] - low[1]:.6g} m at {resolution!r} m), more than {MAX_MAP_CELLS}")
    width, height = cells.astype(np.int64).tolist()

    def to_cells(xy: NDArray[np.float64]) -> NDArray[np.int64]:
        return np.floor((xy - low) / resolution).astype(np.int64)

    start_cells, end_cells = to_cells(start_xy), to_cells(end_xy)
    log_odds = np.zeros((height, width), dtype=np.float32)
    seen = np.zeros((height, width), dtype=np.bool_)
    _integrate_beams(
        log_odds,
        seen,
        np.ascontiguousarray(start_cells[:, 0]),
        np.ascontiguousarray(start_cells[:, 1]),
        np.ascontiguousarray(end_cells[:, 0]),
        np.ascontiguousarray(end_cells[:, 1]),
        np.ascontiguousarray(endpoint_hit),
        np.float32(LOG_ODDS_MISS),
        np.float32(LOG_ODDS_HIT),
        np.float32(LOG_ODDS_MIN),
        np.float32(LOG_ODDS_MAX),
    )
    data = np.full((height, width), -1, dtype=np.int8)
    data[seen & (log_odds > 0.0)] = 100
    data[seen & (log_odds < 0.0)] = 0
    return GridMap(data, resolution, (float(low[0]), float(low[1])))


@dataclass(frozen=True)
class ConversionSettings:
    """Options of one conversion (defaults as in ``--help``).

    Attributes:
        alphas: Thrun odometry-model alpha1..alpha4 (variance scales, as nav2_amcl).
        seed: seed of the odometry noise.
        resolution: map cell size [m].
        period: scan period [s] used when the log has no usable timestamps.
        max_range: no-return threshold [m]; None: detect from the log.
        no_return_tolerance: readings within this of the log's largest reading are no-returns [m].
        map_max_range: hits used for the map up to this range [m].
    """

    alphas: tuple[float, float, float, float] = DEFAULT_ALPHAS
    seed: int = 0
    resolution: float = 0.05
    period: float = 1.0
    max_range: float | None = None
    no_return_tolerance: float = 0.1
    map_max_range: float = 40.0

    def __post_init__(self) -> None:
        if len(self.alphas) != 4 or not all(np.isfinite(a) and a >= 0.0 for a in self.alphas):
            raise ValueError(f"alpha1..alpha4 must be four finite values >= 0, got {self.alphas!r}")
        for name in ("resolution", "period", "map_max_range"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0.0:
                raise ValueError(f"{name} must be positive, got {value!r}")
        if self.max_range is not None and (not np.isfinite(self.max_range) or self.max_range <= 0.0):
            raise ValueError(f"max_range must be positive, got {self.max_range!r}")
        if not np.isfinite(self.no_return_tolerance) or self.no_return_tolerance < 0.0:
            raise ValueError(f"no_return_tolerance must be >= 0, got {self.no_return_tolerance!r}")


@dataclass(frozen=True)
class PreparedLog:
    """A parsed log with what every bag cut from it shares: stamps, truth, odometry, beams.

    Attributes:
        stamps: ``(S,)`` scan stamps [s]; ``stamp_source`` says where they come from.
        poses: ``(S, 3)`` corrected laser poses (the ground truth).
        odom: ``(S, 3)`` simulated odometry, one seeded stream over the whole log.
        max_range: no-return threshold [m].
        scan_time: median time between scans [s] (``LaserScan.scan_time``).
        odometry_model: the noise model ``odom`` was drawn from (declared in every bag cut from the log).
    """

    log: CarmenLog
    stamps: NDArray[np.float64]
    stamp_source: str
    stamp_warnings: tuple[str, ...]
    poses: NDArray[np.float64]
    odom: NDArray[np.float64]
    max_range: float
    scan_time: float
    odometry_model: OdometryMotionModel

    @property
    def scans(self) -> list[CarmenScan]:
        return self.log.scans

    def angles(self, index: int) -> NDArray[np.float64]:
        """Beam angles [rad] of scan ``index``."""
        angle_min, increment = scan_geometry(self.scans[index])
        return angle_min + increment * np.arange(self.scans[index].ranges.size, dtype=np.float64)


def _report_warning_to_stderr(message: str) -> None:
    print(f"carmen_to_bag: warning: timestamps: {message}", file=sys.stderr)


def _check_stamp_range(stamps: NDArray[np.float64], scans: list[CarmenScan], source: str) -> None:
    """Refuse stamps a bag cannot hold (outside ``[MIN_STAMP_S, MAX_STAMP_S]``), naming the first one's line."""
    bad = np.flatnonzero(~((stamps >= MIN_STAMP_S) & (stamps <= MAX_STAMP_S)))
    if bad.size:
        first = int(bad[0])
        raise CarmenLogError(
            f"{bad.size} of {stamps.size} scan stamps ({source}) lie outside the {MIN_STAMP_S:g} to "
            f"{MAX_STAMP_S:.0f} s a bag holds, the first at line {scans[first].line_number}: {float(stamps[first])!r} s")


def prepare_log(
    log_path: str | os.PathLike[str],
    settings: ConversionSettings | None = None,
    *,
    on_skip: Callable[[int, str], None] | None = _report_to_stderr,
    on_warning: Callable[[str], None] | None = _report_warning_to_stderr,
) -> PreparedLog:
    """Parse a log, choose its stamps (warning through ``on_warning``) and simulate its odometry."""
    settings = settings or ConversionSettings()
    log = parse_carmen_log(log_path, on_skip=on_skip)
    scans = log.scans
    max_range = settings.max_range or detect_max_range(scans, settings.no_return_tolerance)
    poses = np.array([s.pose for s in scans])
    choice = choose_stamps(scans, settings.period, message=log.message)
    if on_warning is not None:
        for message in choice.warnings:
            on_warning(message)
    _check_stamp_range(choice.stamps, scans, choice.source)
    rng = np.random.default_rng(settings.seed)
    model = OdometryMotionModel(*settings.alphas)
    odom = simulate_odometry(poses, model, rng)
    stamps = choice.stamps
    scan_time = float(np.median(np.diff(stamps))) if len(stamps) > 1 else settings.period
    return PreparedLog(log, stamps, choice.source, choice.warnings, poses, odom, float(max_range), scan_time, model)


def build_log_map(prepared: PreparedLog, settings: ConversionSettings, indices: Sequence[int] | None = None) -> GridMap:
    """The occupancy map of the scans ``indices`` of a prepared log (default: all of them)."""
    chosen = range(len(prepared.scans)) if indices is None else indices
    return build_occupancy_map(
        prepared.poses[list(chosen)],
        [prepared.angles(i) for i in chosen],
        [prepared.scans[i].ranges for i in chosen],
        prepared.max_range,
        resolution=settings.resolution,
        map_max_range=settings.map_max_range,
    )


def write_bag(
    out_dir: str | os.PathLike[str],
    prepared: PreparedLog,
    grid_map: GridMap | None,
    *,
    scans: range | None = None,
    compress: bool = False,
) -> Path:
    """Write the scans ``scans`` (default: all) of a prepared log as a bag, ``/map`` first if given.

    Every message depends only on its scan's index in the whole log, so the bags of a
    partition of the scans hold exactly the whole log's messages. The bag's metadata declares the
    odometry's noise model (``custom_data``, :data:`~..core.motion.ODOMETRY_NOISE_KEY`).
    """
    # Imported here so that parsing and map building stay usable without ROS.
    from ..ros import conversions
    from ..ros.bag import BagWriter

    chosen = range(len(prepared.scans)) if scans is None else scans
    stamps, odom, poses, max_range = prepared.stamps, prepared.odom, prepared.poses, prepared.max_range
    microsecond = _MICROSECOND_NS
    out_dir = Path(out_dir)
    declared = {ODOMETRY_NOISE_KEY: declare_odometry_noise(prepared.odometry_model)}
    with BagWriter(out_dir, compress=compress, custom_data=declared) as writer:
        if grid_map is not None:
            first = float(stamps[chosen[0]])
            writer.write("/map", conversions.grid_map_to_msg(grid_map, first),
                         int(round(first * 1e9)) - 4 * microsecond)
        for i in chosen:
            scan = prepared.scans[i]
            stamp = float(stamps[i])
            stamp_ns = int(round(stamp * 1e9))
            dt = stamp - float(stamps[i - 1]) if i > 0 else 0.0
            if i > 0 and dt > 0.0:
                step = odometry_delta(odom[i - 1], odom[i])
                velocity = (step.trans / dt, (step.rot1 + step.rot2) / dt)
            else:
                velocity = (0.0, 0.0)
            writer.write(
                "/odom",
                conversions.odometry_to_msg(stamp, odom[i], frame_id="odom", velocity=velocity),
                stamp_ns - 2 * microsecond,
            )
            writer.write(
                "/ground_truth", conversions.odometry_to_msg(stamp, poses[i], frame_id="map"), stamp_ns - microsecond
            )
            ranges = np.where(np.isfinite(scan.ranges) & (scan.ranges >= max_range), np.inf, scan.ranges)
            ranges = np.where(np.isfinite(ranges) & (ranges < 0.0), np.nan, ranges)
            angle_min, increment = scan_geometry(scan)
            writer.write(
                "/scan",
                conversions.scan_to_msg(
                    stamp,
                    "laser",
                    angle_min=angle_min,
                    angle_increment=increment,
                    ranges=ranges,
                    range_min=0.0,
                    range_max=max_range,
                    scan_time=prepared.scan_time,
                ),
                stamp_ns,
            )
    return out_dir


@dataclass
class ConversionReport:
    """What a conversion produced."""

    scans: int
    skipped_lines: list[tuple[int, str]]
    beam_counts: list[int]
    max_range: float
    duration_s: float
    path_length_m: float
    map_cells: tuple[int, int]
    bag_bytes: int
    map_yaml: Path | None
    stamp_source: str = "FLASER ipc_timestamp"
    stamp_warnings: tuple[str, ...] = ()

    def summary(self) -> str:
        lines = [
            f"{self.scans} scans ({', '.join(str(c) for c in self.beam_counts)} beams), "
            f"{len(self.skipped_lines)} malformed lines skipped",
            f"no-return threshold {self.max_range:.3f} m, {self.duration_s:.1f} s, path {self.path_length_m:.1f} m",
            f"stamps: {self.stamp_source}"
            + (f" ({len(self.stamp_warnings)} timestamp warnings on stderr)" if self.stamp_warnings else ""),
            f"map {self.map_cells[0]} x {self.map_cells[1]} cells, bag {self.bag_bytes / 1e6:.2f} MB",
        ]
        if self.map_yaml is not None:
            lines.append(f"map written to {self.map_yaml}")
        return "\n".join(lines)


def _clear(path: Path, overwrite: bool) -> None:
    """Refuse an existing output unless ``overwrite``; then remove it."""
    if path.exists():
        if not overwrite:
            raise CarmenLogError(f"output {str(path)!r} exists (use --overwrite)")
        shutil.rmtree(path) if path.is_dir() else path.unlink()


def convert_log(
    log_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    map_out: str | os.PathLike[str] | None = None,
    settings: ConversionSettings | None = None,
    overwrite: bool = False,
    on_skip: Callable[[int, str], None] | None = _report_to_stderr,
    on_warning: Callable[[str], None] | None = _report_warning_to_stderr,
) -> ConversionReport:
    """Convert one CARMEN log into a bag at ``out_dir`` (and a map YAML at ``map_out``)."""
    settings = settings or ConversionSettings()
    prepared = prepare_log(log_path, settings, on_skip=on_skip, on_warning=on_warning)
    grid_map = build_log_map(prepared, settings)
    out_dir = Path(out_dir)
    _clear(out_dir, overwrite)
    write_bag(out_dir, prepared, grid_map)
    map_yaml = grid_map.save(map_out) if map_out is not None else None
    poses, stamps = prepared.poses, prepared.stamps
    steps = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    from ..ros.bag import bag_bytes  # rclpy only once a bag is written

    return ConversionReport(
        scans=len(prepared.scans),
        skipped_lines=prepared.log.skipped,
        beam_counts=sorted({s.ranges.size for s in prepared.scans}),
        max_range=prepared.max_range,
        duration_s=float(stamps[-1] - stamps[0]),
        path_length_m=float(steps.sum()),
        map_cells=(grid_map.width, grid_map.height),
        bag_bytes=bag_bytes(out_dir),
        map_yaml=map_yaml,
        stamp_source=prepared.stamp_source,
        stamp_warnings=prepared.stamp_warnings,
    )


def _output_problem(path: Path, *, directory: bool | None) -> str | None:
    """Why ``path`` cannot be written (None if it can): it lies under a file, or it is a file where a directory
    goes (``directory`` True) or a directory where a file goes (False); None: either will do (--overwrite).
    """
    if path.exists():
        if directory is True and not path.is_dir():
            return f"{str(path)!r} is not a directory"
        if directory is False and path.is_dir():
            return f"{str(path)!r} is a directory"
        return None
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        return f"{str(path)!r} cannot be created: {str(parent)!r} is not a directory"
    return None


def _number_from(low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a number from ``low`` to ``high``, else an error naming the value."""

    def number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number from {low:.12g} to {high:.12g}")
        return value

    return number


def _parser() -> argparse.ArgumentParser:
    from .carmen_cv import MIN_BLOCK_SCANS, NEAR_PATH_M

    defaults = ConversionSettings()
    parser = argparse.ArgumentParser(
        prog="carmen_to_bag",
        description="Convert a corrected CARMEN log (FLASER or ROBOTLASER1 lines) into a rosbag2 MCAP bag with /scan, /odom, "
        "/ground_truth and /map, and save the occupancy map built from it. With --blocks K, cut it instead "
        "into K cross-validation blocks, each a bag with a map built from the other K-1 blocks only.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("log", type=Path, help="CARMEN log, plain or .gz")
    parser.add_argument("out_dir", type=Path, help="bag directory to create (with --blocks: the output directory)")
    parser.add_argument("--map-out", type=Path, default=None, help="also save the map as this nav2 YAML (+ .pgm)")
    parser.add_argument(
        "--blocks", type=int, default=None, metavar="K",
        help="cross-validation split: K contiguous blocks of equal scan counts (by scan index, the first "
        "blocks one scan longer when K does not divide the count). Writes OUT_DIR/<name>_cv<k>of<K>/ (the "
        "block's scans; its /map is the block's map), OUT_DIR/<name>_cv<k>of<K>.yaml + .png (map from the other "
        f"K-1 blocks), OUT_DIR/<name>_full.yaml + .png (map from all scans) and the index OUT_DIR/<name>_cv.yaml. "
        f"Odometry is the whole log's seeded stream restricted to each block. A block of fewer than "
        f"{MIN_BLOCK_SCANS} scans is skipped; a map with no free cell within {NEAR_PATH_M:g} m of the block's "
        "path is refused; exit status 1 only if no block was written. None: convert the whole log",
    )
    parser.add_argument("--name", default=None,
                        help="with --blocks: file name prefix; None: the log's file name without -corrected.log.gz")
    for index, default in enumerate(defaults.alphas, start=1):
        meaning = ("rotation from rotation", "rotation from translation", "translation from translation",
                   "translation from rotation")[index - 1]
        parser.add_argument(f"--alpha{index}", type=float, default=default,
                            help=f"odometry noise, {meaning} (variance scale, Thrun table 5.6 / nav2_amcl)")
    parser.add_argument("--seed", type=int, default=defaults.seed, help="seed of the odometry noise")
    parser.add_argument("--resolution", type=_number_from(MIN_RESOLUTION_M, MAX_RESOLUTION_M),
                        default=defaults.resolution, help="map cell size [m]")
    parser.add_argument("--period", type=_number_from(MIN_STAMP_STEP_S, MAX_STAMP_S), default=defaults.period,
                        help="scan period [s] when neither the laser nor the ODOM lines have usable timestamps "
                        "(warned on stderr)")
    parser.add_argument("--max-range", type=float, default=None,
                        help="no-return threshold [m] (default: the log's largest finite reading minus the tolerance)")
    parser.add_argument("--no-return-tolerance", type=float, default=defaults.no_return_tolerance,
                        help="readings this close to the log's largest reading are no-returns [m]")
    parser.add_argument("--map-max-range", type=float, default=defaults.map_max_range,
                        help="hits farther than this are not used as map endpoints [m]")
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.blocks is not None and args.map_out is not None:
        parser.error("--map-out does not go with --blocks (the whole-log map is OUT_DIR/<name>_full.yaml)")
    outputs = [("OUT_DIR", args.out_dir, True if args.blocks is not None else None)]
    if args.map_out is not None:
        outputs += [("--map-out", args.map_out, False), ("--map-out", args.map_out.with_suffix(".pgm"), False)]
    for name, path, directory in outputs:
        problem = _output_problem(path, directory=directory)
        if problem is not None:
            parser.error(f"{name}: {problem}")
    try:
        settings = ConversionSettings(
            alphas=(args.alpha1, args.alpha2, args.alpha3, args.alpha4),
            seed=args.seed,
            resolution=args.resolution,
            period=args.period,
            max_range=args.max_range,
            no_return_tolerance=args.no_return_tolerance,
            map_max_range=args.map_max_range,
        )
        if args.blocks is not None:
            from .carmen_cv import split_log

            split = split_log(args.log, args.out_dir, args.blocks, name=args.name, settings=settings,
                              overwrite=args.overwrite)
            print(split.summary())
            return 0 if split.written() else 1
        report = convert_log(args.log, args.out_dir, map_out=args.map_out, settings=settings, overwrite=args.overwrite)
    except (ValueError, LocalizationSuiteError) as exc:
        print(f"carmen_to_bag: error: {exc}", file=sys.stderr)
        return 1
    print(report.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
