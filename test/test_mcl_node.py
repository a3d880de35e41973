"""The mcl_baseline plugin and the shared node running it, fed messages in-process."""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from mcl_test_world import drive, office_map

from robot_localization_suite import registry
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.localizer import LocalizerStatus
from robot_localization_suite.core.mcl.localizer import MclSettings, MonteCarloLocalizer
from robot_localization_suite.core.scan import LaserMount
from robot_localization_suite.core.se2 import compose, inverse
from robot_localization_suite.core.settings import parameters
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter


def test_the_plugin_builds_the_filter_from_the_packaged_params_file() -> None:
    plugin = registry.plugin("mcl_baseline")
    localizer = plugin.create(plugin.load_settings()[1])
    assert isinstance(localizer, MonteCarloLocalizer)
    assert localizer.settings == MclSettings()  # the packaged file repeats the defaults


def test_the_node_handles_a_message_feed_and_its_services() -> None:
    rclpy = pytest.importorskip("rclpy")
    from rclpy.qos import (
        HistoryPolicy,
        QoSCompatibility,
        QoSProfile,
        ReliabilityPolicy,
        qos_check_compatible,
        qos_profile_sensor_data,
    )
    from std_srvs.srv import Empty

    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    office = office_map()
    run = drive(office, steps=80, seed=2)
    rclpy.init(args=["mcl_baseline", "--ros-args", "-p", "max_particles:=3000", "-p", "min_particles:=200"])
    node = LocalizerNode(registry.plugin("mcl_baseline"))
    node.trigger_configure()
    node.trigger_activate()
    published = []
    try:
        for param in parameters(MclSettings):
            assert node.has_parameter(param.name), param.name
        assert node.describe_parameter("sigma_hit").floating_point_range[0].to_value == 100.0
        # scans: the newest one only (a slow update drops old scans rather than queueing them), and best
        # effort, so that nav2-style sensor-data publishers and reliable ones (a bag player) both match
        scan_qos = node.sensor_sub.qos_profile
        assert scan_qos.depth == 1 and scan_qos.history is HistoryPolicy.KEEP_LAST
        for publisher_qos in (qos_profile_sensor_data, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)):
            assert qos_check_compatible(publisher_qos, scan_qos)[0] is not QoSCompatibility.ERROR, publisher_qos
        localizer = node.localizer
        assert localizer.settings.max_particles == 3000
        node.publish = lambda output, *_: published.append(output) if output is not None else None  # type: ignore[method-assign]
        node.adapter.on_map_msg(conversions.grid_map_to_msg(office, 0.0))
        node.adapter.on_initial_pose_msg(
            conversions.initial_pose_to_msg(0.0, run.truth[0], np.diag([0.05**2, 0.05**2, 0.05**2]))
        )
        for k in range(len(run.stamps)):
            node.adapter.on_odom_msg(conversions.odometry_to_msg(run.stamps[k], run.odometry[k], frame_id="odom"))
            scan = run.scans[k]
            node._on_scan(
                conversions.scan_to_msg(
                    scan.stamp, "laser", angle_min=scan.angles[0], angle_increment=scan.angles[1] - scan.angles[0],
                    ranges=scan.ranges, range_min=scan.range_min, range_max=scan.range_max,
                )
            )
        # bad input on the same path: a scan of NaNs, odometry stepping back in time
        node._on_scan(conversions.scan_to_msg(100.0, "laser", angle_min=-1.0, angle_increment=0.01,
                                              ranges=np.full(200, np.nan), range_min=0.1, range_max=10.0))
        node.adapter.on_odom_msg(conversions.odometry_to_msg(0.0, np.zeros(3), frame_id="odom"))
        assert len(published) > 5
        last = published[-1]
        assert last.estimate.status is LocalizerStatus.LOCALIZED
        assert np.hypot(*(last.estimate.pose[:2] - run.truth[len(run.stamps) - 1][:2])) < 0.2
        assert last.pose.header.frame_id == "map"
        values = {kv.key: kv.value for kv in last.diagnostics.status[0].values}
        assert int(values["particles"]) >= 200

        # the services, through their callbacks
        node._on_reinitialize(Empty.Request(), Empty.Response())
        assert localizer.particle_count == 3000 and np.all(office.is_free(localizer.particles[:, :2]))
        assert np.ptp(localizer.particles[:, 0]) > 10.0
        node._on_nomotion(Empty.Request(), Empty.Response())
        assert localizer.odometry.forced
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    assert math.isfinite(published[-1].update_ms)


@contextlib.contextmanager
def _mcl_node(*parameters: str) -> Iterator[Any]:
    """An unconfigured ``mcl_baseline`` node with 500-200 particles and these ``-p`` parameters, destroyed after."""
    rclpy = pytest.importorskip("rclpy")
    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    args = ["max_particles:=500", "min_particles:=200", *parameters]
    rclpy.init(args=["mcl_baseline", "--ros-args", *[part for value in args for part in ("-p", value)]])
    node = LocalizerNode(registry.plugin("mcl_baseline"))
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def test_an_initial_pose_received_while_inactive_is_checked_at_activation_as_an_active_nodes() -> None:
    # A NaN pose kept for the activation used to fail it (lifecycle ERROR) at every later activation too.
    office = office_map()
    run = drive(office, steps=2, seed=2)
    logged: list[tuple[str, str]] = []
    with _mcl_node() as node:
        node.trigger_configure()
        node.adapter.log._sink = lambda level, text: logged.append((level, text))
        node.adapter.on_map_msg(conversions.grid_map_to_msg(office, 0.0))
        bad = conversions.initial_pose_to_msg(0.0, run.truth[0], np.diag([0.01, 0.01, 0.01]))
        bad.pose.pose.position.x = math.nan
        node._on_initial_pose(bad)
        node.trigger_activate()
        assert node.active
        assert any("non-finite" in text for _, text in logged), logged
        good = conversions.initial_pose_to_msg(0.0, run.truth[0], np.diag([0.01, 0.01, 0.01]))
        node.trigger_deactivate()
        node._on_initial_pose(good)
        node.trigger_activate()
        assert node.active
        assert np.hypot(*(node.localizer.particles[:, :2].mean(axis=0) - run.truth[0][:2])) < 0.3


def test_a_method_rebuilt_before_the_first_scan_or_during_a_map_setup_keeps_the_mount_and_the_map() -> None:
    # a change of sigma_hit before the first scan left the rebuilt method at mount (0, 0, 0); one during the
    # map's setup left the map to the discarded method (every scan "before any map" after it)
    import threading

    from rclpy.parameter import Parameter

    office = office_map()
    run = drive(office, steps=3, seed=2)
    with _mcl_node("laser_x:=0.3", "laser_yaw:=0.4") as node:
        node.trigger_configure()
        node.trigger_activate()
        release = threading.Event()
        set_map = node.adapter.set_map

        def slow_set_map(grid_map: GridMap) -> None:
            release.wait(60)
            set_map(grid_map)

        node.adapter.set_map = slow_set_map  # type: ignore[method-assign]
        node._on_map(conversions.grid_map_to_msg(office, 0.0))
        assert node._work.busy
        assert node.set_parameters([Parameter("sigma_hit", value=0.25)])[0].successful
        release.set()
        assert node._work.wait(60)
        node._after_work()  # the change, deferred to the end of the setup, is applied now
        assert node.localizer.settings.sigma_hit == 0.25 and node.adapter.has_map
        node._on_odom(conversions.odometry_to_msg(run.stamps[0], run.odometry[0], frame_id="odom"))
        node._on_scan(_scan_msg(run.scans[0]))
        assert node.adapter.mount_known and node.adapter.mount.pose.tolist() == pytest.approx([0.3, 0.0, 0.4])
        # frames tf2 would refuse are refused here, the old ones kept
        for name, value in (("global_frame_id", ""), ("odom_frame_id", "map"), ("base_frame_id", " base"),
                            ("odom_frame_id", "/odom")):
            assert not node.set_parameters([Parameter(name, value=value)])[0].successful, name
        assert (node.node_settings.global_frame_id, node.node_settings.odom_frame_id) == ("map", "odom")


def test_a_transition_the_state_has_not_is_refused_not_the_end_of_the_process() -> None:
    # nav2's lifecycle manager asks by id; configure twice made rclpy raise out of the service (exit code 1)
    pytest.importorskip("rclpy")
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    with _mcl_node() as node:
        answer = node._service_change_state.callback

        def ask(transition: int) -> bool:
            request = ChangeState.Request()
            request.transition.id = transition
            return bool(answer(request, ChangeState.Response()).success)

        assert not ask(Transition.TRANSITION_ACTIVATE)  # while unconfigured
        assert ask(Transition.TRANSITION_CONFIGURE)
        assert not ask(Transition.TRANSITION_CONFIGURE)  # again
        assert ask(Transition.TRANSITION_ACTIVATE) and node.active


def test_the_map_in_use_sent_again_while_another_is_set_up_is_the_one_kept() -> None:
    # map_server publishes the right map again (or a user corrects a wrong one) while a wrong one is being set
    # up: the newest map wins, though it equals the one in use when it arrives
    office = office_map()
    coarse = GridMap(office.data[::4, ::4].copy(), office.resolution * 4, office.origin)
    with _mcl_node() as node:

        def settle() -> None:
            deadline = time.monotonic() + 60.0
            while (node._work.busy or node._pending_map is not None) and time.monotonic() < deadline:
                time.sleep(0.02)
                node._after_work()

        node.trigger_configure()
        node.trigger_activate()
        node._on_map(conversions.grid_map_to_msg(office, 0.0))
        settle()
        node._on_map(conversions.grid_map_to_msg(coarse, 0.0))
        assert node._work.busy
        node._on_map(conversions.grid_map_to_msg(office, 0.0))
        settle()
        assert node.adapter.current_map.resolution == pytest.approx(office.resolution)


def test_scans_from_another_laser_frame_are_named_in_a_warning() -> None:
    # the mount is looked up once; a second laser on the same topic used to be read with the first one's, silently
    office = office_map()
    run = drive(office, steps=6, seed=2)
    logged: list[tuple[str, str]] = []
    with _mcl_node() as node:
        node.trigger_configure()
        node.trigger_activate()
        node.throttled._sink = lambda level, text: logged.append((level, text))
        node.adapter.on_map_msg(conversions.grid_map_to_msg(office, 0.0))
        for k in range(len(run.stamps)):
            node._on_odom(conversions.odometry_to_msg(run.stamps[k], run.odometry[k], frame_id="odom"))
            msg = _scan_msg(run.scans[k])
            msg.header.frame_id = "laser" if k < 3 else "laser_rear"
            node._on_scan(msg)
        warned = [text for level, text in logged if level == "warn" and "laser_rear" in text]
        assert warned and "'laser'" in warned[0], logged
        # a /tf_static that comes after the mount was taken (from the parameters here) is said, not used
        from robot_localization_suite.ros.tf import TFMessage, transform_to_msg

        if TFMessage is not None:  # tf2_msgs is built by make
            node._on_tf_static(TFMessage(transforms=[transform_to_msg(0.0, "base_footprint", "laser",
                                                                      np.array([0.3, 0.0, 0.0]))]))
            assert any("/tf_static now puts laser at (0.3 m" in text for _, text in logged), logged
            assert node.adapter.mount.x == 0.0


def test_a_new_map_reseeds_around_the_laser_pose_with_a_mount_offset() -> None:
    """The adapter turns the core's laser estimate into a base estimate without touching the core's own.

    MCL keeps its last estimate and reseeds around it on a new map; were the adapter to rewrite that
    estimate in place (as it once did), the new cloud would sit on the base pose, 0.32 m from the laser.
    """
    office = office_map()
    mount = LaserMount(0.3, 0.1, 0.2)
    run = drive(office, steps=60, seed=4)  # run.truth: the laser's poses, scans cast from them
    base = compose(run.truth, inverse(mount.pose))
    localizer = MonteCarloLocalizer(MclSettings(min_particles=500, max_particles=3000, random_seed=1))
    adapter = LocalizerAdapter(localizer, node_name="mcl_baseline", log=lambda *_: None, mount=mount)
    adapter.set_map(office)
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, base[0], np.diag([0.05**2, 0.05**2, 0.05**2])))
    output = None
    for k, scan in enumerate(run.scans):
        adapter.on_odom_msg(conversions.odometry_to_msg(run.stamps[k], compose(run.odometry[k], inverse(mount.pose)),
                                                       frame_id="odom"))
        output = adapter.on_scan_msg(conversions.scan_to_msg(
            scan.stamp, "laser", angle_min=scan.angles[0], angle_increment=scan.angles[1] - scan.angles[0],
            ranges=scan.ranges, range_min=scan.range_min, range_max=scan.range_max,
        )) or output
    assert output is not None and output.estimate.status is LocalizerStatus.LOCALIZED
    k = int(np.argmin(np.abs(run.stamps - output.estimate.stamp)))  # the last update's scan
    assert np.hypot(*(output.estimate.pose[:2] - base[k, :2])) < 0.1  # the published pose is the base's
    assert localizer.last_estimate is not None
    assert np.hypot(*(localizer.last_estimate.pose[:2] - run.truth[k, :2])) < 0.1  # the core's is the laser's

    changed = GridMap(office.data.copy(), office.resolution, office.origin)
    changed.data[5:10, 5:10] = 100  # a new box far from the robot: a different map
    adapter.set_map(changed)
    centre = localizer.particles[:, :2].mean(axis=0)
    assert np.hypot(*(centre - run.truth[k, :2])) < 0.1
    assert np.hypot(*(centre - base[k, :2])) > 0.2


def _scan_msg(scan, stamp=None):  # noqa: ANN001, ANN202
    return conversions.scan_to_msg(
        scan.stamp if stamp is None else stamp, "laser", angle_min=scan.angles[0],
        angle_increment=scan.angles[1] - scan.angles[0], ranges=scan.ranges, range_min=scan.range_min,
        range_max=scan.range_max,
    )


def test_one_message_stamped_in_2038_does_not_stop_the_node_and_time_going_back_restarts_it() -> None:
    """The issue's attack: a LaserScan and an Odometry stamped 2^31 - 1, before and in the middle of a run."""
    office = office_map()
    run = drive(office, steps=80, seed=3)
    localizer = MonteCarloLocalizer(MclSettings(min_particles=500, max_particles=3000, random_seed=2))
    logs: list[tuple[str, str]] = []
    now = [0.0]  # the node's clock: the time of the scan being sent
    adapter = LocalizerAdapter(localizer, node_name="mcl_baseline", log=lambda *a: logs.append(a), clock=lambda: now[0])
    adapter.set_map(office)
    far = float(2**31 - 1)
    # first messages ever: the attack
    adapter.on_odom_msg(conversions.odometry_to_msg(far, np.zeros(3), frame_id="odom"))
    adapter.on_scan_msg(_scan_msg(run.scans[0], far))
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, run.truth[0], np.diag([0.05**2] * 3)))
    outputs = []
    for k in range(len(run.stamps)):
        now[0] = run.stamps[k]
        adapter.on_odom_msg(conversions.odometry_to_msg(run.stamps[k], run.odometry[k], frame_id="odom"))
        if k == 40:  # and again in the middle: refused, and it does not move the node's time
            adapter.on_odom_msg(conversions.odometry_to_msg(far, run.odometry[k], frame_id="odom"))
            assert adapter.on_scan_msg(_scan_msg(run.scans[k], far)) is None
        output = adapter.on_scan_msg(_scan_msg(run.scans[k]))
        if output is not None:
            outputs.append(output)
    assert len(outputs) > 10
    assert outputs[-1].estimate.status is LocalizerStatus.LOCALIZED
    k = int(np.argmin(np.abs(run.stamps - outputs[-1].estimate.stamp)))
    assert np.hypot(*(outputs[-1].estimate.pose[:2] - run.truth[k, :2])) < 0.15
    texts = " ".join(text for _, text in logs)
    assert "ahead of the node's clock" in texts
    # a bag that loops: the same run again from t = 0 starts a new timeline and the node keeps localizing
    again = []
    for k in range(len(run.stamps)):
        now[0] = run.stamps[k]
        adapter.on_odom_msg(conversions.odometry_to_msg(run.stamps[k], run.odometry[k], frame_id="odom"))
        output = adapter.on_scan_msg(_scan_msg(run.scans[k]))
        if output is not None:
            again.append(output)
    assert len(again) > 10 and localizer.odometry.time_jumps >= 1
    assert "time jumped back" in " ".join(text for _, text in logs)


def test_the_cores_python_log_reaches_the_nodes_ros_log() -> None:
    """A corrupt cache is reported through Python logging in core/: the node forwards it to its ROS log."""
    import logging

    rclpy = pytest.importorskip("rclpy")
    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    rclpy.init(args=["mcl_baseline"])
    node = LocalizerNode(registry.plugin("mcl_baseline"))
    node.trigger_configure()
    node.trigger_activate()
    seen: list[tuple[str, str]] = []
    try:
        node._log_handler._sink = lambda level, text: seen.append((level, text))
        logging.getLogger("robot_localization_suite.core.ir.index").warning("IR cache %s is unreadable; rebuilding it", "x.npz")
        logging.getLogger("robot_localization_suite.core.pil.learning").info("relearning for 180 deg")
        logging.getLogger("robot_localization_suite.core").debug("not forwarded")
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    assert seen == [("warn", "IR cache x.npz is unreadable; rebuilding it"), ("info", "relearning for 180 deg")]
    logging.getLogger("robot_localization_suite.core").warning("after the node is gone")
    assert len(seen) == 2


def test_slow_work_runs_off_the_executor_with_progress_in_the_diagnostics() -> None:
    """A map from the topic is set up in a worker thread: meanwhile the node drops scans, answers its
    services and publishes INITIALIZING with the percent done of the work's progress bars; an initial pose
    received meanwhile is applied when the map is ready, moved on by the odometry received meanwhile."""
    import threading
    from types import SimpleNamespace

    rclpy = pytest.importorskip("rclpy")
    from std_srvs.srv import Empty

    from robot_localization_suite.core.progress import ReportingBar
    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    office = office_map()
    run = drive(office, steps=5, seed=1)
    rclpy.init(args=["mcl_baseline", "--ros-args", "-p", "max_particles:=2000"])
    node = LocalizerNode(registry.plugin("mcl_baseline"))
    node.trigger_configure()
    node.trigger_activate()
    diagnostics: list = []
    published: list = []
    node.diagnostics_pub = SimpleNamespace(publish=diagnostics.append)  # type: ignore[assignment]
    node.publish = lambda output, *_: published.append(output) if output is not None else None  # type: ignore[method-assign]
    release, halfway = threading.Event(), threading.Event()
    adapter = node.adapter
    set_map = adapter.set_map

    def slow_set_map(grid_map: GridMap) -> None:  # the map setup of a large map, two steps of four done
        bar = ReportingBar(total=4, disable=True)
        bar.update(2)
        halfway.set()
        release.wait(60)
        bar.close()
        set_map(grid_map)

    adapter.set_map = slow_set_map  # type: ignore[method-assign]
    try:
        node._on_map(conversions.grid_map_to_msg(office, 0.0))
        assert node._work.busy and not adapter.has_map  # the callback returned before the setup ended
        assert halfway.wait(60)
        node._watch_inputs()
        status = diagnostics[-1].status[0]
        values = {kv.key: kv.value for kv in status.values}
        assert status.message == LocalizerStatus.INITIALIZING.value and values["progress_percent"] == "50.0"
        scan = run.scans[0]
        node._on_scan(conversions.scan_to_msg(scan.stamp, "laser", angle_min=scan.angles[0],
                                              angle_increment=scan.angles[1] - scan.angles[0], ranges=scan.ranges,
                                              range_min=scan.range_min, range_max=scan.range_max))
        assert not published  # dropped while busy
        node._on_nomotion(Empty.Request(), Empty.Response())  # services still answer
        # An initial pose meanwhile waits for the map; the odometry meanwhile is kept and moves it on to now.
        given = np.array([2.0, 5.0, 0.0])
        node._on_odom(conversions.odometry_to_msg(10.0, np.array([0.0, 0.0, 0.0]), frame_id="odom"))
        node._on_odom(conversions.odometry_to_msg(10.5, np.array([0.5, 0.0, 0.0]), frame_id="odom"))
        node._on_initial_pose(conversions.initial_pose_to_msg(10.0, given, np.diag([1e-4, 1e-4, 1e-4])))
        assert node._deferred
        release.set()
        assert node._work.wait(60)
        node._watch_inputs()
        assert not node._work.busy and adapter.has_map and node._map_received
        assert not node._deferred
        particles = adapter.localizer.particles
        assert np.allclose(particles[:, :2].mean(axis=0), [2.5, 5.0], atol=0.05)
    finally:
        release.set()
        node.destroy_node()
        rclpy.try_shutdown()


def test_the_candidates_and_the_cloud_are_built_only_for_a_subscriber(monkeypatch: pytest.MonkeyPatch) -> None:
    """Building thousands of poses in Python costs more than the update: not done for nobody."""
    rclpy = pytest.importorskip("rclpy")
    from geometry_msgs.msg import PoseArray

    from robot_localization_suite.nodes import localizer_node
    from robot_localization_suite.ros.qos import RELIABLE_QOS, SENSOR_QOS

    office = office_map()
    run = drive(office, steps=60, seed=3)
    built: list[int] = []
    real = localizer_node.nav2.estimate_to_particle_cloud
    monkeypatch.setattr(localizer_node.nav2, "estimate_to_particle_cloud",
                        lambda *args: built.append(1) or real(*args))
    rclpy.init(args=["mcl_baseline", "--ros-args", "-p", "max_particles:=1000", "-p", "min_particles:=1000"])
    node = localizer_node.LocalizerNode(registry.plugin("mcl_baseline"))
    listener = rclpy.create_node("candidates_listener")
    try:
        node.trigger_configure()
        node.trigger_activate()
        node.adapter.on_map_msg(conversions.grid_map_to_msg(office, 0.0))
        node.adapter.on_initial_pose_msg(
            conversions.initial_pose_to_msg(0.0, run.truth[0], np.diag([0.05**2, 0.05**2, 0.05**2])))

        def feed(steps: range) -> None:
            for k in steps:
                node.adapter.on_odom_msg(conversions.odometry_to_msg(run.stamps[k], run.odometry[k], frame_id="odom"))
                node._on_scan(_scan_msg(run.scans[k]))

        feed(range(0, 30))
        assert node.last_pose is not None and built == []
        assert node.candidates_pub.get_subscription_count() == 0
        listener.create_subscription(PoseArray, "/mcl_baseline/candidates", lambda _msg: None, RELIABLE_QOS)
        listener.create_subscription(localizer_node.nav2.ParticleCloud, "/mcl_baseline/particle_cloud",
                                     lambda _msg: None, SENSOR_QOS)
        deadline = time.monotonic() + 10.0
        while node.cloud_pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        feed(range(30, 60))
        assert built, "a subscriber gets the particle cloud"
    finally:
        listener.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown()


@contextlib.contextmanager
def _tracking_node(office: GridMap, start: np.ndarray, handled: list[Any]) -> Iterator[Any]:
    """An active mcl_baseline node on ``office``, started at ``start``, that appends ``(stamp, output)`` to
    ``handled`` instead of publishing."""
    rclpy = pytest.importorskip("rclpy")
    from robot_localization_suite.nodes.localizer_node import LocalizerNode

    rclpy.init(args=["mcl_baseline", "--ros-args", "-p", "max_particles:=2000", "-p", "min_particles:=500"])
    node = LocalizerNode(registry.plugin("mcl_baseline"))
    node.trigger_configure()
    node.trigger_activate()
    node.publish = lambda output, stamp=None: handled.append((stamp, output))  # type: ignore[method-assign]
    try:
        node.adapter.on_map_msg(conversions.grid_map_to_msg(office, 0.0))
        node.adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, start, np.diag([0.05**2] * 3)))
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def test_odometry_whose_lag_keeps_growing_still_updates_once_a_transform_tolerance() -> None:
    """An executor that cannot keep up serves one odometry message a spin while the scans stay fresh: the
    odometry's lag grows past transform_tolerance. The node then updates late, with the scans its odometry
    reaches, instead of dropping each before its odometry comes (the demo's starvation under load)."""
    office = office_map()
    run = drive(office, steps=120, seed=2)
    handled: list[tuple[float, Any]] = []
    with _tracking_node(office, run.truth[0], handled) as node:
        node._on_odom(conversions.odometry_to_msg(run.stamps[0], run.odometry[0], frame_id="odom"))
        for k in range(1, 120):  # odometry at half the scan rate: 6 s behind at the end
            node._on_scan(_scan_msg(run.scans[k]))
            if k % 2 == 0:
                node._on_odom(conversions.odometry_to_msg(run.stamps[k // 2], run.odometry[k // 2], frame_id="odom"))
    stamps = [stamp for stamp, _ in handled]
    reached = run.stamps[59]
    assert stamps and stamps[-1] >= reached - 2.0  # within two tolerances of where the odometry is
    assert np.all(np.diff(stamps) > 0.0)  # in order, each once
    assert len([stamp for stamp in stamps if stamp > run.stamps[20]]) >= 3  # past the first second of lag


def test_odometry_trailing_the_scans_by_several_periods_delays_updates_but_never_starves_them() -> None:
    """Under load the odometry can arrive several scans late: every scan then waits for its own odometry
    (none is updated with an earlier instant's), and none is lost for a newer scan that also waits. With
    the odometry stopped, nothing is updated with odometry it lacks; when it comes back, the scans still
    waiting are updated."""
    pytest.importorskip("rclpy")
    from robot_localization_suite.nodes.localizer_node import MAX_WAITING_INPUTS

    office = office_map()
    run = drive(office, steps=90, seed=2)
    lag = 3  # scans (0.3 s at 10 Hz), within the default transform_tolerance of 1 s
    handled: list[tuple[float, Any]] = []  # (scan stamp, its output: None where the filter did not move enough)
    with _tracking_node(office, run.truth[0], handled) as node:
        odometry = [conversions.odometry_to_msg(run.stamps[k], run.odometry[k], frame_id="odom")
                    for k in range(len(run.stamps))]
        node._on_odom(odometry[0])
        for k in range(1, 60):
            node._on_scan(_scan_msg(run.scans[k]))
            if k >= lag:
                node._on_odom(odometry[k - lag])
        np.testing.assert_allclose([stamp for stamp, _ in handled], run.stamps[1:60 - lag])  # each once, in order
        last = [output for _, output in handled if output is not None][-1].estimate
        assert last.status is LocalizerStatus.LOCALIZED
        assert np.hypot(*(last.pose[:2] - run.truth[60 - lag - 1, :2])) < 0.15
        # odometry stops: none is updated; the scans of the last transform_tolerance (1 s) all wait, older
        # ones one a second
        before = len(handled)
        for k in range(60, 90):
            node._on_scan(_scan_msg(run.scans[k]))
        assert len(handled) == before
        waiting = [stamp for stamp, *_ in node._waiting]
        recent = [stamp for stamp in waiting if waiting[-1] - stamp <= 1.0 + 1e-9]
        assert waiting[-1] == pytest.approx(run.stamps[89]) and len(recent) == 11
        older = waiting[: len(waiting) - len(recent)]
        assert older and np.all(np.diff(older) >= 1.0 - 1e-9) and recent[0] - older[-1] <= 1.1 + 1e-9
        assert len(waiting) <= MAX_WAITING_INPUTS
        # it comes back: the scans that still wait are updated, each when its own odometry arrives
        for k in range(60 - lag, 90):
            node._on_odom(odometry[k])
        assert [stamp for stamp, _ in handled[before:]] == waiting and not node._waiting
        last = [output for _, output in handled if output is not None][-1].estimate
        assert last.stamp > run.stamps[80]
        assert np.hypot(*(last.pose[:2] - run.truth[89, :2])) < 0.3
