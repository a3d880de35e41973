"""The node shape all localizers share: subscriptions, publishers, services, map loading.

A concrete node only lists its parameters and turns their values into a core
localizer (``make_localizer``); everything else (the ROS interface of
DESIGN.md) lives here once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, LaserScan
from std_srvs.srv import Empty

from ..core.errors import MapError
from ..core.grid_map import load_map_yaml
from ..core.localizer import Estimate
from ..core.scan import LaserMount
from ..ros.adapter import AdapterOutput, LocalizerAdapter
from ..ros.qos import MAP_QOS, RELIABLE_QOS, SENSOR_QOS
from .common import LASER_MOUNT_PARAMS, ParamSpec, declare_parameters, guarded

__all__ = ["LocalizerNode", "COMMON_PARAMS", "LOCALIZER_TOPICS", "CAMERA_LOCALIZER_TOPICS"]

COMMON_PARAMS = (
    ParamSpec("map_yaml", "", "nav2 map_server YAML to load at start; empty: wait for the map topic"),
    *LASER_MOUNT_PARAMS,
    ParamSpec("max_published_candidates", 2000, "cap on the poses in ~/candidates", 0, 1_000_000),
)

LOCALIZER_TOPICS = """  in:  scan (sensor_msgs/LaserScan), odom (nav_msgs/Odometry), map (nav_msgs/OccupancyGrid),
       initialpose (geometry_msgs/PoseWithCovarianceStamped)
  out: ~/pose (geometry_msgs/PoseWithCovarianceStamped), ~/candidates (geometry_msgs/PoseArray),
       /diagnostics (diagnostic_msgs/DiagnosticArray)
  services: ~/reinitialize_global_localization, ~/request_nomotion_update (std_srvs/Empty)"""

CAMERA_LOCALIZER_TOPICS = """  in:  camera/image_raw (sensor_msgs/Image: mono8, rgb8, bgr8, rgba8, bgra8), odom (nav_msgs/Odometry),
       initialpose (geometry_msgs/PoseWithCovarianceStamped)
  out: ~/pose (geometry_msgs/PoseWithCovarianceStamped), ~/candidates (geometry_msgs/PoseArray),
       /diagnostics (diagnostic_msgs/DiagnosticArray), and the method's extra topics
  services: ~/reinitialize_global_localization, ~/request_nomotion_update (std_srvs/Empty)"""

# Odometry must not be lost, yet must accept best-effort publishers too.
_ODOM_QOS = QoSProfile(depth=50, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT)


class LocalizerNode(Node):
    """Base class of every localizer node.

    Args:
        name: default node name.
        specs: the method's own parameters (the common ones are added).
        make_localizer: builds the core localizer from the parameter values.
        extras: topic suffix -> message type of method-specific outputs.
        extras_builder: turns an estimate into those messages.
        uses_camera: subscribe to ``camera/image_raw`` instead of ``scan``.
    """

    def __init__(
        self,
        name: str,
        specs: Sequence[ParamSpec],
        make_localizer: Callable[[dict[str, Any]], Any],
        *,
        extras: dict[str, type] | None = None,
        extras_builder: Callable[[Estimate], dict[str, Any]] | None = None,
        uses_camera: bool = False,
    ) -> None:
        super().__init__(name)
        self.params = declare_parameters(self, [*COMMON_PARAMS, *specs])
        mount = LaserMount(self.params["laser_x"], self.params["laser_y"], self.params["laser_yaw"])
        self.localizer = make_localizer(self.params)
        self.adapter = LocalizerAdapter(
            self.localizer,
            node_name=self.get_name(),
            log=self._log,
            mount=mount,
            extras_builder=extras_builder,
            max_candidates=self.params["max_published_candidates"],
        )
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, "~/pose", RELIABLE_QOS)
        self.candidates_pub = self.create_publisher(PoseArray, "~/candidates", RELIABLE_QOS)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
        self.extra_pubs = {key: self.create_publisher(kind, f"~/{key}", RELIABLE_QOS) for key, kind in (extras or {}).items()}

        if uses_camera:
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
        if self.params["map_yaml"] and not uses_camera:
            self._load_map(self.params["map_yaml"])
        self.get_logger().info(f"{self.get_name()} ready")

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


def localizer_node_main(module: Any, argv: Sequence[str] | None = None) -> int:
    """``main()`` of a localizer node module.

    The module defines ``NODE_NAME``, ``DESCRIPTION``, ``PARAMS`` (its ParamSpecs),
    ``make_localizer(params) -> core localizer`` and optionally ``EXTRAS``
    (topic suffix -> message type), ``build_extras(estimate)`` and ``USES_CAMERA``.
    The same module attributes let ``rls_bench`` build the localizer without a node.
    """
    from .common import run_node

    return run_node(
        module.NODE_NAME,
        module.DESCRIPTION,
        [*COMMON_PARAMS, *module.PARAMS],
        CAMERA_LOCALIZER_TOPICS if getattr(module, "USES_CAMERA", False) else LOCALIZER_TOPICS,
        lambda _options: LocalizerNode(
            module.NODE_NAME,
            module.PARAMS,
            module.make_localizer,
            extras=getattr(module, "EXTRAS", None),
            extras_builder=getattr(module, "build_extras", None),
            uses_camera=getattr(module, "USES_CAMERA", False),
        ),
        argv,
    )
