"""The message <-> core bridge (ros/adapter.py) with a tiny fake core localizer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_localization_suite.core.errors import LocalizationSuiteError, MapError
from robot_localization_suite.core.grid_map import GridMap
from robot_localization_suite.core.localizer import Estimate, LocalizerStatus
from robot_localization_suite.core.scan import LaserMount, Scan
from robot_localization_suite.core.se2 import angle_difference, compose, inverse
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter


class EchoLocalizer:
    """Reports the last laser odometry pose it was given as its estimate, and records every call."""

    def __init__(self) -> None:
        self.odometry: list[tuple[float, np.ndarray]] = []
        self.scans: list[Scan] = []
        self.initial_poses: list[np.ndarray] = []
        self.initial_covariances: list[np.ndarray] = []
        self.grid_map: GridMap | None = None
        self.fail_next = False

    def set_map(self, grid_map: GridMap) -> None:
        self.grid_map = grid_map

    def on_odometry(self, stamp: float, odom_pose: np.ndarray) -> None:
        self.odometry.append((stamp, np.array(odom_pose)))

    def on_scan(self, scan: Scan) -> Estimate | None:
        self.scans.append(scan)
        if self.fail_next:
            raise LocalizationSuiteError("precomputation not ready")
        pose = self.odometry[-1][1] if self.odometry else np.zeros(3)
        candidates = np.array([pose, compose(pose, [0.5, 0.0, 0.0])])
        return Estimate(scan.stamp, pose.copy(), np.eye(3) * 0.01, LocalizerStatus.LOCALIZED, candidates, details={"hypotheses": 2})

    def set_initial_pose(self, pose: np.ndarray, covariance: np.ndarray) -> None:
        self.initial_poses.append(np.array(pose))
        self.initial_covariances.append(np.array(covariance))

    def reinitialize(self) -> None:
        pass

    def request_nomotion_update(self) -> None:
        pass


class Logs:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def __call__(self, level: str, text: str) -> None:
        self.lines.append((level, text))

    def text(self) -> str:
        return "\n".join(text for _level, text in self.lines)


def make_adapter(mount: LaserMount | None = None) -> tuple[LocalizerAdapter, EchoLocalizer, Logs]:
    core, logs = EchoLocalizer(), Logs()
    adapter = LocalizerAdapter(core, node_name="echo", log=logs, mount=mount)
    adapter.set_map(GridMap(np.zeros((10, 10), np.int8), 0.1))
    return adapter, core, logs


def odom_msg(stamp: float, pose: list[float]):
    return conversions.odometry_to_msg(stamp, np.array(pose, dtype=float), frame_id="odom")


def scan_msg(stamp: float, ranges: list[float] | np.ndarray, *, increment: float = 0.1):
    return conversions.scan_to_msg(
        stamp,
        "laser",
        angle_min=-0.2,
        angle_increment=increment,
        ranges=np.asarray(ranges, dtype=float),
        range_min=0.1,
        range_max=10.0,
    )


def test_out_of_order_odometry_is_ignored_and_logged() -> None:
    adapter, core, logs = make_adapter()
    adapter.on_odom_msg(odom_msg(2.0, [1.0, 0.0, 0.0]))
    adapter.on_odom_msg(odom_msg(1.0, [9.0, 9.0, 0.0]))  # older than the last one
    adapter.on_odom_msg(odom_msg(3.0, [2.0, 0.0, 0.0]))
    adapter.on_odom_msg(odom_msg(4.0, [float("nan"), 0.0, 0.0]))
    adapter.on_scan_msg(scan_msg(5.0, [1.0] * 5))  # odometry reaches the localizer with the next scan
    assert [stamp for stamp, _pose in core.odometry] == [2.0, 3.0]
    assert "older than the last one" in logs.text()
    assert "non-finite" in logs.text()


def test_a_scan_is_weighed_after_the_odometry_of_its_stamp_and_before_newer_odometry() -> None:
    """Live, a scan arrives after odometry newer than its stamp (the driver publishes its sweep a period
    later): that odometry waits for the next scan, as in a replay in log order."""
    adapter, core, _logs = make_adapter()
    for stamp in (1.0, 1.1, 1.2, 1.3):
        adapter.on_odom_msg(odom_msg(stamp, [stamp, 0.0, 0.0]))
    output = adapter.on_scan_msg(scan_msg(1.1, [1.0] * 5))
    assert [stamp for stamp, _pose in core.odometry] == [1.0, 1.1]
    assert output is not None and output.estimate.pose[0] == pytest.approx(1.1)  # the echo: odometry at 1.1
    assert output.map_to_odom is not None and np.allclose(output.map_to_odom, 0.0)  # odometry at the scan's stamp
    adapter.on_scan_msg(scan_msg(1.3, [1.0] * 5))
    assert [stamp for stamp, _pose in core.odometry] == [1.0, 1.1, 1.2, 1.3]
    # an initial pose is where the robot is now: every odometry so far goes first
    adapter.on_odom_msg(odom_msg(1.4, [1.4, 0.0, 0.0]))
    adapter.set_initial_pose(np.array([1.0, 2.0, 0.0]))
    assert core.odometry[-1][0] == 1.4


def test_nan_scan_is_rejected_without_raising() -> None:
    adapter, core, logs = make_adapter()
    assert adapter.on_scan_msg(scan_msg(1.0, [math.nan] * 5)) is None
    assert core.scans == []
    assert "no valid beam" in logs.text()
    # A scan with some NaN readings still goes through; the readings stay classified as invalid.
    output = adapter.on_scan_msg(scan_msg(2.0, [1.0, math.nan, -3.0, math.inf, 2.0]))
    assert output is not None
    scan = core.scans[-1]
    assert scan.hit_mask.tolist() == [True, False, False, False, True]
    assert scan.no_return_mask.tolist() == [False, False, False, True, False]


@pytest.mark.parametrize(
    ("msg", "log"),
    [
        (lambda: scan_msg(1.0, []), "no ranges"),
        (lambda: scan_msg(1.0, [1.0, 2.0], increment=0.0), "angle_increment"),
    ],
)
def test_unusable_scan_geometry_is_skipped(msg, log: str) -> None:
    adapter, core, logs = make_adapter()
    assert adapter.on_scan_msg(msg()) is None
    assert core.scans == []
    assert log in logs.text()


def test_old_scans_and_scans_before_the_map_are_skipped() -> None:
    adapter, core, logs = make_adapter()
    assert adapter.on_scan_msg(scan_msg(5.0, [1.0] * 5)) is not None
    assert adapter.on_scan_msg(scan_msg(4.0, [1.0] * 5)) is None
    assert len(core.scans) == 1
    no_map = LocalizerAdapter(EchoLocalizer(), node_name="echo", log=logs)
    assert no_map.on_scan_msg(scan_msg(1.0, [1.0] * 5)) is None
    assert "before any map" in logs.text()


def test_core_errors_skip_the_update_without_raising() -> None:
    adapter, core, logs = make_adapter()
    core.fail_next = True
    assert adapter.on_scan_msg(scan_msg(1.0, [1.0] * 5)) is None
    assert "precomputation not ready" in logs.text()


def test_mount_offset_round_trip() -> None:
    mount = LaserMount(0.2, 0.1, 0.3)
    adapter, core, _logs = make_adapter(mount)
    base = np.array([1.0, 2.0, np.pi / 2])
    adapter.on_odom_msg(odom_msg(1.0, base.tolist()))
    output = adapter.on_scan_msg(scan_msg(1.5, [1.0] * 5))
    assert output is not None
    # The core sees the laser: 0.2 m ahead and 0.1 m to the left of a base facing +y.
    laser = core.odometry[-1][1]
    np.testing.assert_allclose(laser, [0.9, 2.2, np.pi / 2 + 0.3], atol=1e-9)
    # The echoed laser pose comes back as the base pose, in the message too.
    np.testing.assert_allclose(output.estimate.pose[:2], base[:2], atol=1e-9)
    assert abs(angle_difference(output.estimate.pose[2], base[2])) < 1e-9
    msg_pose = conversions.pose_from_pose_msg(output.pose.pose.pose)
    np.testing.assert_allclose(msg_pose[:2], base[:2], atol=1e-6)
    assert output.pose.header.frame_id == "map"
    assert conversions.stamp_to_seconds(output.pose.header.stamp) == pytest.approx(1.5)
    # Candidates are converted too: the second is a laser pose 0.5 m ahead of the first, returned as the base
    # pose that puts the laser there.
    assert len(output.candidates.poses) == 2
    second = conversions.pose_from_pose_msg(output.candidates.poses[1])
    expected = compose(compose(laser, [0.5, 0.0, 0.0]), inverse(mount.pose))
    np.testing.assert_allclose(second[:2], expected[:2], atol=1e-6)

    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, base, np.eye(3)))
    np.testing.assert_allclose(core.initial_poses[-1], laser, atol=1e-9)


def test_diagnostics_carry_status_and_update_time() -> None:
    adapter, _core, _logs = make_adapter()
    output = adapter.on_scan_msg(scan_msg(1.0, [1.0] * 5))
    assert output is not None and output.update_ms >= 0.0
    status = output.diagnostics.status[0]
    assert status.message == "LOCALIZED"
    assert status.hardware_id == "echo"
    values = {kv.key: kv.value for kv in status.values}
    assert values["candidates"] == "2"
    assert values["hypotheses"] == "2"
    assert float(values["update_ms"]) == pytest.approx(output.update_ms, abs=0.01)


def test_map_message_reaches_the_core_and_a_bad_one_is_refused() -> None:
    core, logs = EchoLocalizer(), Logs()
    adapter = LocalizerAdapter(core, node_name="echo", log=logs)
    grid = GridMap(np.zeros((4, 6), np.int8), 0.25, (1.0, 2.0))
    assert adapter.on_map_msg(conversions.grid_map_to_msg(grid, 0.0))
    assert core.grid_map is not None and core.grid_map.width == 6
    bad = conversions.grid_map_to_msg(grid, 0.0)
    bad.info.width = 7  # no longer matches the data
    assert not adapter.on_map_msg(bad)
    assert "ignoring map message" in logs.text()


def test_same_map_from_topic_is_not_handed_over_twice_but_a_changed_one_is():
    adapter, core, _logs = make_adapter()
    first = core.grid_map
    # The same map arriving on /map (resolution passed through float32) must not trigger relearning.
    adapter.on_map_msg(conversions.grid_map_to_msg(first, 0.0))
    assert core.grid_map is first
    changed = GridMap(first.data.copy(), first.resolution)
    changed.data[5, 5] = 100
    adapter.on_map_msg(conversions.grid_map_to_msg(changed, 1.0))
    assert core.grid_map is not first and core.grid_map.data[5, 5] == 100


def test_the_input_clock_refuses_the_future_steps_over_small_steps_back_and_restarts_after_a_jump() -> None:
    from robot_localization_suite.ros.adapter import InputClock

    now = [100.0]
    clock = InputClock(max_future_s=1.0, time_jump_reset_s=3.0, clock=lambda: now[0])
    assert clock.admit("scan", 100.0) == "ok"
    assert clock.admit("odom", 100.5) == "ok"
    assert clock.admit("scan", 102.0) == "future"  # 2 s ahead of the clock
    assert clock.newest == 100.5  # a refused stamp does not move the node's time
    now[0] = 103.0  # a sensor pause of 3 s is no attack: its next stamp is in the clock's present
    assert clock.admit("scan", 103.0) == "ok"
    assert clock.admit("scan", 102.5) == "older"  # 0.5 s back on its own stream: refused
    assert clock.admit("scan", 99.0) == "reset"  # 4 s back: a new timeline
    assert clock.admit("odom", 99.1) == "ok" and clock.newest == 99.1
    assert clock.admit("odom", float("nan")) == "future"
    # Without a clock (a bare replay), a far-future stamp is taken, and the next real one restarts the timeline.
    bare = InputClock()
    assert bare.admit("scan", 10.0) == "ok" and bare.admit("scan", 2.0**31) == "ok"
    assert bare.admit("scan", 11.0) == "reset"


def test_an_initial_pose_with_an_unusable_covariance_gets_the_default_spread_and_a_warning() -> None:
    adapter, core, logs = make_adapter()
    pose = np.array([1.0, 2.0, 0.3])
    good = np.diag([0.04, 0.09, 0.01])
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, pose, good))
    np.testing.assert_allclose(core.initial_covariances[-1], good)
    default = np.diag([0.5**2, 0.5**2, (np.pi / 12) ** 2])
    for bad in (np.zeros((3, 3)), np.diag([0.04, -0.01, 0.01]), np.array([[1.0, 2.0, 0], [2.0, 1.0, 0], [0, 0, 1.0]]),
                np.full((3, 3), np.nan)):
        adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, pose, bad))
        np.testing.assert_allclose(core.initial_covariances[-1], default)
        np.testing.assert_allclose(core.initial_poses[-1], pose)
    assert "is not positive definite: using the default spread (std 0.5 m, 0.5 m, 15 deg)" in logs.text()


def test_scans_refused_by_a_clock_at_zero_say_that_the_clock_has_not_started() -> None:
    # use_sim_time without /clock: the node's clock reads 0 and every scan of a bag is "from the future"
    logs = Logs()
    clock = [0.0]
    adapter = LocalizerAdapter(EchoLocalizer(), node_name="echo", log=logs, clock=lambda: clock[0])
    adapter.set_map(GridMap(np.zeros((10, 10), np.int8), 0.1))
    assert adapter.on_scan_msg(scan_msg(1_700_000_000.0, [0.5] * 5)) is None
    assert "use_sim_time with no /clock" in logs.text()
    clock[0] = 1_700_000_000.0
    adapter.on_odom_msg(odom_msg(1_700_000_000.0, [0.1, 0.1, 0.0]))
    assert adapter.on_scan_msg(scan_msg(1_700_000_000.1, [0.5] * 5)) is not None


def test_an_initial_pose_off_the_map_is_taken_as_nav2_does_but_said() -> None:
    # 700 km off a 1 m map used to be tracked as LOCALIZED with nothing logged (a frame or unit mixed up)
    adapter, core, logs = make_adapter()
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, np.array([0.5, 0.5, 0.0]), np.eye(3) * 0.01))
    assert "outside the map" not in logs.text()
    far = np.array([5e5, 5e5, 0.0])
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, far, np.eye(3) * 0.01))
    np.testing.assert_allclose(core.initial_poses[-1], far)
    assert "initial pose at (500000, 500000) m is outside the map (x 0 to 1 m, y 0 to 1 m)" in logs.text()


def test_a_stamped_initial_pose_is_moved_on_by_the_odometry_since_and_older_than_it_is_said() -> None:
    """RViz stamps the pose when clicked: the robot has moved since. A pose older than the odometry kept
    (received before activation) can only be moved on from the oldest odometry: a warning says so."""
    adapter, core, logs = make_adapter()
    pose = np.array([1.0, 2.0, 0.0])
    adapter.on_odometry(10.0, np.array([0.0, 0.0, 0.0]))
    adapter.on_odometry(11.0, np.array([0.4, 0.0, 0.5]))
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(10.0, pose, np.diag([0.04, 0.04, 0.01])))
    np.testing.assert_allclose(core.initial_poses[-1], [1.4, 2.0, 0.5], atol=1e-9)
    assert "before the oldest odometry" not in logs.text()
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(9.0, pose, np.diag([0.04, 0.04, 0.01])))
    np.testing.assert_allclose(core.initial_poses[-1], [1.4, 2.0, 0.5], atol=1e-9)
    assert "initial pose stamped 1.00 s before the oldest odometry kept" in logs.text()


def test_a_scan_whose_angle_max_disagrees_with_its_increment_is_skipped_naming_the_values() -> None:
    adapter, core, logs = make_adapter()
    msg = scan_msg(1.0, [1.0] * 5)
    msg.angle_max = float(msg.angle_max + 0.5)
    assert adapter.on_scan_msg(msg) is None and not core.scans
    assert "angle_max" in logs.text() and "disagrees" in logs.text()
    off_by_one = scan_msg(2.0, [1.0] * 5)
    off_by_one.angle_max = float(off_by_one.angle_max + off_by_one.angle_increment)  # a driver's end of the last sector
    assert adapter.on_scan_msg(off_by_one) is not None


def test_a_clockwise_scan_reaches_the_method_with_its_angles_increasing() -> None:
    """A driver sweeping clockwise publishes a negative angle_increment: the same readings, beams reordered."""
    adapter, core, _ = make_adapter()
    clockwise = conversions.scan_to_msg(1.0, "laser", angle_min=0.2, angle_increment=-0.1,
                                        ranges=np.array([1.0, 2.0, 3.0, 4.0, 5.0]), range_min=0.1, range_max=10.0)
    assert adapter.on_scan_msg(clockwise) is not None
    scan = core.scans[-1]
    np.testing.assert_allclose(scan.angles, [-0.2, -0.1, 0.0, 0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(scan.ranges, [5.0, 4.0, 3.0, 2.0, 1.0])
    counter = scan_msg(2.0, [5.0, 4.0, 3.0, 2.0, 1.0])  # the same sweep published counter-clockwise
    assert adapter.on_scan_msg(counter) is not None
    np.testing.assert_allclose(core.scans[-1].hit_endpoints([0.0, 0.0, 0.3]), scan.hit_endpoints([0.0, 0.0, 0.3]))


def test_a_map_the_method_refuses_is_logged_and_the_next_map_is_taken_even_if_it_is_the_previous_one() -> None:
    """MCL refused a map without a free cell after taking it in part; the right map sent again was 'unchanged'."""

    class Picky(EchoLocalizer):
        def set_map(self, grid_map: GridMap) -> None:
            self.grid_map = grid_map  # in part, as a method failing half-way
            if not grid_map.free_mask.any():
                raise MapError("the map has no free cell to sample poses from")

    core, logs = Picky(), Logs()
    adapter = LocalizerAdapter(core, node_name="echo", log=logs)
    room = GridMap(np.zeros((10, 10), np.int8), 0.1)
    assert adapter.on_map_msg(conversions.grid_map_to_msg(room, 0.0)) and adapter.has_map
    wall = GridMap(np.full((1, 1), 100, np.int8), 0.1)
    assert not adapter.on_map_msg(conversions.grid_map_to_msg(wall, 0.0))
    assert "ignoring map message: the map has no free cell" in logs.text() and not adapter.has_map
    assert adapter.on_scan_msg(scan_msg(1.0, [1.0] * 5)) is None and not core.scans  # no map: no update
    assert adapter.on_map_msg(conversions.grid_map_to_msg(room, 0.0)) and adapter.has_map
    assert core.grid_map is not None and core.grid_map.width == 10  # given again, not kept as "unchanged"
    with pytest.raises(MapError):  # map_yaml at configure: the caller sees the refusal
        adapter.set_map(wall)


def test_positions_beyond_a_thousand_kilometres_are_refused() -> None:
    adapter, core, logs = make_adapter()
    adapter.on_odom_msg(odom_msg(1.0, [1e308, -1e308, 0.0]))
    assert not core.odometry and "more than 1e+06 m from the odometry origin" in logs.text()
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, np.array([2e6, 0.0, 0.0]), np.eye(3)))
    assert not core.initial_poses and "more than 1e+06 m from the origin of 'map'" in logs.text()
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, np.array([1.0, 2.0, 0.0]),
                                                                np.diag([1e300, 1e300, 1.0])))
    np.testing.assert_allclose(core.initial_covariances[-1], np.diag([0.5**2, 0.5**2, (np.pi / 12) ** 2]))
    assert "is wider than 1e+06 m: using the default spread" in logs.text()
    far = conversions.grid_map_to_msg(GridMap(np.zeros((10, 10), np.int8), 0.1), 0.0)
    far.info.origin.position.x = 6.6e16  # float64 steps of 8 m there
    assert not adapter.on_map_msg(far)
    assert "reaches more than 1e+06 m from the origin" in logs.text()


def test_odometry_and_initial_poses_whose_quaternion_is_no_rotation_are_refused() -> None:
    """A quaternion far from unit norm has no meaning as a heading (tf2 refuses it too)."""
    adapter, core, logs = make_adapter()
    odom = odom_msg(1.0, [1.0, 2.0, 0.5])
    odom.pose.pose.orientation.x, odom.pose.pose.orientation.y = 0.0, 1e308
    adapter.on_odom_msg(odom)
    zero = odom_msg(1.0, [1.0, 2.0, 0.5])
    zero.pose.pose.orientation.z = zero.pose.pose.orientation.w = 0.0
    adapter.on_odom_msg(zero)
    # the zero one too (its warning is throttled with the first); accepted odometry would set the stamp
    assert adapter.last_odometry_stamp == -math.inf
    assert "ignoring odometry: its quaternion (x, y, z, w) [0.0, 1e+308, " in logs.text()
    adapter.on_odom_msg(odom_msg(1.0, [1.0, 2.0, 0.5]))
    assert adapter.last_odometry_stamp == 1.0
    initial = conversions.initial_pose_to_msg(0.0, np.array([1.0, 2.0, 0.3]), np.eye(3) * 0.01)
    initial.pose.pose.orientation.w = 2.0
    assert not adapter.on_initial_pose_msg(initial) and not core.initial_poses
    assert "ignoring initial pose: its quaternion" in logs.text() and "is not a rotation" in logs.text()
