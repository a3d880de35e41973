"""A scenario that keeps the robot moving for as long as a soak runs: its route out and back, repeated.

The scenarios in ``config/scenarios`` end after a few minutes and carry kidnappings. A soak needs
hours of ordinary driving from one ``scan_sim`` process (restarting it would reset the localizers'
time and break its memory series), so the route is turned into a closed tour: the waypoints up to
the first kidnapping's teleport (the part the robot really drives), then the same points back to
the start, repeated. Reversed straight legs are the legs already checked against the map, so the
tour is as collision-free as the original. Kidnappings are left out: a soak measures resources,
not recovery.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from ...core.errors import ScenarioError
from ...core.sim.scenario import Scenario
from ...core.sim.scenario_yaml import scenario_from_dict

__all__ = ["tour_route", "write_tour"]


def tour_route(data: dict[str, Any]) -> list[Any]:
    """One loop of the tour (raw YAML waypoints): the driven route out, then back to the start.

    Raises:
        ScenarioError: the scenario has no waypoint route (velocity segments or cmd_vel only).
    """
    motion = data.get("motion") or {}
    waypoints = list(motion.get("waypoints") or [])
    if not waypoints:
        raise ScenarioError(f"scenario {data.get('name', '?')!r} has no motion.waypoints: a soak tour needs a route")
    teleports = [k["continue_at"] for k in data.get("kidnappings") or [] if k.get("continue_at") is not None]
    driven = waypoints[: min(teleports)] if teleports else waypoints
    points = [list(w[:2]) for w in driven if isinstance(w, (list, tuple))]
    if not points:
        raise ScenarioError(f"scenario {data.get('name', '?')!r} drives no waypoint before its first kidnapping")
    back = points[-2::-1] + [list(data["start"][:2])]
    return driven + back


def write_tour(scenario_path: Path, out_path: Path, sim_seconds: float) -> Scenario:
    """Write ``out_path``: the tour of ``scenario_path`` repeated to last at least ``sim_seconds``.

    Returns the validated scenario (its ``end_time`` says how long it lasts).
    """
    data = yaml.safe_load(Path(scenario_path).read_text())
    base_dir = Path(scenario_path).resolve().parent
    data["map"] = str((base_dir / str(data["map"])).resolve())
    data.pop("kidnappings", None)
    loop = tour_route(yaml.safe_load(Path(scenario_path).read_text()))
    data["name"] = f"{data.get('name', 'scenario')}_tour"
    data["motion"]["waypoints"] = loop
    once = scenario_from_dict(data, base_dir)
    repeats = max(1, math.ceil(sim_seconds / once.end_time))
    data["motion"]["waypoints"] = loop * repeats
    scenario = once if repeats == 1 else scenario_from_dict(data, base_dir)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(
        f"# The route of {Path(scenario_path).name} out and back, {repeats} times, without kidnappings "
        f"(rls_soak; {scenario.end_time:.0f} s simulated).\n" + yaml.safe_dump(data, sort_keys=False)
    )
    return scenario
