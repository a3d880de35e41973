"""Recall of the IR initialiser's global fixes on bags: the paper's Tables I and II, measured here.

Every ``--every``-th scan of each bag is localized alone (no prior, no
odometry) and the ranked candidates are compared with ``/ground_truth``
interpolated at the scan's stamp; a candidate is correct within 0.5 m and 25
degrees (the paper's criterion). Rows:

* ``step 1 (x, y)``: the positions of step 1, position only (Table I, first row);
* ``paper, idf`` / ``paper, no idf``: step 2's ranking as the paper makes it
  (no refinement, no duplicate suppression), with and without idf (Table II);
* ``final, idf`` / ``final, no idf``: the list the localizer publishes
  (refined, duplicates suppressed), with and without idf.

Usage::

    python -m robot_localization_suite.tools.ir_recall bags/intel bags/fr101 bags/orebro --every 1
    python -m robot_localization_suite.tools.ir_recall bags/intel --map config/maps/intel.yaml --set split_at_jump=0

The map is ``--map``, else ``config/maps/<bag name>.yaml``, else the bag's ``/map``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..core import metrics
from ..core.grid_map import GridMap, load_map_yaml
from ..core.ir.global_fix import IRGlobalFixer
from ..core.ir.settings import IRSettings
from ..core.scan import LaserMount, Scan
from ..core.se2 import compose, inverse

__all__ = ["KS", "evaluate", "format_table", "load_bag_scans", "main"]

KS = (1, 5, 10, 30, 50, 100)


def load_bag_scans(bag: Path) -> tuple[list[Scan], NDArray[np.float64], GridMap | None]:
    """Scans, ground-truth base poses at the scans' stamps (NaN where unknown) and the bag's map, if any."""
    from ..ros import conversions
    from ..ros.bag import read_bag

    scans: list[Scan] = []
    truth_stamps, truth_poses = [], []
    grid_map = None
    for message in read_bag(bag, ["/scan", "/ground_truth", "/map"]):
        if message.topic == "/scan":
            scans.append(conversions.scan_from_msg(message.msg))
        elif message.topic == "/ground_truth":
            stamp, pose = conversions.odometry_from_msg(message.msg)
            truth_stamps.append(stamp)
            truth_poses.append(pose)
        elif message.topic == "/map" and grid_map is None:
            grid_map = conversions.grid_map_from_msg(message.msg)
    truths: NDArray[np.float64] = np.full((len(scans), 3), np.nan)
    if truth_stamps:
        order = np.argsort(truth_stamps)
        trajectory = metrics.Trajectory(np.asarray(truth_stamps)[order], np.asarray(truth_poses).reshape(-1, 3)[order])
        truths = metrics.interpolate_poses(trajectory, [scan.stamp for scan in scans])
    return scans, truths, grid_map


def evaluate(
    grid_map: GridMap,
    scans: Sequence[Scan],
    truths: NDArray[np.float64],
    settings: IRSettings,
    *,
    mount: LaserMount | None = None,
    every: int = 1,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Recall@k of each row of the module docstring over the scans, and query times."""
    mount = mount or LaserMount()
    to_base = inverse(mount.pose)
    scans = [mount.level(scan) for scan in scans]
    variants = {
        "final, idf": settings,
        "final, no idf": replace(settings, use_idf=False),
        "paper, idf": replace(settings, refine_candidates=0, nms_distance=0.0),
        "paper, no idf": replace(settings, refine_candidates=0, nms_distance=0.0, use_idf=False),
    }
    start = time.perf_counter()
    main_fixer = IRGlobalFixer(settings)
    main_fixer.set_map(grid_map)
    index = main_fixer.prepare(scans[0])
    build_s = time.perf_counter() - start
    localizers = {name: main_fixer if variant is settings else main_fixer.variant(replace(variant, progress=False))
                  for name, variant in variants.items()}
    hits: dict[str, list[dict[int, bool]]] = {"step 1 (x, y)": [], **{name: [] for name in variants}}
    query_ms: list[float] = []
    step_ms: list[float] = []
    reasons: dict[str, int] = {}
    used = 0
    for i in range(0, len(scans), max(1, every)):
        truth = truths[i]
        if not np.all(np.isfinite(truth)):
            continue
        used += 1
        for name, localizer in localizers.items():
            t0 = time.perf_counter()
            estimate = localizer.global_fix(scans[i])
            elapsed = (time.perf_counter() - t0) * 1e3
            candidates = compose(estimate.candidates, to_base) if len(estimate.candidates) else estimate.candidates
            hits[name].append(metrics.recall_at_k(candidates, truth, KS))
            if name == "final, idf":
                query_ms.append(elapsed)
                step_ms.append(estimate.details.get("step1_ms", 0.0) + estimate.details.get("step2_ms", 0.0))
                xy = estimate.details.get("step1_xy", np.zeros((0, 2)))
                # Position only (the paper's "pose (x, y)" row): the laser's position, heading ignored.
                truth_laser = compose(truth, mount.pose)
                as_poses = np.column_stack([xy, np.full(len(xy), truth_laser[2])]) if len(xy) else np.zeros((0, 3))
                hits["step 1 (x, y)"].append(metrics.recall_at_k(as_poses, truth_laser, KS))
                if "reason" in estimate.details:
                    reasons[estimate.details["reason"]] = reasons.get(estimate.details["reason"], 0) + 1
        if progress and used % 50 == 0:
            progress(f"{used} scans")
    recall = {name: {k: float(np.mean([row[k] for row in rows])) if rows else float("nan") for k in KS} for name, rows in hits.items()}
    return {
        "queries": used,
        "recall": recall,
        "query_ms_median": float(np.median(query_ms)) if query_ms else None,
        "query_ms_p95": float(np.percentile(query_ms, 95)) if query_ms else None,
        "steps12_ms_median": float(np.median(step_ms)) if step_ms else None,
        "steps12_ms_p95": float(np.percentile(step_ms, 95)) if step_ms else None,
        "no_candidate_reasons": reasons,
        "index": index.describe(),
        "index_ready_s": build_s,
    }


def format_table(name: str, result: dict[str, Any]) -> str:
    lines = [
        f"### {name}: {result['queries']} scans; query median {result['query_ms_median']:.0f} ms, "
        f"p95 {result['query_ms_p95']:.0f} ms (steps 1+2 median {result['steps12_ms_median']:.0f} ms, "
        f"p95 {result['steps12_ms_p95']:.0f} ms)",
        "",
        "| ranking | " + " | ".join(str(k) for k in KS) + " |",
        "| --- | " + " | ".join("---" for _ in KS) + " |",
    ]
    for row, values in result["recall"].items():
        lines.append(f"| {row} | " + " | ".join(f"{100 * values[k]:.1f}" for k in KS) + " |")
    lines.append("")
    lines.append(f"index: {result['index']}; ready in {result['index_ready_s']:.1f} s")
    if result["no_candidate_reasons"]:
        lines.append(f"no candidates: {result['no_candidate_reasons']}")
    return "\n".join(lines)


def _parse_overrides(pairs: Sequence[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bags", nargs="+", type=Path)
    parser.add_argument("--map", type=Path, default=None, help="map YAML (default config/maps/<bag>.yaml or /map)")
    parser.add_argument("--every", type=int, default=1, help="use every N-th scan")
    parser.add_argument("--set", nargs="*", default=[], help="IR settings overrides, name=value (ROS parameter names)")
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    options = parser.parse_args(argv)

    from ..registry import config_dir, plugin

    node_settings, settings = plugin("ir_initializer").load_settings(_parse_overrides(options.set))
    if not isinstance(settings, IRSettings):
        raise TypeError(f"the ir_initializer plugin gave {type(settings).__name__} settings, not IRSettings")
    from .bench.reference import load_reference

    results = {}
    for bag in options.bags:
        # the laser mount as a node and the benchmark take it: the bag's /tf_static, else the parameters
        mount = load_reference(bag).laser_mounts.get(node_settings.base_frame_id, node_settings.mount)
        scans, truths, bag_map = load_bag_scans(bag)
        map_path = options.map or config_dir() / "maps" / f"{bag.name}.yaml"
        grid_map = load_map_yaml(map_path) if map_path.is_file() else bag_map
        if grid_map is None:
            print(f"{bag}: no map ({map_path} missing and no /map in the bag)", file=sys.stderr)
            return 2
        result = evaluate(grid_map, scans, truths, settings, mount=mount, every=options.every, progress=lambda s: print(s, file=sys.stderr))
        results[bag.name] = result
        print(format_table(bag.name, result), flush=True)
    if options.json:
        options.json.write_text(json.dumps(results, indent=2, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
