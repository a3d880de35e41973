"""The one node shape of every localizer: parameters from its plugin's settings, topics, services, map loading.

A node module hands its :class:`~robot_localization_suite.registry.LocalizerPlugin` (and any
extra outputs) to :func:`run_localizer`; everything of DESIGN.md's ROS interface lives here once,
and the message handling lives in :class:`~robot_localization_suite.ros.adapter.LocalizerAdapter`,
which the benchmark runs too.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, LaserScan
from std_srvs.srv import Empty

from ..core.errors import MapError
from ..core.grid_map import load_map_yaml
from ..core.settings import from_params
from ..registry import LocalizerPlugin, NodeSettings
from ..ros.adapter import AdapterOutput, LocalizerAdapter
from ..ros.extras import Extra
from ..ros.params import declare_settings
from ..ros.qos import MAP_QOS, RELIABLE_QOS, SENSOR_QOS
from .common import guarded, help_parser, run_node

__all__ = ["LocalizerNode", "run_localizer", "topics_text"]

_PACKAGE_LOGGER = logging.getLogger("robot_localization_suite")

# Odometry must not be lost, yet must accept best-effort publishers too.
_ODOM_QOS = QoSProfile(depth=50, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT)


def topics_text(plugin: LocalizerPlugin) -> str:
    """The topics and services of a localizer node, for ``--help``."""
    sensor = ("camera/image_raw (sensor_msgs/Image: mono8, rgb8, bgr8, rgba8, bgra8)" if plugin.uses_camera
              else "scan (sensor_msgs/LaserScan), map (nav_msgs/OccupancyGrid)")
    lines = [
        f"  in:  {sensor}, odom (nav_msgs/Odometry), initialpose (geometry_msgs/PoseWithCovarianceStamped)",
        "  out: ~/pose (geometry_msgs/PoseWithCovarianceStamped), ~/candidates (geometry_msgs/PoseArray),",
        "       /diagnostics (diagnostic_msgs/DiagnosticArray)",
        *(f"       {output}" for output in plugin.outputs),
        "  services: ~/reinitialize_global_localization, ~/request_nomotion_update (std_srvs/Empty)",
    ]
    return "\n".join(lines)


class _RosLogHandler(logging.Handler):
    """Python log records of the package (cache warnings, relearning notices) into the node's ROS log."""

    def __init__(self, sink: Callable[[str, str], None]) -> None:
        super().__init__(logging.INFO)
        self._sink = sink

    def emit(self, record: logging.LogRecord) -> None:
        level = "error" if record.levelno >= logging.ERROR else "warn" if record.levelno >= logging.WARNING else "info"
        self._sink(level, record.getMessage())


class LocalizerNode(Node):
    """A localizer node running one plugin.

    Args:
        plugin: what the node runs (its settings declare the node's parameters).
        extras: topic suffix -> :class:`~robot_localization_suite.ros.extras.Extra` of method-specific outputs.
        node_name: default node name (``-r __node:=...`` still renames it); default: the plugin's name.
    """

    def __init__(
        self, plugin: LocalizerPlugin, *, extras: Mapping[str, Extra] | None = None, node_name: str | None = None
    ) -> None:
        super().__init__(node_name or plugin.name)
        self.plugin = plugin
        # Before anything that may log: the core reports through Python logging (a corrupt cache, a relearning).
        self._log_handler = _RosLogHandler(self._log)
        _PACKAGE_LOGGER.addHandler(self._log_handler)
        _PACKAGE_LOGGER.setLevel(logging.INFO)
        values = declare_settings(self, NodeSettings, plugin.settings)
        self.node_settings = from_params(NodeSettings, values)
        self.settings = from_params(plugin.settings, values)
        self.localizer = plugin.create(self.settings)
        extras = dict(extras or {})
        self.adapter = LocalizerAdapter(
            self.localizer,
            node_name=self.get_name(),
            log=self._log,
            mount=self.node_settings.mount,
            extras_builder=(lambda estimate: {key: extra.build(estimate) for key, extra in extras.items()})
            if extras else None,
            max_candidates=self.node_settings.max_published_candidates,
            max_future_s=self.node_settings.max_future_s,
            time_jump_reset_s=self.node_settings.time_jump_reset_s,
            clock=lambda: self.get_clock().now().nanoseconds * 1e-9,
        )
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, "~/pose", RELIABLE_QOS)
        self.candidates_pub = self.create_publisher(PoseArray, "~/candidates", RELIABLE_QOS)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
        self.extra_pubs = {key: self.create_publisher(extra.kind, f"~/{key}", RELIABLE_QOS)
                           for key, extra in extras.items()}

        if plugin.uses_camera:
            self.create_subscription(Image, "camera/image_raw", guarded(self, self._on_image, "image update"), SENSOR_QOS)
        else:
            self.create_subscription(LaserScan, "scan", guarded(self, self._on_scan, "scan update"), SENSOR_QOS)
            self.create_subscription(OccupancyGrid, "map", guarded(self, self.adapter.on_map_msg, "map"), MAP_QOS)
        self.create_subscription(Odometry, "odom", guarded(self, self.adapter.on_odom_msg, "odometry"), _ODOM_QOS)
        self.create_subscription(
            PoseWithCovarianceStamped,
            "initialpose",
            guarded(self, self.adapter.on_initial_pose_msg, "initial pose"),
            RELIABLE_QOS,
        )
        self.create_service(Empty, "~/reinitialize_global_localization", self._on_reinitialize)
        self.create_service(Empty, "~/request_nomotion_update", self._on_nomotion)
        if self.node_settings.map_yaml and not plugin.uses_camera:
            self._load_map(self.node_settings.map_yaml)
        self.get_logger().info(f"{self.get_name()} ready")

    def destroy_node(self) -> None:
        _PACKAGE_LOGGER.removeHandler(self._log_handler)
        super().destroy_node()

    def _log(self, level: str, text: str) -> None:
        # One call site per severity: rclpy refuses a second severity from the same
        # caller ("Logger severity cannot be changed between calls").
        logger = self.get_logger()
        if level == "debug":
            logger.debug(text)
        elif level == "info":
            logger.info(text)
        elif level == "warn":
            logger.warning(text)
        else:
            logger.error(text)

    def _load_map(self, path: str) -> None:
        try:
            self.adapter.set_map(load_map_yaml(path))
        except MapError as exc:
            self.get_logger().error(f"{exc}; waiting for a map on the map topic")

    def _on_reinitialize(self, request: Empty.Request, response: Empty.Response) -> Empty.Response:
        guarded(self, lambda _: self.adapter.reinitialize(), "reinitialize")(None)
        return response

    def _on_nomotion(self, request: Empty.Request, response: Empty.Response) -> Empty.Response:
        self.adapter.request_nomotion_update()
        return response

    def _on_scan(self, msg: LaserScan) -> None:
        self.publish(self.adapter.on_scan_msg(msg))

    def _on_image(self, msg: Image) -> None:
        self.publish(self.adapter.on_image_msg(msg))

    def publish(self, output: AdapterOutput | None) -> None:
        if output is None:
            return
        self.pose_pub.publish(output.pose)
        self.candidates_pub.publish(output.candidates)
        self.diagnostics_pub.publish(output.diagnostics)
        for key, msg in output.extras.items():
            if key in self.extra_pubs:
                self.extra_pubs[key].publish(msg)


def run_localizer(
    plugin: LocalizerPlugin, argv: Sequence[str] | None = None, *, extras: Mapping[str, Extra] | None = None
) -> int:
    """``main()`` of a localizer node module: ``--help`` from the plugin's settings, then the node."""
    parser = help_parser(plugin.name, plugin.description, (NodeSettings, plugin.settings), topics_text(plugin))
    return run_node(parser, lambda _options: LocalizerNode(plugin, extras=extras), argv)
