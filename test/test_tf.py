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
