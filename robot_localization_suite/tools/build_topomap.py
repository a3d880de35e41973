"""``build_topomap SCENARIO OUT_DIR``: the topological map of a simulated world (thesis 003, 4.1.3, 4.2.3).

For every place of a nodes file (``name``, ``x``, ``y``; default
``OUT_DIR/nodes.yaml``) the simulated robot stands on the place and turns
clockwise on the spot, taking a snapshot with the scenario's camera after
each *imprecise* angle step (``--step-deg`` plus a uniform error of up to
``--step-error-deg``, as the thesis' robot did on carpet, 5.1.2), until the
turn has covered the circle. The panorama is rebuilt from the snapshots with
the IMA variant of Code 2.3 (``core.ima.build_panorama``; ``--slots`` 15 as
the thesis used for panoramas, CLAHE on by default) and written as
``OUT_DIR/<name>.png``; ``OUT_DIR/topomap.yaml`` lists each node's name, x, y
and panorama file (the thesis' map file, Figure 4.1), the camera's field of
view and the heading of the first snapshot (``heading_ref``, common to all
places so the heading can be recovered, 3.7).

The snapshots are rendered with the scenario's camera (lighting variation
included, its own random stream) in an empty world: the people of the
scenario are not there when the map is made.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from ..core.errors import LocalizationSuiteError, MapError, ScenarioError
from ..core.ima.panorama import build_panorama
from ..core.ima.settings import ImaSettings
from ..core.ima.topomap import TopologicalMap, TopoNode, save_topomap
from ..core.sim.camera import CameraRenderer
from ..core.sim.scenario import Scenario
from ..core.sim.scenario_yaml import load_scenario

__all__ = ["snapshot_turns", "load_nodes", "build_topomap", "main"]

TOPOMAP_FILE = "topomap.yaml"


def snapshot_turns(step_deg: float, step_error_deg: float, rng: np.random.Generator) -> np.ndarray:
    """Cumulative clockwise turns [rad] at which snapshots are taken: 0, then imprecise steps.

    Steps are ``step + U(-error, +error)``; snapshots continue until the turn
    reaches ``360 - step/2`` degrees, so the last one overlaps the first.
    """
    if not 0.0 < step_deg < 180.0:
        raise ValueError(f"step_deg must be within (0, 180), got {step_deg!r}")
    if not 0.0 <= step_error_deg < step_deg:
        raise ValueError(f"step_error_deg must be within [0, step_deg={step_deg!r}), got {step_error_deg!r}")
    turns = [0.0]
    while turns[-1] < 360.0 - 0.5 * step_deg:
        turns.append(turns[-1] + step_deg + rng.uniform(-step_error_deg, step_error_deg))
    return np.radians(np.asarray(turns))


def load_nodes(path: str | Path) -> tuple[list[tuple[str, float, float]], float]:
    """Places ``(name, x, y)`` and the common ``heading_ref`` [rad] of a nodes file.

    Raises:
        MapError: naming the file and the bad entry.
    """
    path = Path(path)
    if not path.is_file():
        raise MapError(f"nodes file {str(path)!r} does not exist")
    try:
        meta = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise MapError(f"nodes file {str(path)!r} is not valid YAML: {exc}") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("nodes"), list) or not meta["nodes"]:
        raise MapError(f"nodes file {str(path)!r} must hold a non-empty list 'nodes'")
    nodes, names = [], set()
    for index, entry in enumerate(meta["nodes"]):
        try:
            name, x, y = str(entry["name"]), float(entry["x"]), float(entry["y"])
        except (TypeError, KeyError, ValueError):
            raise MapError(f"nodes file {str(path)!r}: node {index} needs name, x, y; got {entry!r}") from None
        if name in ("", ".", "..") or Path(name).name != name:
            raise MapError(f"nodes file {str(path)!r}: node name {name!r} is not a plain file name "
                           "(its panorama is written as OUT_DIR/<name>.png)")
        if not (math.isfinite(x) and math.isfinite(y)):
            raise MapError(f"nodes file {str(path)!r}: node {name!r} has a non-finite position {entry!r}")
        if name in names:
            raise MapError(f"nodes file {str(path)!r}: node name {name!r} appears twice")
        names.add(name)
        nodes.append((name, x, y))
    try:
        heading_ref = float(meta.get("heading_ref", 0.0))
    except (TypeError, ValueError):
        raise MapError(f"nodes file {str(path)!r}: heading_ref must be a number, got {meta.get('heading_ref')!r}") from None
    return nodes, heading_ref


def build_topomap(
    scenario: Scenario,
    nodes: Sequence[tuple[str, float, float]],
    out_dir: str | Path,
    *,
    heading_ref: float = 0.0,
    settings: ImaSettings | None = None,
    step_deg: float = 40.0,
    step_error_deg: float = 10.0,
    seed: int = 0,
    min_insert_match: float = 0.6,
    attempts: int = 5,
    progress: bool = True,
) -> Path:
    """Rebuild every node's panorama and write ``OUT_DIR/topomap.yaml`` with the PNGs; returns the YAML path.

    A snapshot whose Code 2.3 ``MAX`` is below ``min_insert_match`` found no
    consistent place in the mosaic (typically the last ones, when an earlier
    one was misplaced and the circle does not close): the robot then turns
    again and takes a new sequence, up to ``attempts`` times, keeping the
    sequence whose worst insertion matched best (the thesis' user watched the
    insertion and retook failed panoramas, 4.1.2).
    """
    if scenario.camera is None:
        raise ScenarioError(f"scenario {scenario.name!r} has no camera section: no snapshots can be taken")
    settings = settings or ImaSettings(width=144, height=116, slots=15, clahe=True, zoom=1.0)
    camera = CameraRenderer(scenario.grid_map, **scenario.camera.renderer_arguments(), **dict(scenario.camera.extra))
    hfov = float(scenario.camera.hfov_deg)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 2024]))
    topo_nodes, panoramas, report = [], [], []
    try:
        from tqdm import tqdm

        iterator = tqdm(nodes, desc="panoramas", unit="node", disable=not progress, file=sys.stderr)
    except ImportError:  # pragma: no cover - tqdm is a dependency
        iterator = nodes
    for name, x, y in iterator:
        if not bool(scenario.grid_map.is_free(np.array([x, y]))):
            raise MapError(f"node {name!r} at ({x}, {y}) is not in free space of the scenario's map")
        best = None
        for attempt in range(1, attempts + 1):
            turns = snapshot_turns(step_deg, step_error_deg, rng)
            snapshots = [camera.render(np.array([x, y, heading_ref - turn]), None, rng) for turn in turns]
            built = build_panorama(snapshots, hfov, settings)
            worst = float(built.matches[1:].min())
            if best is None or worst > best[0]:
                best = (worst, attempt, turns, built)
            if worst >= min_insert_match:
                break
        if best is None:
            raise ValueError(f"attempts must be at least 1, got {attempts!r}")
        worst, attempt, turns, built = best
        topo_nodes.append(TopoNode(name, x, y, f"{name}.png", heading_ref))
        panoramas.append(built.panorama)
        width = built.panorama.shape[1]
        true_columns = turns / (2.0 * np.pi) * width
        error = (built.columns - true_columns + 0.5 * width) % width - 0.5 * width
        report.append(
            {
                "name": name,
                "snapshots": len(turns),
                "attempt": attempt,
                "worst_insert_match": round(worst, 3),
                "max_insert_error_px": round(float(np.abs(error).max()), 2),
            }
        )
    source = {
        "scenario": scenario.name,
        "step_deg": step_deg,
        "step_error_deg": step_error_deg,
        "seed": seed,
        "min_insert_match": min_insert_match,
        "width": settings.width,
        "height": settings.height,
        "slots": settings.slots,
        "clahe": settings.clahe,
        "cylindrical": settings.cylindrical,
        "insertions": report,
    }
    topomap = TopologicalMap(topo_nodes, hfov, panoramas, source)
    return save_topomap(topomap, Path(out_dir) / TOPOMAP_FILE)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="build_topomap",
        description=(
            "Make the topological map of a simulated world: at every place the robot turns on the spot "
            "taking snapshots at imprecise angle steps; each panorama is rebuilt with IMA (Code 2.3)."
        ),
    )
    parser.add_argument("scenario", help="scenario YAML with a camera section (map and camera are taken from it)")
    parser.add_argument("out_dir", help="output folder: topomap.yaml and one <name>.png per node")
    parser.add_argument("--nodes", default=None, help="nodes YAML (name, x, y); default OUT_DIR/nodes.yaml")
    parser.add_argument("--step-deg", type=float, default=40.0, help="nominal turn between snapshots [deg] (default 40)")
    parser.add_argument("--step-error-deg", type=float, default=10.0, help="uniform error of each turn [deg] (default 10)")
    parser.add_argument("--width", type=int, default=144, help="working width of the snapshots [px] (default 144)")
    parser.add_argument("--height", type=int, default=116, help="working height of the snapshots [px] (default 116)")
    parser.add_argument("--slots", type=int, default=15, help="IMA slots for the reconstruction (default 15, thesis 5.1.3)")
    parser.add_argument("--no-clahe", action="store_true", help="align the snapshots without CLAHE filtering")
    parser.add_argument("--seed", type=int, default=0, help="seed of the turn errors and lighting (default 0)")
    parser.add_argument(
        "--min-insert-match", type=float, default=0.6,
        help="retake a node's snapshots when an insertion's Code 2.3 match is below this (default 0.6)",
    )
    parser.add_argument("--attempts", type=int, default=5, help="snapshot sequences tried per node (default 5)")
    args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    out_dir = Path(args.out_dir)
    blocked = next((path for path in (out_dir, *out_dir.parents) if path.exists() and not path.is_dir()), None)
    if blocked is not None:
        print(f"build_topomap: out_dir {args.out_dir!r}: {str(blocked)!r} is a file, not a folder", file=sys.stderr)
        return 1
    try:
        scenario = load_scenario(args.scenario)
        nodes, heading_ref = load_nodes(args.nodes or out_dir / "nodes.yaml")
        settings = ImaSettings(width=args.width, height=args.height, slots=args.slots, clahe=not args.no_clahe, zoom=1.0)
        path = build_topomap(
            scenario,
            nodes,
            out_dir,
            heading_ref=heading_ref,
            settings=settings,
            step_deg=args.step_deg,
            step_error_deg=args.step_error_deg,
            seed=args.seed,
            min_insert_match=args.min_insert_match,
            attempts=args.attempts,
        )
    except (LocalizationSuiteError, ValueError) as exc:
        print(f"build_topomap: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {path} ({len(nodes)} nodes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
