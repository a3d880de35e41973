"""Scenarios from YAML: :func:`load_scenario` and :func:`scenario_from_dict`, every field checked and named.

The map path is relative to the scenario file. Layout: docs/simulator.md.
A scenario needs ``motion`` or ``duration``: without motion the robot stands at its start (live
``scan_sim``: drives by ``cmd_vel``) for ``duration`` seconds; with neither it would never end, and is refused.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from ..errors import MapError, ScenarioError
from ..grid_map import load_map_yaml
from .config import (
    CameraConfig,
    Kidnapping,
    LaserConfig,
    MapChange,
    MotionPlan,
    OdometryConfig,
    Person,
    Reinitialization,
    VelocitySegment,
    Waypoint,
    finite_value,
    non_negative_value,
    point_value,
    pose_value,
    positive_value,
)
from .scenario import Scenario

__all__ = ["load_scenario", "scenario_from_dict"]


# -- YAML loading -------------------------------------------------------------------------
_TOP_KEYS = {
    "name",
    "map",
    "seed",
    "duration",
    "robot_radius",
    "start",
    "motion",
    "kidnappings",
    "map_changes",
    "reinitializations",
    "people",
    "laser",
    "odometry",
    "camera",
    "description",
}


def _mapping(name: str, value: Any, allowed: set[str]) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ScenarioError(f"{name} must be a mapping, got {value!r}")
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise ScenarioError(f"{name} has unknown key(s) {unknown} (allowed: {sorted(allowed)})")
    return dict(value)


def _list(name: str, value: Any) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, list):
        raise ScenarioError(f"{name} must be a list, got {value!r}")
    return value


def _integer(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ScenarioError(f"{name} must be an integer, got {value!r}")
    return value


def _dataclass_fields(cls: type, name: str, raw: dict[str, Any], integers: Sequence[str] = ()) -> dict[str, Any]:
    """Fields of a config dataclass from YAML, numbers as float (``integers`` as int)."""
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key in integers:
            out[key] = _integer(f"{name}.{key}", value)
        elif isinstance(value, (str, bool)):  # strings and flags as given (the dataclass checks their kind)
            out[key] = value
        elif key == "mount":
            out[key] = pose_value(f"{name}.mount", value)
        else:
            out[key] = finite_value(f"{name}.{key}", value)
    return out


def _parse_waypoint(index: int, raw: Any) -> Waypoint:
    name = f"motion.waypoints[{index}]"
    if isinstance(raw, Mapping):
        data = _mapping(name, raw, {"wait"})
        if "wait" not in data:
            raise ScenarioError(f"{name} must be [x, y], [x, y, yaw] or {{wait: seconds}}, got {raw!r}")
        return Waypoint(wait=non_negative_value(f"{name}.wait", data["wait"]))
    if not isinstance(raw, (list, tuple)) or len(raw) not in (2, 3):
        raise ScenarioError(f"{name} must be [x, y], [x, y, yaw] or {{wait: seconds}}, got {raw!r}")
    values = [finite_value(name, v) for v in raw]
    return Waypoint(values[0], values[1], values[2] if len(values) == 3 else None)


def scenario_from_dict(data: Mapping[str, Any], base_dir: str | os.PathLike[str] = ".") -> Scenario:
    """Build a :class:`Scenario` from parsed YAML; the map path is relative to ``base_dir``.

    Without ``motion`` a ``duration`` is required (the module docstring says why).
    """
    data = _mapping("scenario", data, _TOP_KEYS)
    if "map" not in data:
        raise ScenarioError("scenario has no 'map' (path of a nav2 map_server YAML)")
    if "start" not in data:
        raise ScenarioError("scenario has no 'start' pose [x, y, yaw]")
    map_path = (Path(base_dir) / str(data["map"])).resolve()
    try:
        grid_map = load_map_yaml(map_path, exact_resolution=True)
    except MapError as exc:
        raise ScenarioError(f"scenario map {str(data['map'])!r}: {exc}") from exc

    motion = None
    if data.get("motion") is not None:
        raw = _mapping("motion", data["motion"], {"linear_speed", "angular_speed", "waypoints", "segments"})
        waypoints = tuple(_parse_waypoint(i, w) for i, w in enumerate(_list("motion.waypoints", raw.get("waypoints"))))
        segments = []
        for index, item in enumerate(_list("motion.segments", raw.get("segments"))):
            seg = _mapping(f"motion.segments[{index}]", item, {"v", "w", "duration"})
            for key in ("v", "w", "duration"):
                if key not in seg:
                    raise ScenarioError(f"motion.segments[{index}] has no {key!r}")
            segments.append(
                VelocitySegment(
                    finite_value(f"motion.segments[{index}].v", seg["v"]),
                    finite_value(f"motion.segments[{index}].w", seg["w"]),
                    positive_value(f"motion.segments[{index}].duration", seg["duration"]),
                )
            )
        motion = MotionPlan(
            waypoints=waypoints,
            segments=tuple(segments),
            linear_speed=finite_value("motion.linear_speed", raw.get("linear_speed", 0.5)),
            angular_speed=finite_value("motion.angular_speed", raw.get("angular_speed", 0.8)),
        )

    kidnappings = []
    for index, item in enumerate(_list("kidnappings", data.get("kidnappings"))):
        raw = _mapping(f"kidnappings[{index}]", item, {"time", "pose", "continue_at"})
        if "time" not in raw or "pose" not in raw:
            raise ScenarioError(f"kidnappings[{index}] needs 'time' and 'pose', got {item!r}")
        continue_at = raw.get("continue_at")
        kidnappings.append(
            Kidnapping(
                non_negative_value(f"kidnappings[{index}].time", raw["time"]),
                pose_value(f"kidnappings[{index}].pose", raw["pose"]),
                None if continue_at is None else _integer(f"kidnappings[{index}].continue_at", continue_at),
            )
        )

    map_changes = []
    for index, item in enumerate(_list("map_changes", data.get("map_changes"))):
        raw = _mapping(f"map_changes[{index}]", item, {"time", "map"})
        if "time" not in raw or "map" not in raw:
            raise ScenarioError(f"map_changes[{index}] needs 'time' and 'map', got {item!r}")
        changed_path = (Path(base_dir) / str(raw["map"])).resolve()
        try:
            changed_map = load_map_yaml(changed_path, exact_resolution=True)
        except MapError as exc:
            raise ScenarioError(f"map_changes[{index}].map {str(raw['map'])!r}: {exc}") from exc
        map_changes.append(
            MapChange(non_negative_value(f"map_changes[{index}].time", raw["time"]), changed_map, str(raw["map"]))
        )

    reinitializations = []
    for index, item in enumerate(_list("reinitializations", data.get("reinitializations"))):
        raw = _mapping(f"reinitializations[{index}]", item, {"time"})
        if "time" not in raw:
            raise ScenarioError(f"reinitializations[{index}] needs 'time', got {item!r}")
        reinitializations.append(Reinitialization(non_negative_value(f"reinitializations[{index}].time", raw["time"])))

    people = []
    for index, item in enumerate(_list("people", data.get("people"))):
        raw = _mapping(f"people[{index}]", item, {"radius", "speed", "waypoints", "loop"})
        points = tuple(
            point_value(f"people[{index}].waypoints", p) for p in _list(f"people[{index}].waypoints", raw.get("waypoints"))
        )
        people.append(
            Person(
                radius=finite_value(f"people[{index}].radius", raw.get("radius", 0.25)),
                speed=finite_value(f"people[{index}].speed", raw.get("speed", 0.8)),
                waypoints=points,
                loop=bool(raw.get("loop", False)),
            )
        )

    laser_raw = _mapping("laser", data.get("laser"), set(LaserConfig.__dataclass_fields__))
    odom_raw = _mapping("odometry", data.get("odometry"), set(OdometryConfig.__dataclass_fields__))
    laser = LaserConfig(**_dataclass_fields(LaserConfig, "laser", laser_raw, integers=("beams",)))
    odometry = OdometryConfig(**_dataclass_fields(OdometryConfig, "odometry", odom_raw))
    camera = None
    if data.get("camera") is not None:
        if not isinstance(data["camera"], Mapping):
            raise ScenarioError(f"camera must be a mapping, got {data['camera']!r}")
        known = set(CameraConfig.__dataclass_fields__) - {"extra"}
        camera_raw = {k: v for k, v in data["camera"].items() if k in known}
        extra = tuple((str(k), finite_value(f"camera.{k}", v)) for k, v in sorted(data["camera"].items()) if k not in known)
        camera = CameraConfig(
            **_dataclass_fields(CameraConfig, "camera", camera_raw, integers=("width", "height", "texture_seed")),
            extra=extra,
        )
    duration = data.get("duration")
    scenario = Scenario(
        grid_map=grid_map,
        start=pose_value("start", data["start"]),
        motion=motion,
        kidnappings=tuple(kidnappings),
        people=tuple(people),
        laser=laser,
        odometry=odometry,
        camera=camera,
        duration=None if duration is None else positive_value("duration", duration),
        robot_radius=non_negative_value("robot_radius", data.get("robot_radius", 0.2)),
        seed=_integer("seed", data.get("seed", 0)),
        name=str(data.get("name", "scenario")),
        map_path=map_path,
        map_changes=tuple(map_changes),
        reinitializations=tuple(reinitializations),
    )
    if scenario.motion is None and scenario.duration is None:
        raise ScenarioError("scenario has no 'motion' (waypoints or segments) and no 'duration': it would never end")
    return scenario


def load_scenario(path: str | os.PathLike[str]) -> Scenario:
    """Load and validate a scenario YAML file.

    Raises:
        ScenarioError: naming the file, the field and the bad value.
    """
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"scenario file {str(path)!r} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"scenario file {str(path)!r} is not valid YAML: {exc}") from exc
    if not isinstance(data, Mapping):
        raise ScenarioError(f"scenario file {str(path)!r} must hold a mapping, got {type(data).__name__}")
    data = dict(data)
    data.setdefault("name", path.stem)
    try:
        return scenario_from_dict(data, path.parent)
    except ScenarioError as exc:
        raise ScenarioError(f"scenario {str(path)!r}: {exc}") from exc
