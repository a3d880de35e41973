"""ros/tf.py and the adapter's map -> odom: planar transforms, bad /tf input, and nav2_amcl's composition."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mcl_test_world import drive, office_map

from robot_localization_suite.core.mcl.localizer import MclSettings, MonteCarloLocalizer
from robot_localization_suite.core.se2 import compose
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter, ThrottledLog
from robot_localization_suite.ros.tf import TFMessage, TransformBuffer, transform_from_msg, transform_to_msg

pytestmark = pytest.mark.skipif(TFMessage is None, reason="tf2_msgs is not installed (make builds it)")


def _buffer(tolerance_s: float = 1.0) -> tuple[TransformBuffer, list[tuple[str, str]]]:
    logged: list[tuple[str, str]] = []
    return TransformBuffer(ThrottledLog(lambda *a: logged.append(a), period_s=60.0), tolerance_s=tolerance_s), logged


def _tf(stamp: float, parent: str, child: str, pose) -> TFMessage:  # noqa: ANN001
    return TFMessage(transforms=[transform_to_msg(stamp, parent, child, np.asarray(pose, dtype=np.float64))])


def test_a_chain_of_static_and_dynamic_frames_is_composed_and_interpolated() -> None:
    buffer, _ = _buffer()
    # odom -> base_footprint moves, base_footprint -> base_link and base_link -> laser are static
    buffer.add_message(_tf(0.0, "base_footprint", "base_link", [0.1, 0.0, 0.0]), static=True)
    buffer.add_message(_tf(0.0, "base_link", "laser", [0.2, 0.0, math.pi / 2]), static=True)
    buffer.add_message(_tf(1.0, "odom", "base_footprint", [1.0, 0.0, 0.0]), static=False)
    buffer.add_message(_tf(2.0, "/odom", "/base_footprint", [2.0, 0.0, math.pi / 2]), static=False)  # tf2 strips "/"
    assert buffer.chain("odom", "base_link") == ["base_link", "base_footprint", "odom"]
    # halfway: x 1.5, yaw pi/4, then 0.1 m forward along that heading
    expected = compose([1.5, 0.0, math.pi / 4], [0.1, 0.0, 0.0])
    assert buffer.lookup("odom", "base_link", 1.5) == pytest.approx(expected)
    assert buffer.lookup("base_link", "laser", static_only=True) == pytest.approx([0.2, 0.0, math.pi / 2])
    assert buffer.lookup("odom", "laser", static_only=True) is None  # a dynamic link on the way
    assert buffer.lookup("map", "base_link") is None  # not connected


def test_nan_a_non_unit_quaternion_and_an_old_transform_are_ignored_with_a_throttled_warning() -> None:
    buffer, logged = _buffer(tolerance_s=0.5)
    buffer.add_message(_tf(10.0, "odom", "base_link", [1.0, 2.0, 0.3]), static=False)
    nan = _tf(10.1, "odom", "base_link", [0.0, 0.0, 0.0])
    nan.transforms[0].transform.translation.x = math.nan
    stretched = _tf(10.2, "odom", "base_link", [0.0, 0.0, 0.0])
    stretched.transforms[0].transform.rotation.w = 2.0
    old = _tf(9.0, "odom", "base_link", [5.0, 5.0, 0.0])  # 1 s behind the newest, tolerance 0.5 s
    for msg in (nan, nan, stretched, old, old):
        assert buffer.add_message(msg, static=False) == []
    assert buffer.lookup("odom", "base_link") == pytest.approx([1.0, 2.0, 0.3])  # untouched
    texts = [text for _, text in logged]
    assert len(texts) == 2  # NaN and the quaternion share a key: throttled together; the old one has its own
    assert "non-finite value" in texts[0] and "odom -> base_link" in texts[0]
    assert "older than transform_tolerance (0.5 s)" in texts[1]
    with pytest.raises(ValueError, match="quaternion of norm 2"):
        transform_from_msg(stretched.transforms[0])
    # a stamp far in the past (a bag looped, a simulator restarted) starts a new timeline instead
    assert buffer.add_message(_tf(1.0, "odom", "base_link", [7.0, 0.0, 0.0]), static=False)
    assert buffer.lookup("odom", "base_link") == pytest.approx([7.0, 0.0, 0.0])


def test_a_refused_transform_neither_reparents_its_frame_nor_breaks_later_lookups() -> None:
    # a flipped /tf transform for a new frame left its parent recorded without a history: KeyError out of the
    # node's /tf callback; one at 1e15 m stayed in the history and pulled the next good pose to 0
    buffer, logged = _buffer()
    flipped = transform_to_msg(1.0, "odom", "mid", np.zeros(3), upside_down=True)
    buffer.add_message(TFMessage(transforms=[flipped, transform_to_msg(1.0, "mid", "base_footprint",
                                                                       np.array([1.0, 0.0, 0.0]))]), static=False)
    assert buffer.chain("odom", "base_footprint") is None and buffer.lookup("odom", "base_footprint") is None
    buffer.add_message(_tf(2.0, "odom", "base_footprint", [1.0, 0.0, 0.0]), static=False)
    buffer.add_message(_tf(2.1, "odom", "base_footprint", [1e15, 0.0, 0.0]), static=False)
    buffer.add_message(_tf(2.2, "odom", "base_footprint", [1.2, 0.0, 0.0]), static=False)
    assert buffer.lookup("odom", "base_footprint", 2.2) == pytest.approx([1.2, 0.0, 0.0])
    assert any("moves more than 1e+06 m" in text for *_, text in logged), logged
    buffer.add_message(_tf(0.5, "elsewhere", "base_footprint", [0.0, 0.0, 0.0]), static=False)  # too old
    assert buffer.chain("odom", "base_footprint") == ["base_footprint", "odom"]
    assert buffer.knows("odom") and not buffer.knows("mid")


def test_a_mount_is_found_through_a_common_frame_as_tf2_resolves_a_tree() -> None:
    # the laser as the base's parent, or its sibling under base_link: the node fell back to laser_x/y/yaw
    buffer, _ = _buffer()
    buffer.add_message(_tf(0.0, "laser", "base_footprint", [0.3, 0.0, 0.0]), static=True)
    assert buffer.chain("base_footprint", "laser") is None
    pose, flipped = buffer.lookup_mount("base_footprint", "laser", static_only=True)
    assert pose == pytest.approx([-0.3, 0.0, 0.0]) and not flipped
    buffer.add_message(_tf(0.0, "base_link", "base_fp", [0.1, 0.0, math.pi / 2]), static=True)
    buffer.add_message(_tf(0.0, "base_link", "laser_2", [0.4, 0.2, 0.0]), static=True)
    # laser_2 is 0.3 m along base_link's x and 0.2 m along its y from base_fp, which faces base_link's y
    pose, flipped = buffer.lookup_mount("base_fp", "laser_2", static_only=True)
    assert pose == pytest.approx([0.2, -0.3, -math.pi / 2]) and not flipped
    assert buffer.lookup_mount("base_fp", "nowhere", static_only=True) is None


def test_map_to_odom_composed_with_odometry_gives_the_estimate() -> None:
    """nav2_amcl's map -> odom: the estimate (+) inverse(odometry at the scan's stamp)."""
    office = office_map()
    run = drive(office, steps=60, seed=5)
    odom_origin = np.array([3.0, -1.0, 0.7])  # odometry starts somewhere else than the map's pose
    adapter = LocalizerAdapter(MonteCarloLocalizer(MclSettings(min_particles=500, max_particles=2000, random_seed=3)),
                               node_name="mcl", log=lambda *_: None)
    adapter.set_map(office)
    adapter.on_initial_pose_msg(conversions.initial_pose_to_msg(0.0, run.truth[0], np.diag([0.05**2] * 3)))
    output = None
    for k, scan in enumerate(run.scans):
        odom = compose(odom_origin, run.odometry[k])
        adapter.on_odometry(run.stamps[k], odom)
        output = adapter.on_scan_msg(conversions.scan_to_msg(
            scan.stamp, "laser", angle_min=scan.angles[0], angle_increment=scan.angles[1] - scan.angles[0],
            ranges=scan.ranges, range_min=scan.range_min, range_max=scan.range_max)) or output
    assert output is not None and output.map_to_odom is not None and output.odometry_lag == pytest.approx(0.0)
    k = int(np.argmin(np.abs(run.stamps - output.estimate.stamp)))
    odom_at_scan = compose(odom_origin, run.odometry[k])
    assert compose(output.map_to_odom, odom_at_scan) == pytest.approx(output.estimate.pose, abs=1e-9)
    # an initial pose in the odom frame is refused, naming both frames
    logged: list[tuple[str, str]] = []
    adapter.log = ThrottledLog(lambda *a: logged.append(a))
    refused = conversions.initial_pose_to_msg(1.0, run.truth[0], np.eye(3), frame_id="odom")
    assert adapter.on_initial_pose_msg(refused) is False
    assert "frame 'odom'" in logged[-1][1] and "global frame 'map'" in logged[-1][1]


def _matrix(transform) -> np.ndarray:  # noqa: ANN001
    """The 4 x 4 homogeneous matrix of a geometry_msgs/TransformStamped (scipy's quaternion convention)."""
    from scipy.spatial.transform import Rotation

    t, q = transform.transform.translation, transform.transform.rotation
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    out[:3, 3] = [t.x, t.y, t.z]
    return out


def test_an_upside_down_laser_on_a_chain_of_static_frames_sees_its_beams_where_3d_rotations_put_them() -> None:
    """base -> plate (rolled by pi) -> bracket (level in it) -> laser (pitched by pi): every beam's end point in
    the base frame, from the planar lookup and a level scan (LaserMount.level), is where the 3-D transforms
    put it; a level chain stays level, and a frame upside down on /tf is refused."""
    from scipy.spatial.transform import Rotation

    from robot_localization_suite.core.scan import LaserMount, Scan

    def message(parent: str, child: str, xyz, rpy) -> TFMessage:  # noqa: ANN001
        msg = transform_to_msg(0.0, parent, child, np.array([xyz[0], xyz[1], 0.0]))
        msg.transform.translation.z = xyz[2]
        q = Rotation.from_euler("xyz", rpy).as_quat()
        msg.transform.rotation.x, msg.transform.rotation.y, msg.transform.rotation.z, msg.transform.rotation.w = q
        return TFMessage(transforms=[msg])

    links = [message("base_link", "plate", [0.3, -0.1, 0.5], [math.pi, 0.0, 0.4]),
             message("plate", "bracket", [0.05, 0.2, -0.02], [0.0, 0.0, -1.1]),
             message("bracket", "laser", [-0.1, 0.07, 0.0], [0.0, math.pi, 0.25])]
    buffer, logged = _buffer()
    for msg in links:
        buffer.add_message(msg, static=True)
    assert buffer.above("laser") == ["bracket", "plate", "base_link"]
    found = buffer.lookup_mount("base_link", "laser", static_only=True)
    assert found is not None
    pose, upside_down = found
    assert not upside_down  # two half-turns: the laser is level on the base
    in_base = _matrix(links[0].transforms[0]) @ _matrix(links[1].transforms[0]) @ _matrix(links[2].transforms[0])
    angles = np.linspace(-2.0, 2.0, 9)
    ranges = np.linspace(1.0, 3.0, 9)
    beams = np.stack([ranges * np.cos(angles), ranges * np.sin(angles), np.zeros(9), np.ones(9)])
    for mount_frame, expect_upside_down in (("base_link", False), ("plate", True)):
        found = buffer.lookup_mount(mount_frame, "laser", static_only=True)
        assert found is not None and found[1] is expect_upside_down
        mount = LaserMount(*map(float, found[0]), upside_down=found[1])
        level = mount.level(Scan(0.0, angles, ranges, 0.1, 10.0))
        assert np.all(np.diff(level.angles) > 0)  # still increasing
        frame = in_base if mount_frame == "base_link" else _matrix(links[1].transforms[0]) @ _matrix(
            links[2].transforms[0])
        truth = (frame @ beams)[:2].T
        # an upside-down laser's beams come reordered (angles increasing), so its end points too
        assert level.hit_endpoints(mount.pose) == pytest.approx(truth[::-1] if mount.upside_down else truth, abs=1e-9)
    assert buffer.lookup("plate", "laser", static_only=True) is None  # upside down: no planar pose
    assert any("upside down in plate" in text for _, text in logged)
    # on /tf (dynamic) an upside-down frame is refused, naming it
    assert buffer.add_message(message("odom", "base_link", [1.0, 0.0, 0.0], [math.pi, 0.0, 0.0]), static=False) == []
    assert any("odom -> base_link on /tf: its z axis points down" in text for _, text in logged)
