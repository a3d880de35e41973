"""``scan_sim``: the simulated robot as a ROS 2 node, or a bag recorder.

Live (default): steps :class:`~robot_localization_suite.core.simulator.Simulator`
on a timer at ``rate_hz * speed`` and publishes ``map`` (reliable, transient
local, once), ``scan`` (sensor QoS, frame ``laser``), ``odom`` (frame ``odom``,
child ``base_link``), ``ground_truth`` (nav_msgs/Odometry in ``map``) and
``camera/image_raw`` when the scenario has a camera. Stamps are the start
time of the node plus the simulated time.

* With ``scenario`` the robot follows the scenario. When it ends the node
  logs it and exits with code 0 (``exit_at_end: true``, the default, so that a
  runner or a demo sees the run is over), or keeps publishing the robot
  standing at its last pose (``exit_at_end: false``).
* Without ``scenario`` the robot drives on ``map_yaml`` from ``start_x/y/yaw``
  following ``cmd_vel`` (geometry_msgs/Twist): NaN components stop the robot,
  infinite or too large ones are clamped to ``max_linear`` / ``max_angular``,
  each logged (throttled), never fatal. Without a command for
  ``cmd_vel_timeout`` seconds the robot stops; it stops translating at walls.

Record: ``scan_sim --record DIR --ros-args -p scenario:=FILE`` runs the
scenario as fast as possible and writes a rosbag2 MCAP bag (``/map`` first,
then per step ``/odom``, ``/ground_truth``, ``/scan``, ``/camera/image_raw``,
stamped with the simulated time from 0, log time = stamp; zstd-compressed
chunks) and exits. No DDS participant is created: the ``--ros-args``
parameters (``-p``, ``--params-file``) are read here, with the same names,
types and ranges as in live mode.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..core.errors import LocalizationSuiteError, ScenarioError
from ..core.grid_map import load_map_yaml
from ..core.sim.scenario import LaserConfig, OdometryConfig, Scenario, load_scenario
from ..core.sim.simulator import SimulationStep, Simulator
from .common import ParamSpec

__all__ = [
    "NODE_NAME",
    "DESCRIPTION",
    "PARAMS",
    "TOPICS",
    "build_scenario",
    "sanitize_command",
    "parameters_from_args",
    "record",
    "main",
]

NODE_NAME = "scan_sim"
DESCRIPTION = (
    "Simulated robot: publishes map, laser scans, wheel odometry, ground truth (and camera images) "
    "from a scenario or from cmd_vel; --record DIR writes a rosbag2 MCAP bag instead."
)
TOPICS = """  out: map (nav_msgs/OccupancyGrid, transient local), scan (sensor_msgs/LaserScan),
       odom (nav_msgs/Odometry), ground_truth (nav_msgs/Odometry in map),
       camera/image_raw (sensor_msgs/Image, when the scenario has a camera)
  in:  cmd_vel (geometry_msgs/Twist, only without a scenario)"""

_KEEP = "negative (or empty): keep the scenario's value"
PARAMS = (
    ParamSpec("scenario", "", "scenario YAML (a path, or a name in config/scenarios); empty: drive by cmd_vel"),
    ParamSpec("map_yaml", "", "nav2 map_server YAML of the world without a scenario (cmd_vel mode)"),
    ParamSpec("seed", -1, "noise seed; -1: the scenario's seed", -1, 2_147_483_647),
    ParamSpec("speed", 1.0, "real-time factor of live mode (2.0 runs twice as fast)", 0.01, 100.0),
    ParamSpec("exit_at_end", True, "live mode: exit (code 0) when the scenario ends; false: keep publishing"),
    ParamSpec("start_x", 0.0, "cmd_vel mode: start x [m]"),
    ParamSpec("start_y", 0.0, "cmd_vel mode: start y [m]"),
    ParamSpec("start_yaw", 0.0, "cmd_vel mode: start heading [rad] (wrapped to [-pi, pi))", -6.2832, 6.2832),
    ParamSpec("robot_radius", 0.2, "cmd_vel mode: robot radius kept from obstacles [m]", 0.0, 2.0),
    ParamSpec("max_linear", 1.0, "cmd_vel mode: |linear.x| limit [m/s]", 0.0, 10.0),
    ParamSpec("max_angular", 2.0, "cmd_vel mode: |angular.z| limit [rad/s]", 0.0, 20.0),
    ParamSpec("cmd_vel_timeout", 0.5, "cmd_vel mode: stop after this long without a command [s]", 0.0, 60.0),
    ParamSpec("beams", -1, f"laser beams; {_KEEP}", -1, 100_000),
    ParamSpec("fov_deg", -1.0, f"laser field of view 90..360 [deg]; {_KEEP}", -1.0, 360.0),
    ParamSpec("range_min", -1.0, f"laser minimum range [m]; {_KEEP}", -1.0, 1000.0),
    ParamSpec("range_max", -1.0, f"laser maximum range [m]; {_KEEP}", -1.0, 1000.0),
    ParamSpec("rate_hz", -1.0, f"scans (and steps) per second; {_KEEP}", -1.0, 1000.0),
    ParamSpec("range_noise_model", "", f"gaussian or uniform; {_KEEP}"),
    ParamSpec("range_noise_std", -1.0, f"Gaussian range noise std [m]; {_KEEP}", -1.0, 10.0),
    ParamSpec("range_noise_bound", -1.0, f"uniform range noise bound [m]; {_KEEP}", -1.0, 10.0),
    ParamSpec("outlier_prob", -1.0, f"probability of a random reading per beam; {_KEEP}", -1.0, 1.0),
    ParamSpec("dropout_prob", -1.0, f"probability of a no-return per beam; {_KEEP}", -1.0, 1.0),
    ParamSpec("odom_model", "", f"odometry noise: alphas or bounded; {_KEEP}"),
    ParamSpec("odom_alpha1", -1.0, f"odometry rotation noise from rotation; {_KEEP}", -1.0, 10.0),
    ParamSpec("odom_alpha2", -1.0, f"odometry rotation noise from translation; {_KEEP}", -1.0, 10.0),
    ParamSpec("odom_alpha3", -1.0, f"odometry translation noise from translation; {_KEEP}", -1.0, 10.0),
    ParamSpec("odom_alpha4", -1.0, f"odometry translation noise from rotation; {_KEEP}", -1.0, 10.0),
    ParamSpec("map_frame", "map", "frame of the map and of ground_truth"),
    ParamSpec("odom_frame", "odom", "frame of odom"),
    ParamSpec("base_frame", "base_link", "child frame of odom and ground_truth"),
    ParamSpec("laser_frame", "laser", "frame of scan"),
    ParamSpec("camera_frame", "camera", "frame of camera/image_raw"),
)
_SPECS = {spec.name: spec for spec in PARAMS}

_LASER_OVERRIDES = {
    "beams": "beams",
    "fov_deg": "fov_deg",
    "range_min": "range_min",
    "range_max": "range_max",
    "rate_hz": "rate_hz",
    "range_noise_model": "range_noise_model",
    "range_noise_std": "range_noise_std",
    "range_noise_bound": "range_noise_bound",
    "outlier_prob": "outlier_prob",
    "dropout_prob": "dropout_prob",
}
_ODOM_OVERRIDES = {
    "odom_model": "model",
    "odom_alpha1": "alpha1",
    "odom_alpha2": "alpha2",
    "odom_alpha3": "alpha3",
    "odom_alpha4": "alpha4",
}


def _overridden(params: dict[str, Any], names: dict[str, str]) -> dict[str, Any]:
    out = {}
    for param, field_name in names.items():
        value = params.get(param, _SPECS[param].default)
        if isinstance(value, str):
            if value:
                out[field_name] = value
        elif value >= 0:
            out[field_name] = value
    return out


def resolve_scenario_path(name: str) -> Path:
    """A scenario path as given, else ``config/scenarios/<name>[.yaml]`` of the package."""
    path = Path(name)
    if path.is_file():
        return path
    from ..registry import config_dir

    for candidate in (config_dir() / "scenarios" / name, config_dir() / "scenarios" / f"{name}.yaml"):
        if candidate.is_file():
            return candidate
    raise ScenarioError(f"scenario {name!r} is neither a file nor a name in {str(config_dir() / 'scenarios')!r}")


def build_scenario(params: dict[str, Any]) -> Scenario:
    """The scenario the parameters describe, with the laser and odometry overrides applied.

    Raises:
        ScenarioError, MapError: naming the bad value.
    """
    laser_changes = _overridden(params, _LASER_OVERRIDES)
    odom_changes = _overridden(params, _ODOM_OVERRIDES)
    if params.get("scenario"):
        scenario = load_scenario(resolve_scenario_path(str(params["scenario"])))
        if not laser_changes and not odom_changes:
            return scenario
        return dataclasses.replace(
            scenario,
            laser=dataclasses.replace(scenario.laser, **laser_changes),
            odometry=dataclasses.replace(scenario.odometry, **odom_changes),
        )
    if not params.get("map_yaml"):
        raise ScenarioError("set either 'scenario' or 'map_yaml' (cmd_vel mode)")
    grid_map = load_map_yaml(str(params["map_yaml"]))
    return Scenario(
        grid_map=grid_map,
        start=(float(params["start_x"]), float(params["start_y"]), float(params["start_yaw"])),
        laser=LaserConfig(**laser_changes),
        odometry=OdometryConfig(**odom_changes),
        robot_radius=float(params["robot_radius"]),
        name="cmd_vel",
    )


def sanitize_command(
    v: float, w: float, max_linear: float, max_angular: float
) -> tuple[float, float, list[str], list[str]]:
    """A safe ``(v, w)`` from a ``cmd_vel``: NaN -> 0, inf / too large -> clamped to the limits.

    Returns ``(v, w, nan_problems, clamp_problems)``, the last two describing what was changed.
    """
    not_a_number: list[str] = []
    clamped: list[str] = []
    out = []
    for name, value, limit in (("linear.x", v, max_linear), ("angular.z", w, max_angular)):
        value = float(value)
        if math.isnan(value):
            not_a_number.append(f"{name} is NaN (stopping)")
            value = 0.0
        elif abs(value) > limit:
            clamped.append(f"{name} {value!r} clamped to +-{limit}")
            value = math.copysign(limit, value)
        out.append(value)
    return out[0], out[1], not_a_number, clamped


# -- messages ------------------------------------------------------------------------------
class StepMessages:
    """Builds the ROS messages of a simulator step (shared by live mode and recording)."""

    def __init__(self, simulator: Simulator, params: dict[str, Any], epoch: float = 0.0) -> None:
        from ..ros import conversions

        self._conv = conversions
        self.simulator = simulator
        self.params = params
        self.epoch = epoch
        laser = simulator.scenario.laser
        self._scan_fields = {
            "angle_min": laser.angle_min,
            "angle_increment": laser.angle_increment,
            "range_min": laser.range_min,
            "range_max": laser.range_max,
            "scan_time": laser.period,
        }

    def stamp(self, step_time: float) -> float:
        return self.epoch + step_time

    def map_message(self):
        msg = self._conv.grid_map_to_msg(self.simulator.grid_map, self.epoch)
        msg.header.frame_id = self.params["map_frame"]
        return msg

    def step_messages(self, step: SimulationStep) -> list[tuple[str, Any]]:
        """``(topic, message)`` of a step in publication order (odometry before the scan it belongs to)."""
        seconds = self.stamp(step.time)
        conv = self._conv
        out = [
            (
                "odom",
                conv.odometry_to_msg(
                    seconds,
                    step.odom_pose,
                    frame_id=self.params["odom_frame"],
                    child_frame_id=self.params["base_frame"],
                    velocity=step.odom_velocity,
                ),
            ),
            (
                "ground_truth",
                conv.odometry_to_msg(
                    seconds,
                    step.true_pose,
                    frame_id=self.params["map_frame"],
                    child_frame_id=self.params["base_frame"],
                    velocity=step.true_velocity,
                ),
            ),
            ("scan", conv.scan_to_msg(seconds, self.params["laser_frame"], ranges=step.ranges, **self._scan_fields)),
        ]
        if step.image is not None:
            out.append(("camera/image_raw", conv.image_to_msg(seconds, self.params["camera_frame"], step.image)))
        return out


def _seed(params: dict[str, Any]) -> int | None:
    seed = int(params.get("seed", -1))
    return None if seed < 0 else seed


# -- record mode --------------------------------------------------------------------------------
def record(bag_dir: str | Path, params: dict[str, Any], *, log=print) -> dict[str, int]:
    """Run the scenario of ``params`` as fast as possible into a new MCAP bag; returns messages per topic."""
    from ..ros.bag import BagWriter

    full = {spec.name: spec.default for spec in PARAMS}
    full.update(params)
    if not full["scenario"]:
        raise ScenarioError("--record needs a scenario (-p scenario:=FILE)")
    scenario = build_scenario(full)
    simulator = Simulator(scenario, seed=_seed(full))
    builder = StepMessages(simulator, full, epoch=0.0)
    counts: dict[str, int] = {}
    started = time.perf_counter()
    with BagWriter(bag_dir, compress=True) as writer:
        writer.write("/map", builder.map_message(), 0)
        counts["/map"] = 1
        for step in simulator.run():
            stamp_ns = int(round(builder.stamp(step.time) * 1e9))
            for topic, msg in builder.step_messages(step):
                writer.write("/" + topic, msg, stamp_ns)
                counts["/" + topic] = counts.get("/" + topic, 0) + 1
    elapsed = time.perf_counter() - started
    size = sum(p.stat().st_size for p in Path(bag_dir).rglob("*") if p.is_file())
    log(
        f"scan_sim: recorded {scenario.name!r} ({scenario.end_time:.1f} s simulated, "
        f"{len(scenario.kidnappings)} kidnappings) into {str(bag_dir)!r} in {elapsed:.1f} s: "
        + ", ".join(f"{topic} {count}" for topic, count in counts.items())
        + f"; {size / 1e6:.2f} MB"
    )
    return counts


# -- parameters without rclpy ----------------------------------------------------------------------
def _coerce(spec: ParamSpec, value: Any) -> Any:
    """A parameter value of the spec's type within its range (as rclpy would enforce)."""
    default = spec.default
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    else:
        ok = isinstance(value, str)
        if not ok and value is not None and not isinstance(value, (list, dict)):
            value, ok = str(value), True
    if not ok:
        raise ScenarioError(f"parameter {spec.name!r} must be of type {type(default).__name__}, got {value!r}")
    if not isinstance(value, (bool, str)):
        if (spec.minimum is not None and value < spec.minimum) or (spec.maximum is not None and value > spec.maximum):
            raise ScenarioError(
                f"parameter {spec.name!r} must be within [{spec.minimum}, {spec.maximum}], got {value!r}"
            )
    return value


def parameters_from_args(
    argv: Sequence[str], specs: Sequence[ParamSpec] = PARAMS, node_name: str = NODE_NAME
) -> dict[str, Any]:
    """Parameter values from ``--ros-args`` (``-p name:=value``, ``--params-file FILE``) without rclpy.

    Later settings override earlier ones, as in ROS 2. Unknown parameter names are refused.
    """
    by_name = {spec.name: spec for spec in specs}
    values: dict[str, Any] = {}

    def put(name: str, raw: Any) -> None:
        if name not in by_name:
            raise ScenarioError(f"unknown parameter {name!r} (known: {', '.join(sorted(by_name))})")
        values[name] = _coerce(by_name[name], raw)

    args = list(argv)
    index = 0
    in_ros_args = False
    while index < len(args):
        arg = args[index]
        if arg == "--ros-args":
            in_ros_args = True
        elif arg == "--":
            in_ros_args = False
        elif in_ros_args and arg in ("-p", "--param") and index + 1 < len(args):
            index += 1
            name, sep, raw = args[index].partition(":=")
            if not sep:
                raise ScenarioError(f"parameter argument {args[index]!r} must be NAME:=VALUE")
            put(name, yaml.safe_load(raw) if raw else "")
        elif in_ros_args and arg == "--params-file" and index + 1 < len(args):
            index += 1
            path = Path(args[index])
            try:
                content = yaml.safe_load(path.read_text()) or {}
            except (OSError, yaml.YAMLError) as exc:
                raise ScenarioError(f"params file {str(path)!r} cannot be read: {exc}") from exc
            for key in ("/**", node_name, f"/{node_name}"):
                section = content.get(key) if isinstance(content, dict) else None
                if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
                    for name, raw in section["ros__parameters"].items():
                        put(name, raw)
        elif in_ros_args and arg in ("-r", "--remap", "--log-level", "-e", "--enclave") and index + 1 < len(args):
            index += 1  # remaps and logging do not matter for recording
        index += 1
    return values


# -- live node -------------------------------------------------------------------------------------
def _make_node(options: argparse.Namespace):
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import OccupancyGrid, Odometry
    from rclpy.node import Node
    from sensor_msgs.msg import Image, LaserScan

    from ..ros.qos import MAP_QOS, RELIABLE_QOS, SENSOR_QOS
    from .common import declare_parameters, guarded

    class ScanSimNode(Node):
        """Publishes the simulator's steps in real time (times ``speed``)."""

        def __init__(self) -> None:
            super().__init__(NODE_NAME)
            self.params = declare_parameters(self, PARAMS)
            try:
                scenario = build_scenario(self.params)
                self.simulator = Simulator(scenario, seed=_seed(self.params))
            except LocalizationSuiteError as exc:
                self.get_logger().fatal(str(exc))
                raise SystemExit(2) from exc
            self.scenario = scenario
            epoch = self.get_clock().now().nanoseconds * 1e-9
            self.messages = StepMessages(self.simulator, self.params, epoch=epoch)
            self.map_pub = self.create_publisher(OccupancyGrid, "map", MAP_QOS)
            self.publishers_by_topic = {
                "scan": self.create_publisher(LaserScan, "scan", SENSOR_QOS),
                "odom": self.create_publisher(Odometry, "odom", RELIABLE_QOS),
                "ground_truth": self.create_publisher(Odometry, "ground_truth", RELIABLE_QOS),
            }
            if scenario.camera is not None:
                self.publishers_by_topic["camera/image_raw"] = self.create_publisher(
                    Image, "camera/image_raw", SENSOR_QOS
                )
            self.map_pub.publish(self.messages.map_message())
            self.command = (0.0, 0.0)
            self.command_time = -math.inf
            self.driven_by_cmd_vel = scenario.motion is None
            if self.driven_by_cmd_vel:
                self.create_subscription(Twist, "cmd_vel", guarded(self, self._on_cmd_vel, "cmd_vel"), 10)
            period = self.simulator.period / float(self.params["speed"])
            self.timer = self.create_timer(period, self._tick)
            self._announced_end = False
            self.get_logger().info(
                f"simulating {scenario.name!r}"
                + (" driven by cmd_vel" if self.driven_by_cmd_vel else f" for {scenario.end_time:.1f} s")
                + f", {scenario.laser.beams} beams at {scenario.laser.rate_hz:g} Hz, speed x{self.params['speed']:g}"
            )

        def _now(self) -> float:
            return self.get_clock().now().nanoseconds * 1e-9

        def _on_cmd_vel(self, msg: Twist) -> None:
            v, w, not_a_number, clamped = sanitize_command(
                msg.linear.x, msg.angular.z, self.params["max_linear"], self.params["max_angular"]
            )
            # Two call sites: rclpy throttles each separately, so neither kind hides the other.
            if not_a_number:
                self.get_logger().warn("bad cmd_vel: " + "; ".join(not_a_number), throttle_duration_sec=2.0)
            if clamped:
                self.get_logger().warn("bad cmd_vel: " + "; ".join(clamped), throttle_duration_sec=2.0)
            self.command = (v, w)
            self.command_time = self._now()

        def _tick(self) -> None:
            if self.simulator.finished and not self.driven_by_cmd_vel:
                if not self._announced_end:
                    self._announced_end = True
                    self.get_logger().info(
                        f"scenario {self.scenario.name!r} ended at {self.scenario.end_time:.1f} s simulated"
                        + (", exiting" if self.params["exit_at_end"] else ", holding the last pose")
                    )
                if self.params["exit_at_end"]:
                    raise SystemExit(0)
            command = None
            if self.driven_by_cmd_vel:
                fresh = self._now() - self.command_time <= self.params["cmd_vel_timeout"]
                command = self.command if fresh else (0.0, 0.0)
            step = self.simulator.step(command)
            if step.blocked:
                self.get_logger().warn(
                    f"cmd_vel blocked by an obstacle at {np.round(step.true_pose, 2).tolist()}",
                    throttle_duration_sec=2.0,
                )
            if step.kidnapped:
                self.get_logger().info(f"kidnapped at t = {step.time:.1f} s to {np.round(step.true_pose, 2).tolist()}")
            for topic, msg in self.messages.step_messages(step):
                self.publishers_by_topic[topic].publish(msg)

    return ScanSimNode()


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--record",
        metavar="DIR",
        help="run the scenario as fast as possible into a new rosbag2 MCAP bag DIR and exit (no DDS)",
    )


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    from rclpy.utilities import remove_ros_args

    from .common import run_node

    plain = remove_ros_args(argv)[1:]
    pre = argparse.ArgumentParser(add_help=False)
    _add_arguments(pre)
    known, _ = pre.parse_known_args(plain)
    if known.record and not {"-h", "--help"} & set(plain):
        try:
            params = parameters_from_args(argv)
            record(known.record, params)
        except LocalizationSuiteError as exc:
            print(f"scan_sim: {exc}", file=sys.stderr)
            return 2
        return 0
    return run_node(NODE_NAME, DESCRIPTION, PARAMS, TOPICS, _make_node, argv, add_arguments=_add_arguments)


if __name__ == "__main__":
    sys.exit(main())
