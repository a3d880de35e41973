"""``scan_sim``: the simulated robot as a ROS 2 node, or a bag recorder.

Live (default): steps the simulator on a timer at ``rate_hz * speed`` and publishes ``map``
(reliable, transient local, once), ``scan``, ``odom``, ``ground_truth`` and
``camera/image_raw`` when the scenario has a camera, stamped with the node's start time plus
the simulated time. A scenario's map change publishes the new map on ``map`` (same QoS); its
reinitialization request calls every ``*/reinitialize_global_localization`` service found and
publishes the request on ``operator/reinitialize_global_localization`` (std_msgs/Header). With ``scenario`` the robot follows it and the node exits with code 0 at
its end (``exit_at_end``); without, it drives on ``map_yaml`` by ``cmd_vel`` (bad commands
clamped and logged, a stop after ``cmd_vel_timeout``).
Record: ``scan_sim --record DIR --ros-args -p scenario:=FILE`` writes the whole scenario into an
MCAP bag as fast as possible, without DDS; the ``--ros-args`` parameters are read here with the
same names, types and ranges; SIGINT or SIGTERM ends it early with a complete bag (exit 0).
Parameters: :class:`~robot_localization_suite.core.sim.settings.ScanSimSettings`.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import BagError, LocalizationSuiteError, ScenarioError, SettingsError
from ..core.settings import from_params, params_from_ros_args, unknown_params
from ..core.sim.settings import ScanSimSettings

__all__ = ["NODE_NAME", "DESCRIPTION", "TOPICS", "sanitize_command", "settings_from_args",
           "main"]

NODE_NAME = "scan_sim"
DESCRIPTION = (
    "Simulated robot: publishes map, laser scans, wheel odometry, ground truth (and camera images) "
    "from a scenario or from cmd_vel; --record DIR writes a rosbag2 MCAP bag instead."
)
TOPICS = """  out: map (nav_msgs/OccupancyGrid, transient local; again at a scenario's map change),
       operator/reinitialize_global_localization (std_msgs/Header, a scenario's reinitialization request),
       scan (sensor_msgs/LaserScan),
       odom (nav_msgs/Odometry), /tf (odom -> base), /tf_static (base -> laser, transient local),
       ground_truth (nav_msgs/Odometry in map),
       camera/image_raw (sensor_msgs/Image, when the scenario has a camera)
  in:  cmd_vel (geometry_msgs/Twist, only without a scenario)
  calls: */reinitialize_global_localization (std_srvs/Empty) of every node offering it, at a reinitialization"""


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


def settings_from_args(argv: Sequence[str]) -> ScanSimSettings:
    """The settings of ``--ros-args`` (``-p``, ``--params-file``) without rclpy; unknown names are refused.

    Raises:
        SettingsError: an unknown name, a wrong type or a value out of range.
    """
    values = params_from_ros_args(argv, NODE_NAME)
    unknown = unknown_params(ScanSimSettings, values)
    if unknown:
        raise SettingsError(f"unknown parameter(s) {', '.join(map(repr, unknown))} of {NODE_NAME}")
    return from_params(ScanSimSettings, values)


# -- live node -------------------------------------------------------------------------------------
def _make_node(options: argparse.Namespace) -> Any:
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import OccupancyGrid, Odometry
    from rclpy.node import Node
    from sensor_msgs.msg import Image, LaserScan
    from std_msgs.msg import Header
    from std_srvs.srv import Empty

    from ..core.sim.config import REINITIALIZE_TOPIC
    from ..ros.params import declare_settings, parameter_values
    from ..ros.qos import MAP_QOS, RELIABLE_QOS, SENSOR_QOS, TF_QOS, TF_STATIC_QOS
    from ..ros.sim_messages import StepMessages, make_simulator
    from ..ros.tf import TFMessage
    from .common import guarded

    class ScanSimNode(Node):
        """Publishes the simulator's steps in real time (times ``speed``)."""

        def __init__(self) -> None:
            super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True)
            unused = declare_settings(self, ScanSimSettings)
            if unused:
                self.get_logger().warn(f"not used by this node: {', '.join(unused)}")
            self.settings = from_params(ScanSimSettings, parameter_values(self, ScanSimSettings))
            try:
                self.simulator = make_simulator(self.settings)
            except LocalizationSuiteError as exc:
                self.get_logger().fatal(str(exc))
                raise SystemExit(2) from exc
            scenario = self.scenario = self.simulator.scenario
            epoch = self.get_clock().now().nanoseconds * 1e-9
            self.messages = StepMessages(self.simulator, self.settings, epoch=epoch,
                                         time_scale=1.0 / self.settings.speed)
            self.map_pub = self.create_publisher(OccupancyGrid, "map", MAP_QOS)
            self.publishers_by_topic = {
                "scan": self.create_publisher(LaserScan, "scan", SENSOR_QOS),
                "odom": self.create_publisher(Odometry, "odom", RELIABLE_QOS),
                "ground_truth": self.create_publisher(Odometry, "ground_truth", RELIABLE_QOS),
                "map": self.map_pub,
                REINITIALIZE_TOPIC: self.create_publisher(Header, REINITIALIZE_TOPIC, RELIABLE_QOS),
            }
            self._reinitialize_clients: dict[str, Any] = {}
            if scenario.camera is not None:
                self.publishers_by_topic["camera/image_raw"] = self.create_publisher(
                    Image, "camera/image_raw", SENSOR_QOS
                )
            if TFMessage is not None:
                self.publishers_by_topic["tf"] = self.create_publisher(TFMessage, "/tf", TF_QOS)
                self.publishers_by_topic["tf_static"] = self.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
            else:
                self.get_logger().warn("tf2_msgs not installed: no /tf and /tf_static")
            self.map_pub.publish(self.messages.map_message())
            for topic, msg in self.messages.static_messages():
                self.publishers_by_topic[topic].publish(msg)
            self.command = (0.0, 0.0)
            self.command_time = -math.inf
            self.driven_by_cmd_vel = scenario.motion is None
            if self.driven_by_cmd_vel:
                self.create_subscription(Twist, "cmd_vel", guarded(self, self._on_cmd_vel, "cmd_vel"), 10)
            self.timer = self.create_timer(self.simulator.period / self.settings.speed, self._tick)
            self._announced_end = False
            self.get_logger().info(
                f"simulating {scenario.name!r}"
                + (" driven by cmd_vel" if self.driven_by_cmd_vel else f" for {scenario.end_time:.1f} s")
                + f", {scenario.laser.beams} beams at {scenario.laser.rate_hz:g} Hz, speed x{self.settings.speed:g}"
            )

        def _now(self) -> float:
            return self.get_clock().now().nanoseconds * 1e-9

        def _on_cmd_vel(self, msg: Twist) -> None:
            v, w, not_a_number, clamped = sanitize_command(
                msg.linear.x, msg.angular.z, self.settings.max_linear, self.settings.max_angular
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
                        + (", exiting" if self.settings.exit_at_end else ", holding the last pose")
                    )
                if self.settings.exit_at_end:
                    raise SystemExit(0)
            command = None
            if self.driven_by_cmd_vel:
                fresh = self._now() - self.command_time <= self.settings.cmd_vel_timeout
                command = self.command if fresh else (0.0, 0.0)
            step = self.simulator.step(command)
            if step.blocked:
                self.get_logger().warn(
                    f"cmd_vel blocked by an obstacle at {np.round(step.true_pose, 2).tolist()}",
                    throttle_duration_sec=2.0,
                )
            if step.kidnapped:
                self.get_logger().info(f"kidnapped at t = {step.time:.1f} s to {np.round(step.true_pose, 2).tolist()}")
            if step.new_map is not None:
                self.get_logger().info(f"the map changed at t = {step.time:.1f} s: publishing it on "
                                       f"{self.map_pub.topic_name}")
            for topic, msg in self.messages.step_messages(step):
                self.publishers_by_topic[topic].publish(msg)
            if step.reinitialize:
                self._request_reinitialization(step.time)

        def _request_reinitialization(self, time: float) -> None:
            """The simulated operator: call every ``*/reinitialize_global_localization`` service there is."""
            names = sorted(name for name, types in self.get_service_names_and_types()
                           if name.endswith("/reinitialize_global_localization") and "std_srvs/srv/Empty" in types)
            for name in names:
                client = self._reinitialize_clients.get(name)
                if client is None:
                    client = self._reinitialize_clients[name] = self.create_client(Empty, name)
                client.call_async(Empty.Request())
            self.get_logger().info(f"reinitialization requested at t = {time:.1f} s: called "
                                   + (", ".join(names) if names else "no service (none offers reinitialize_global_localization)"))

    return ScanSimNode()


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--record",
        metavar="DIR",
        help="run the scenario as fast as possible into a new rosbag2 MCAP bag DIR and exit (no DDS)",
    )


def _file_in_the_way(folder: Path) -> Path | None:
    """The plain file standing where ``folder`` or one of its parents should be, if any."""
    return next((path for path in (folder, *folder.parents) if path.exists() and not path.is_dir()), None)


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[Callable[[], str | None]]:
    """While recording, SIGINT and SIGTERM ask for a stop after the current step (so the bag is closed).

    Yields the question the recorder asks: the signal's name once one came, else None.
    """
    received: list[str] = []
    if threading.current_thread() is not threading.main_thread():  # only the main thread may set handlers
        yield lambda: None
        return

    def note(signum: int, _frame: object) -> None:
        received.append(signal.Signals(signum).name)

    previous = {number: signal.signal(number, note) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield lambda: received[0] if received else None
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    from rclpy.utilities import remove_ros_args

    from .common import help_parser, run_node

    plain = remove_ros_args(argv)[1:]
    pre = argparse.ArgumentParser(add_help=False)
    _add_arguments(pre)
    known, _ = pre.parse_known_args(plain)
    if known.record and not {"-h", "--help"} & set(plain):
        with _stop_on_signals() as stop_requested:
            try:
                settings = settings_from_args(argv)
                if not settings.scenario:
                    raise ScenarioError("--record needs a scenario (-p scenario:=FILE)")
                if (blocked := _file_in_the_way(Path(known.record))) is not None:
                    raise BagError(f"--record {known.record!r}: {str(blocked)!r} is a file, not a folder")
                from ..ros.sim_messages import make_simulator, record

                record(known.record, make_simulator(settings), settings, stop_requested=stop_requested)
            except LocalizationSuiteError as exc:
                print(f"scan_sim: {exc}", file=sys.stderr)
                return 2
        return 0
    parser = help_parser(NODE_NAME, DESCRIPTION, (ScanSimSettings,), TOPICS)
    _add_arguments(parser)
    return run_node(parser, _make_node, argv)


if __name__ == "__main__":
    sys.exit(main())
