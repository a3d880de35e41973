"""The one node shape of every localizer: a lifecycle node as nav2_amcl is, running its plugin's method.

``configure`` reads the parameters (:class:`~robot_localization_suite.registry.NodeSettings` and the
plugin's settings), builds the method, loads ``map_yaml`` and precomputes; ``activate`` starts the
outputs (pose, candidates, particle cloud, diagnostics, ``map -> odom`` on ``/tf``); ``deactivate``
stops them; ``cleanup`` frees the method; ``shutdown`` ends the process. Parameters change live
(``ros2 param set``), checked against the same ranges; a change of a method parameter rebuilds the
method around its last pose, as nav2_amcl reinitialises its filter. The message handling lives in
:class:`~robot_localization_suite.ros.adapter.LocalizerAdapter`, which the benchmark runs too.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, LaserScan
from std_srvs.srv import Empty

from ..core.cache import log_kernel_compilations
from ..core.errors import LocalizationSuiteError, SettingsError
from ..core.grid_map import load_map_yaml
from ..core.scan import LaserMount
from ..core.settings import Settings, from_params, parameters
from ..registry import LocalizerPlugin, NodeSettings
from ..ros import nav2, tf
from ..ros.adapter import AdapterOutput, LocalizerAdapter, ThrottledLog
from ..ros.background import BackgroundWork
from ..ros.conversions import progress_diagnostics, stamp_to_seconds
from ..ros.extras import Extra
from ..ros.params import declare_settings, parameter_values
from ..ros.qos import MAP_QOS, POSE_QOS, RELIABLE_QOS, SENSOR_INPUT_QOS, SENSOR_QOS, TF_QOS, TF_STATIC_QOS
from .common import guarded, help_parser, run_node

__all__ = ["LocalizerNode", "run_localizer", "topics_text"]

_PACKAGE_LOGGER = logging.getLogger("robot_localization_suite")

# Odometry must not be lost, yet must accept best-effort publishers too.
_ODOM_QOS = QoSProfile(depth=50, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT)
# How often the inputs are checked for silence once active [s].
_WATCH_PERIOD_S = 0.5
# How long scans wait for the laser mount on /tf_static before the laser_x/y/yaw parameters are used [s].
_MOUNT_WAIT_S = 5.0
# inputs waiting for their odometry, at most (nav2_amcl's scan filter queues 10; a 40 Hz scanner in 1 s: 40)
MAX_WAITING_INPUTS = 100


def topics_text(plugin: LocalizerPlugin) -> str:
    """The topics and services of a localizer node, for ``--help``."""
    sensor = ("camera/image_raw (sensor_msgs/Image: mono8, rgb8, bgr8, rgba8, bgra8)" if plugin.uses_camera
              else "scan (sensor_msgs/LaserScan), map (nav_msgs/OccupancyGrid)")
    if plugin.camera_cue:
        sensor += ",\n       camera/image_raw (sensor_msgs/Image, with a camera_topomap)"
    lines = [
        f"  in:  {sensor}, odom (nav_msgs/Odometry) or /tf (odom_source), /tf_static (laser mount),",
        "       initialpose (geometry_msgs/PoseWithCovarianceStamped, in global_frame_id)",
        "  out: ~/pose (geometry_msgs/PoseWithCovarianceStamped, reliable + transient local as nav2's amcl_pose),",
        "       /tf (map -> odom), ~/candidates (geometry_msgs/PoseArray),",
        "       ~/particle_cloud (nav2_msgs/ParticleCloud, where nav2_msgs is installed),",
        "       /diagnostics (diagnostic_msgs/DiagnosticArray)",
        *(f"       {output}" for output in plugin.outputs),
        "  services: ~/reinitialize_global_localization, ~/request_nomotion_update (std_srvs/Empty),",
        "       ~/set_initial_pose (nav2_msgs/SetInitialPose), and the lifecycle_msgs services of a lifecycle node",
        "  lifecycle: starts unconfigured; configure, then activate (ros2 lifecycle set, rls_run, or nav2's",
        "       lifecycle manager) before it localizes",
    ]
    return "\n".join(lines)


class _RosLogHandler(logging.Handler):
    """Python log records of the package (cache warnings, relearning notices) into the node's ROS log."""

    def __init__(self, sink: Callable[[str, str], None]) -> None:
        super().__init__(logging.INFO)
        self._sink = sink

    def emit(self, record: logging.LogRecord) -> None:
        # Several nodes in one process (a container) each have a handler: one of them shows the record.
        if getattr(record, "rls_shown", False):
            return
        record.rls_shown = True
        level = "error" if record.levelno >= logging.ERROR else "warn" if record.levelno >= logging.WARNING else "info"
        self._sink(level, record.getMessage())


class LocalizerNode(LifecycleNode):
    """A localizer lifecycle node running one plugin.

    Args:
        plugin: what the node runs (its settings declare the node's parameters).
        extras: topic suffix -> :class:`~robot_localization_suite.ros.extras.Extra` of method-specific outputs.
        node_name: default node name (``-r __node:=...`` still renames it); default: the plugin's name.
        node_options: for rclpy's ``Node`` (a container passes each node its own ``cli_args``).

    Raises:
        SettingsError: a parameter override of the wrong type or out of range, naming it.
    """

    def __init__(
        self, plugin: LocalizerPlugin, *, extras: Mapping[str, Extra] | None = None, node_name: str | None = None,
        **node_options: Any,
    ) -> None:
        # Overrides are declared as they come so that those this node does not have can be listed.
        super().__init__(node_name or plugin.name, automatically_declare_parameters_from_overrides=True,
                         **node_options)
        self.plugin = plugin
        self.extras = dict(extras or {})
        self._answer_every_transition_request()
        # Before anything that may log: the core reports through Python logging (a corrupt cache, a relearning).
        self._log_handler = _RosLogHandler(self._log)
        _PACKAGE_LOGGER.addHandler(self._log_handler)
        _PACKAGE_LOGGER.setLevel(logging.INFO)
        log_kernel_compilations()  # a cold cache says what it compiles during configure
        self.throttled = ThrottledLog(self._log)
        self._classes: tuple[type[Settings], ...] = (NodeSettings, plugin.settings)
        self.unused_parameters = declare_settings(self, *self._classes)
        self._table = {p.name: p for cls in self._classes for p in parameters(cls)}
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self.adapter: LocalizerAdapter | None = None
        self.node_settings: NodeSettings = NodeSettings()
        self.settings: Settings = plugin.settings()
        self.tf_buffer = tf.TransformBuffer(self.throttled)
        self._fresh_method = True
        self._map_received = False
        self.active = False
        self.exit_requested = False
        self._entities: list[Any] = []  # subscriptions, services, timers of the configured node
        self._lifecycle_pubs: list[Any] = []
        self._watchdog: Any = None
        # Kept across cleanup, as nav2_amcl keeps last_published_pose_: (pose, covariance) of the last estimate.
        self.last_pose: tuple[np.ndarray, np.ndarray] | None = None
        self._mount_frame = ""  # the laser frame the mount in use was looked up for ("": not looked up)
        self._pending_initial_pose: PoseWithCovarianceStamped | None = None  # received while inactive
        # Slow work (a new map, precomputation for the scanner) runs here, off the executor.
        self._work = BackgroundWork(self._log)
        self._pending_map: Any = None
        # Requests that restart the method (initial pose, global localization) received during that work: applied,
        # in order, when it ends (the method is being set up in another thread meanwhile).
        self._deferred: list[Callable[[], None]] = []
        self.get_logger().info(f"{self.get_name()} unconfigured: waiting for the configure transition")

    # -- parameters -------------------------------------------------------------------------
    def _values(self) -> dict[str, Any]:
        return parameter_values(self, *self._classes)

    def _read_settings(self, values: Mapping[str, Any]) -> tuple[NodeSettings, Settings]:
        return from_params(NodeSettings, values), from_params(self.plugin.settings, values)

    def _check_parameters(self, changed: list[Parameter]) -> SetParametersResult:
        """Every change is checked as at start-up (type, range, choices, cross-field rules); refused with the reason."""
        values = self._values()
        try:
            for param in changed:
                if param.name in self._table:
                    self._table[param.name].from_ros(param.value)
                    values[param.name] = param.value
            self._read_settings(values)
        except SettingsError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, changed: list[Parameter]) -> None:
        """A configured node takes a change at once: node settings in place, a method's by rebuilding it."""
        if self.adapter is None:
            return  # read at configure
        # A rebuild while a map is set up (or a scanner prepared for) would leave that work to the old method.
        if self._when_idle("parameter change", lambda: self._apply_parameters(changed)):
            return
        old_node, old_method = self.node_settings, self.settings
        self.node_settings, self.settings = self._read_settings(self._values())
        names = ", ".join(f"{p.name}={p.value!r}" for p in changed)
        ns = self.node_settings
        self.adapter.max_candidates = ns.max_published_candidates
        self.adapter.clock.max_future_s = ns.max_future_s
        self.adapter.clock.time_jump_reset_s = ns.time_jump_reset_s
        self.adapter.global_frame = ns.global_frame_id
        self.tf_buffer.tolerance_s = ns.transform_tolerance
        # Before the first scan the mount is not looked up yet: the rebuilt method looks it up then too.
        known = self.adapter.mount_known
        mount_changed = known and ns.mount != old_node.mount and self.adapter.mount == old_node.mount
        if self.settings != old_method or mount_changed:
            self.get_logger().info(f"{names}: rebuilding the method around its last pose")
            self._build_method(mount=(ns.mount if mount_changed else self.adapter.mount) if known else None)
        else:
            self.get_logger().info(f"{names}: in effect")

    def _answer_every_transition_request(self) -> None:
        """A ``change_state`` request for a transition the current state has not (configure twice, activate while
        unconfigured), sent by id as nav2's lifecycle manager sends it, made rclpy raise out of the service and end
        the process; it is refused (``success`` false) with a warning instead, as one sent by label already is."""
        service = getattr(self, "_service_change_state", None)
        if service is None:
            return
        answer = service.callback

        def refusing_invalid(request: Any, response: Any) -> Any:
            try:
                return answer(request, response)
            except RuntimeError as exc:  # rclpy's RCLError: "Transition is not registered"
                state = self._state_machine.current_state[1]
                self.get_logger().warning(f"refusing lifecycle transition {request.transition.id} "
                                          f"({request.transition.label or 'no label'}) from state {state!r}: {exc}")
                response.success = False
                return response

        service.callback = refusing_invalid

    # -- lifecycle ----------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        started = time.perf_counter()
        try:
            self.node_settings, self.settings = self._read_settings(self._values())
        except SettingsError as exc:
            self.get_logger().error(f"configure failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        if self.unused_parameters:
            self.get_logger().warn(f"not used by this node: {', '.join(self.unused_parameters)}")
        ns = self.node_settings
        self.tf_buffer = tf.TransformBuffer(self.throttled, tolerance_s=ns.transform_tolerance,
                                            time_jump_reset_s=ns.time_jump_reset_s,
                                            ignore=[(ns.global_frame_id, ns.odom_frame_id)])
        self._map_received = False
        try:
            self._build_method()
            if ns.map_yaml and not self.plugin.uses_camera:
                self._set_map(load_map_yaml(ns.map_yaml))
        except LocalizationSuiteError as exc:
            self.get_logger().error(f"configure failed: {exc}")
            self._destroy_entities()
            self.adapter = None
            return TransitionCallbackReturn.FAILURE
        self._create_entities()
        self.get_logger().info(f"configured in {time.perf_counter() - started:.2f} s")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        ns = self.node_settings
        pending, self._pending_initial_pose = self._pending_initial_pose, None
        assert self.adapter is not None
        if ns.set_initial_pose:
            self._set_initial_pose(np.array(ns.initial_pose), None, "initial_pose.* parameters")
        elif pending is not None and self.adapter.on_initial_pose_msg(pending):  # checked as an active node's
            self.get_logger().info("starting from the initial pose received while inactive")
            self._fresh_method = False
        elif self.last_pose is not None and not ns.always_reset_initial_pose and self._fresh_method:
            self._set_initial_pose(*self.last_pose, "the last known pose")
        now = time.monotonic()
        self._activated_at = now
        self._last_input = {"sensor": now, "odometry": now}
        self._warned = {"sensor": now, "odometry": now, "map": now}
        self._watchdog = self.create_timer(_WATCH_PERIOD_S, self._watch_inputs)
        self.active = True
        self.get_logger().info("active")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        if self._watchdog is not None:
            self.destroy_timer(self._watchdog)
            self._watchdog = None
        self.get_logger().info("inactive")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy_entities()
        self.adapter = None
        self._deferred.clear()
        self.get_logger().info("cleaned up")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        if self._watchdog is not None:
            self.destroy_timer(self._watchdog)
            self._watchdog = None
        self._destroy_entities()
        self.adapter = None
        self.exit_requested = True
        self.get_logger().info("shut down")
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self._destroy_entities()
        self.adapter = None
        return TransitionCallbackReturn.SUCCESS

    # -- the configured node ------------------------------------------------------------------
    @property
    def localizer(self) -> Any:
        return None if self.adapter is None else self.adapter.localizer

    def _build_method(self, mount: LaserMount | None = None) -> None:
        """The method and its adapter from the current settings; the map and the last pose carried over."""
        previous = self.adapter
        ns = self.node_settings
        extras = self.extras
        self.adapter = LocalizerAdapter(
            self.plugin.create(self.settings),
            node_name=self.get_name(),
            log=self._log,
            mount=mount,
            extras_builder=(lambda estimate: {key: extra.build(estimate) for key, extra in extras.items()})
            if extras else None,
            max_candidates=ns.max_published_candidates,
            max_future_s=ns.max_future_s,
            time_jump_reset_s=ns.time_jump_reset_s,
            global_frame=ns.global_frame_id,
            # The mount comes from /tf_static with the first scan (camera methods need none).
            defer_mount=mount is None and not self.plugin.uses_camera,
            clock=lambda: self.get_clock().now().nanoseconds * 1e-9,
        )
        self.adapter.log = self.throttled
        self._fresh_method = True
        self._mount_wait_since: float | None = None
        if mount is None:
            self._mount_frame = ""  # the laser frame the mount in use was looked up for
        self._waiting: list[tuple[float, Any, Callable[[Any], AdapterOutput | None]]] = []
        if previous is not None:
            if previous.current_map is not None:
                self.adapter.set_map(previous.current_map)
            if self.last_pose is not None:
                self.adapter.set_initial_pose(*self.last_pose)

    def _create_entities(self) -> None:
        ns = self.node_settings
        pub = self._lifecycle_publisher
        self.pose_pub = pub(PoseWithCovarianceStamped, "~/pose", POSE_QOS)
        self.candidates_pub = pub(PoseArray, "~/candidates", RELIABLE_QOS)
        self.diagnostics_pub = pub(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
        # nav2_amcl publishes its particle cloud best effort (SensorDataQoS).
        self.cloud_pub = pub(nav2.ParticleCloud, "~/particle_cloud", SENSOR_QOS) if nav2.ParticleCloud else None
        self.tf_pub = pub(tf.TFMessage, "/tf", TF_QOS) if tf.TFMessage else None
        self.extra_pubs = {key: pub(extra.kind, f"~/{key}", RELIABLE_QOS) for key, extra in self.extras.items()}
        missing = [name for name, kind in (("tf2_msgs", tf.TFMessage), ("nav2_msgs", nav2.ParticleCloud)) if kind is None]
        if missing:
            self.get_logger().warn(f"{' and '.join(missing)} not installed: no "
                                   + " and no ".join({"tf2_msgs": "map -> odom on /tf",
                                                     "nav2_msgs": "~/particle_cloud, ~/set_initial_pose"}[m]
                                                     for m in missing)
                                   + " (a ROS 2 install has them; a PyPI install gets them from `make`)")
        sub = self.create_subscription
        entities = self._entities
        self.odom_sub: Any = None
        if self.plugin.uses_camera:
            self.sensor_sub = sub(Image, "camera/image_raw", guarded(self, self._on_image, "image update"),
                                  SENSOR_INPUT_QOS)
        else:
            self.sensor_sub = sub(LaserScan, "scan", guarded(self, self._on_scan, "scan update"),
                                  SENSOR_INPUT_QOS)
            entities.append(sub(OccupancyGrid, "map", guarded(self, self._on_map, "map"), MAP_QOS))
            if self.plugin.reads_camera_cue(self.settings):
                entities.append(sub(Image, "camera/image_raw", guarded(self, self._on_camera_cue, "image cue"),
                                    SENSOR_INPUT_QOS))
        entities.append(self.sensor_sub)
        if tf.TFMessage is not None:
            entities.append(sub(tf.TFMessage, "/tf_static", guarded(self, self._on_tf_static, "/tf_static"),
                                TF_STATIC_QOS))
        if ns.odom_source == "tf":
            if tf.TFMessage is None:
                self.get_logger().error("odom_source tf needs tf2_msgs: no odometry until it is installed")
            else:
                self.odom_sub = sub(tf.TFMessage, "/tf", guarded(self, self._on_tf, "/tf"), TF_QOS)
                entities.append(self.odom_sub)
        else:
            self.odom_sub = sub(Odometry, "odom", guarded(self, self._on_odom, "odometry"), _ODOM_QOS)
            entities.append(self.odom_sub)
        entities.append(sub(PoseWithCovarianceStamped, "initialpose",
                            guarded(self, self._on_initial_pose, "initial pose"), RELIABLE_QOS))
        entities.append(self.create_service(Empty, "~/reinitialize_global_localization", self._on_reinitialize))
        entities.append(self.create_service(Empty, "~/request_nomotion_update", self._on_nomotion))
        if nav2.SetInitialPose is not None:
            entities.append(self.create_service(nav2.SetInitialPose, "~/set_initial_pose", self._on_set_initial_pose))
        self._last_tf: tuple[float, np.ndarray] | None = None

    def _lifecycle_publisher(self, kind: type, topic: str, qos: QoSProfile) -> Any:
        publisher = self.create_lifecycle_publisher(kind, topic, qos)
        self._lifecycle_pubs.append(publisher)
        return publisher

    def _destroy_entities(self) -> None:
        for entity in self._entities:
            if hasattr(entity, "timer_period_ns"):
                self.destroy_timer(entity)
            elif hasattr(entity, "srv_type"):
                self.destroy_service(entity)
            else:
                self.destroy_subscription(entity)
        for publisher in self._lifecycle_pubs:
            self.destroy_lifecycle_publisher(publisher)
        self._entities, self._lifecycle_pubs = [], []

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

    # -- inputs -------------------------------------------------------------------------------
    def _set_map(self, grid_map: Any) -> None:
        assert self.adapter is not None
        self.adapter.set_map(grid_map)
        self._map_received = True

    def _on_map(self, msg: OccupancyGrid) -> None:
        if self.adapter is None:
            return
        if self.node_settings.first_map_only and self._map_received:
            self.throttled("info", "first_map_only", "ignoring a new map: first_map_only is set")
            return
        grid_map = self.adapter.map_from_msg(msg)
        if grid_map is None:
            return
        if self._work.busy:
            # The newest map wins; it is set up after the running job, which may be setting up another map:
            # compared with the map in use only then (the one in use now may be about to be replaced).
            self._pending_map = grid_map
            self.throttled("info", "map_queued", f"map queued until {self._work.what} ends")
            return
        if self.adapter.is_current_map(grid_map):
            self._map_received = True
            return
        self._start_map_setup(grid_map)

    def _start_map_setup(self, grid_map: Any) -> None:
        """Set up a map from the topic in the background (a new map may mean a new precomputation)."""
        adapter = self.adapter
        assert adapter is not None

        def received() -> None:
            self._map_received = True

        self._work.start(f"setting up the {grid_map.width} x {grid_map.height} map", lambda: adapter.set_map(grid_map),
                         then=received)

    def _after_work(self) -> None:
        """On the executor: report a job that ended, apply the requests that came meanwhile, then set up a map that
        came meanwhile."""
        self._work.poll()
        while not self._work.busy and self._deferred:
            self._deferred.pop(0)()
        if not self._work.busy and self._pending_map is not None and self.adapter is not None:
            grid_map, self._pending_map = self._pending_map, None
            if not self.adapter.is_current_map(grid_map):
                self._start_map_setup(grid_map)

    def _busy(self, what: str) -> bool:
        """Whether background work runs (inputs are dropped meanwhile, with a throttled note)."""
        self._after_work()
        if not self._work.busy:
            return False
        percent = self._work.percent()
        done = "" if percent is None else f", {percent:.0f} %"
        self.throttled("info", "busy", f"{self._work.what} ({self._work.elapsed_s():.0f} s{done}): {what} dropped")
        return True

    def _on_scan(self, msg: LaserScan) -> None:
        if not self._accepting("sensor", "scan"):
            return
        assert self.adapter is not None
        frame = tf.frame_name(msg.header.frame_id)
        if not self.adapter.mount_known:
            mount = self._laser_mount(frame)
            if mount is None:
                return
            self.adapter.set_mount(mount)
            self._mount_frame = frame
        elif self._mount_frame and frame != self._mount_frame:
            self.throttled("warn", "scan_frame", f"a scan from frame {frame!r}, but the laser mount in use is that "
                           f"of {self._mount_frame!r} (looked up at the first scan after configure): used with "
                           "it. One laser a topic; cleanup and configure to take another laser's mount")
        if self._busy("scans"):
            return
        if self.adapter.preparation_due(msg):
            adapter = self.adapter
            self._work.start(f"precomputing {self.plugin.name} for this scanner", lambda: adapter.prepare(msg))
            return
        self._when_odometry_reaches(msg, self.adapter.on_scan_msg)

    def _on_image(self, msg: Image) -> None:
        if not self._accepting("sensor", "image") or self._busy("images"):
            return
        assert self.adapter is not None
        self._when_odometry_reaches(msg, self.adapter.on_image_msg)

    def _on_camera_cue(self, msg: Image) -> None:
        """An image for a laser method's camera cue (the hybrid's): used at once, it weighs what the scans estimate."""
        if not self._accepting("camera", "image") or self._busy("images"):
            return
        assert self.adapter is not None
        self.adapter.on_image_msg(msg)

    def _when_odometry_reaches(self, msg: Any, update: Callable[[Any], AdapterOutput | None]) -> None:
        """Update with ``msg`` once odometry reaches its stamp, as nav2_amcl's tf message filter waits for it.

        Scans are best effort and odometry reliable: a scan often arrives before the odometry of its
        own instant, and under load the odometry can trail by several scans. Inputs wait in stamp order
        for that odometry, so that neither the update nor ``map -> odom`` uses odometry of an earlier
        instant; each odometry message then runs the newest input it reaches and drops the older ones.
        The inputs within ``transform_tolerance`` (stamp time) of the newest all wait, as nav2_amcl's filter
        holds its scans; older ones are thinned to one a ``transform_tolerance``, so that odometry whose lag
        keeps growing (an executor that cannot keep up serves one odometry message a spin) still reaches an
        input within that of its stamp: late updates rather than none (with 0, only the newest waits). At most
        ``MAX_WAITING_INPUTS`` wait.
        Without any odometry an input goes at once.
        """
        assert self.adapter is not None
        stamp = stamp_to_seconds(msg.header.stamp)
        odometry_stamp = self.adapter.last_odometry_stamp
        if odometry_stamp >= stamp or odometry_stamp == -math.inf:
            self.publish(update(msg), stamp)
            return
        # An input stamped before waiting ones starts a new timeline (a bag looped): those are dropped.
        waiting = [entry for entry in self._waiting if entry[0] < stamp] + [(stamp, msg, update)]
        tolerance = self.node_settings.transform_tolerance
        recent = [entry for entry in waiting if stamp - entry[0] <= tolerance]
        thinned: list[tuple[float, Any, Callable[[Any], AdapterOutput | None]]] = []
        for entry in waiting[: len(waiting) - len(recent)] if tolerance > 0.0 else ():  # oldest first: kept stay kept
            if not thinned or entry[0] - thinned[-1][0] >= tolerance:
                thinned.append(entry)
        self._waiting = (thinned + recent)[-MAX_WAITING_INPUTS:]
        if len(self._waiting) < len(waiting):
            self.throttled("warn", "odometry_behind", f"odometry ({odometry_stamp:.3f} s) trails the sensor's "
                           f"newest stamp by {stamp - odometry_stamp:.2f} s: inputs older than "
                           f"transform_tolerance ({tolerance:g} s) keep one a {tolerance:g} s for it, the others "
                           "are dropped (is odometry late or stopped?)")

    def _odometry_arrived(self) -> None:
        """Run the newest input this odometry reaches; drop the older ones (as a newer scan replaces them)."""
        if not self._waiting or self.adapter is None:
            return
        reached = self.adapter.last_odometry_stamp
        due = [entry for entry in self._waiting if entry[0] <= reached]  # the list is in stamp order
        if due:
            self._waiting = self._waiting[len(due):]
            stamp, msg, update = due[-1]
            self.publish(update(msg), stamp)

    def _on_odom(self, msg: Odometry) -> None:
        # Kept by the adapter during background work too: a pose given meanwhile is moved on by it afterwards.
        if self._accepting("odometry", "odometry"):
            assert self.adapter is not None
            self.adapter.on_odom_msg(msg)
            if not self._busy("inputs waiting for odometry"):
                self._odometry_arrived()

    def _on_tf(self, msg: Any) -> None:
        """Odometry from /tf (odom_source tf): ``odom -> base`` at the stamp of each transform on the way."""
        ns = self.node_settings
        odometry = self.tf_buffer.add_odometry(msg, ns.odom_frame_id, ns.base_frame_id)
        if not odometry or not self._accepting("odometry", "odometry"):
            return
        assert self.adapter is not None
        for stamp, pose in odometry:
            self.adapter.on_odometry(stamp, pose)
        if not self._busy("inputs waiting for odometry"):
            self._odometry_arrived()

    def _on_tf_static(self, msg: Any) -> None:
        self.tf_buffer.add_message(msg, static=True)
        if self.adapter is None or not self._mount_frame:
            return
        # The mount is taken once, at the first scan: a later /tf_static that moves the laser is said, not used.
        found = self.tf_buffer.lookup_mount(self.node_settings.base_frame_id, self._mount_frame, static_only=True)
        if found is not None:
            pose, upside_down = found
            used = self.adapter.mount
            if upside_down != used.upside_down or np.abs(pose - used.pose).max() > 1e-3:
                self.throttled("warn", "mount_moved", f"/tf_static now puts {self._mount_frame} at ({pose[0]:g} m, "
                               f"{pose[1]:g} m, {pose[2]:g} rad){', upside down' if upside_down else ''}; the mount "
                               f"in use, taken at the first scan, is ({used.x:g} m, {used.y:g} m, {used.yaw:g} rad): "
                               "cleanup and configure to take the new one")

    def _laser_mount(self, laser_frame: str) -> LaserMount | None:
        """``base -> laser`` from /tf_static, else the laser_x/y/yaw parameters.

        None while waiting for it: /tf_static is transient local, yet DDS may deliver it seconds after
        the first (best-effort) scans; with a publisher on /tf_static, scans wait up to ``_MOUNT_WAIT_S``.
        """
        base = self.node_settings.base_frame_id
        found = self.tf_buffer.lookup_mount(base, laser_frame, static_only=True) if laser_frame else None
        refused = False
        if found is not None:
            pose, upside_down = found
            try:
                from_tf = LaserMount(float(pose[0]), float(pose[1]), float(pose[2]), upside_down)
            except ValueError as exc:
                refused = True
                self.get_logger().warning(f"ignoring {base} -> {laser_frame} on /tf_static: {exc}")
            else:
                self.get_logger().info(f"laser mount from /tf_static {base} -> {laser_frame}: "
                                       f"({pose[0]:g} m, {pose[1]:g} m, {pose[2]:g} rad)"
                                       f"{', upside down' if upside_down else ''}")
                return from_tf
        now = time.monotonic()
        self._mount_wait_since = self._mount_wait_since or now
        if not refused and now - self._mount_wait_since < _MOUNT_WAIT_S and self.count_publishers("/tf_static"):
            self.throttled("info", "mount_wait", f"waiting up to {_MOUNT_WAIT_S:g} s for {base} -> "
                           f"{laser_frame or '(no frame)'} on /tf_static before using laser_x/y/yaw")
            return None
        mount = self.node_settings.mount
        # A laser frame /tf knows but not below the base (its parent, or a sibling) is a tree tf2 would resolve
        # and this lookup does not: said as a warning, since the parameters' mount may well be wrong then.
        astray = not refused and bool(laser_frame) and self.tf_buffer.knows(laser_frame)
        text = (f"laser mount from laser_x/y/yaw ({mount.x:g} m, {mount.y:g} m, {mount.yaw:g} rad)"
                f"{', upside down' if mount.upside_down else ''}: " + (
                    f"/tf_static's {base} -> {laser_frame} is refused" if refused else
                    f"{laser_frame} is on /tf but not below {base} (the laser must be a descendant of the base)"
                    if astray else f"/tf_static has no {base} -> {laser_frame or '(no frame)'}"))
        if astray:
            self.get_logger().warning(text)
        else:
            self.get_logger().info(text)
        return mount

    def _accepting(self, kind: str, what: str) -> bool:
        """Inputs are used only while active (nav2_amcl drops them before); notes the time for the watchdog."""
        if self.adapter is None:
            return False
        if not self.active:
            self.throttled("info", f"inactive_{kind}", f"received {what} while inactive: ignored until activation")
            return False
        self._last_input[kind] = time.monotonic()
        return True

    def _on_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        if self.adapter is None:
            return
        if not self.active:
            # nav2_amcl keeps it for the activation.
            frame = tf.frame_name(msg.header.frame_id)
            if frame != self.node_settings.global_frame_id:
                self.adapter.on_initial_pose_msg(msg)  # refused, with the message naming both frames
                return
            self._pending_initial_pose = msg
            self.get_logger().info("initial pose received while inactive: checked and applied on activation")
            return
        if self._when_idle("initial pose", lambda: self._apply_initial_pose(msg)):
            return
        self._apply_initial_pose(msg)

    def _apply_initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        if self.adapter is not None and self.adapter.on_initial_pose_msg(msg):
            self._fresh_method = False

    def _when_idle(self, what: str, request: Callable[[], None]) -> bool:
        """Defer ``request`` to the end of the background work, if any runs (True then)."""
        self._after_work()
        if not self._work.busy:
            return False
        self._deferred.append(request)
        self.get_logger().info(f"{what} received during '{self._work.what}': applied when it ends")
        return True

    def _set_initial_pose(self, pose: np.ndarray, covariance: np.ndarray | None, source: str) -> None:
        assert self.adapter is not None
        self.get_logger().info(f"starting from {source}")
        self.adapter.set_initial_pose(pose, covariance)
        self._fresh_method = False

    def _on_set_initial_pose(self, request: Any, response: Any) -> Any:
        guarded(self, self._on_initial_pose, "set_initial_pose")(request.pose)
        return response

    def _on_reinitialize(self, request: Empty.Request, response: Empty.Response) -> Empty.Response:
        adapter = self.adapter
        if adapter is not None:
            reinitialize = guarded(self, lambda _: adapter.reinitialize(), "reinitialize")
            if not self._when_idle("global localization request", lambda: reinitialize(None)):
                reinitialize(None)
        return response

    def _on_nomotion(self, request: Empty.Request, response: Empty.Response) -> Empty.Response:
        if self.adapter is not None:
            self.adapter.request_nomotion_update()
        return response

    def _watch_inputs(self) -> None:
        """INITIALIZING with the progress while background work runs; a warning (every scan_timeout) for
        each input that has been silent for scan_timeout since activation."""
        self._after_work()
        if self._work.busy and self.active:
            self.diagnostics_pub.publish(progress_diagnostics(self.get_clock().now().nanoseconds * 1e-9,
                                                              self.get_name(), self._work.what, self._work.percent()))
        now, timeout = time.monotonic(), self.node_settings.scan_timeout
        ns = self.node_settings
        checks = [("sensor", self.sensor_sub.topic_name, "image" if self.plugin.uses_camera else "scan")]
        if self.odom_sub is not None:
            checks.append(("odometry", self.odom_sub.topic_name, "odometry" if ns.odom_source == "topic"
                           else f"{ns.odom_frame_id} -> {ns.base_frame_id} transform"))
        for kind, topic, what in checks:
            silent = now - self._last_input[kind]
            if silent >= timeout and now - self._warned[kind] >= timeout:
                self._warned[kind] = now
                since = "since activation" if self._last_input[kind] == self._activated_at else "since the last one"
                others = [info for info in self.get_publishers_info_by_topic(topic)
                          if (info.node_name, info.node_namespace) != (self.get_name(), self.get_namespace())]
                self.get_logger().warning(
                    f"no {what} received on {topic} for {silent:.1f} s {since} "
                    f"({len(others)} publisher(s)): nothing is localized without it")
        adapter = self.adapter
        if (adapter is not None and not self.plugin.uses_camera and not adapter.has_map
                and now - self._activated_at >= timeout and now - self._warned["map"] >= timeout):
            self._warned["map"] = now
            self.get_logger().warning(f"no map yet: waiting for {self.resolve_topic_name('map')} (or set map_yaml)")

    # -- outputs ------------------------------------------------------------------------------
    def publish(self, output: AdapterOutput | None, input_stamp: float | None = None) -> None:
        """Publish an update's messages and ``map -> odom``; without an update, ``map -> odom`` again (nav2)."""
        if not self.active:
            return
        ns = self.node_settings
        if output is None:
            if input_stamp is not None and self._last_tf is not None:
                self._send_tf(self._last_tf[1], max(input_stamp, self._last_tf[0]))
            return
        estimate = output.estimate
        if output.has_pose:  # LOST, INITIALIZING or not finite: no pose, no new map -> odom (diagnostics and candidates only)
            self.pose_pub.publish(output.pose)
            self.last_pose = (estimate.pose.copy(), estimate.covariance.copy())
        # Thousands of poses cost far more to build in Python than the update itself (mcl_baseline: ~25 of
        # ~27 ms per scan at 2,000 particles, docs/footprint.md): built only for a subscriber.
        if self.candidates_pub.get_subscription_count():
            self.candidates_pub.publish(output.candidates)
        self.diagnostics_pub.publish(output.diagnostics)
        if self.cloud_pub is not None and self.cloud_pub.get_subscription_count():
            self.cloud_pub.publish(nav2.estimate_to_particle_cloud(estimate, ns.global_frame_id,
                                                                   ns.max_published_candidates))
        for key, msg in output.extras.items():
            if key in self.extra_pubs:
                self.extra_pubs[key].publish(msg)
        self._fresh_method = False
        if not output.has_pose:
            self.publish(None, input_stamp)  # map -> odom as on a scan without an update
        elif output.map_to_odom is None:
            self.throttled("warn", "tf_no_odometry", "no odometry yet: map -> odom not published")
        elif output.odometry_lag > ns.transform_tolerance:
            self.throttled("warn", "tf_odometry_lag", f"odometry lags the scan by {output.odometry_lag:.2f} s "
                           f"(more than transform_tolerance {ns.transform_tolerance:g} s): map -> odom not updated")
        else:
            self._last_tf = (estimate.stamp, output.map_to_odom)
            self._send_tf(output.map_to_odom, estimate.stamp)

    def _send_tf(self, map_to_odom: np.ndarray, stamp: float) -> None:
        """``map -> odom`` valid until ``stamp + transform_tolerance``, as nav2_amcl future-dates it."""
        ns = self.node_settings
        if self.tf_pub is None or not ns.tf_broadcast:
            return
        transform = tf.transform_to_msg(stamp + ns.transform_tolerance, ns.global_frame_id, ns.odom_frame_id,
                                        map_to_odom)
        self.tf_pub.publish(tf.tf_message([transform]))


def run_localizer(
    plugin: LocalizerPlugin, argv: Sequence[str] | None = None, *, extras: Mapping[str, Extra] | None = None
) -> int:
    """``main()`` of a localizer node module: ``--help`` from the plugin's settings, then the node."""
    parser = help_parser(plugin.name, plugin.description, (NodeSettings, plugin.settings), topics_text(plugin))
    return run_node(parser, lambda _options: LocalizerNode(plugin, extras=extras), argv)
