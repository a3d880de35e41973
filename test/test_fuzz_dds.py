"""The worst messages of the fuzz suite (test_fuzz.py) sent over DDS to a real localizer node process.

A probe node plays the robot in test_fuzz's room: the map, then odometry and a scan five times a
second, stamped with the wall clock. Once the node localizes, the probe sends each worst case
(stamps in 2038 and at 0, NaN / inf / empty / mismatched scans, a scan that fits nowhere, odometry
at 1e308 or with a zero quaternion, initial poses with NaN or negative covariance, maps whose data
disagree with their size or whose resolution is 0 or NaN, a 1 x 1 map), each followed by a normal
step; then the map again and normal data. Every pose the node publishes must be finite, and it must
localize on the normal data afterwards, alive and without a traceback.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from test_fuzz import BEAMS, WORST_LASER, Step, World, build, room
from test_nav2_dropin import Process

from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.launch.lifecycle import LifecycleManager
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.context_node import ContextNode

RATE_HZ = 5.0
RANGE_MAX = 8.0


def truth_at(t: float) -> np.ndarray:
    """The robot's pose [m, m, rad] ``t`` seconds into the test: back and forth in the room's west part."""
    phase = 2.0 * math.pi * t / 20.0
    return np.array([1.8 - 0.8 * math.cos(phase), 1.3 + 0.2 * math.sin(phase), 0.3 * math.sin(phase)])


class Robot(ContextNode):
    """The probe: publishes the room's map and the robot's odometry and scans, and records the node's output."""

    def __init__(self, node_name: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import OccupancyGrid, Odometry
        from sensor_msgs.msg import LaserScan

        from robot_localization_suite.ros.qos import MAP_QOS, POSE_QOS, RELIABLE_QOS, SENSOR_QOS

        super().__init__("fuzz_robot")
        grid_map = room()
        self.world = World(grid_map, conversions.grid_map_to_msg(grid_map, 0.0), [], [])
        self.caster = RayCaster(grid_map, max_range=RANGE_MAX)
        self.angles = -math.pi + (2.0 * math.pi / BEAMS) * np.arange(BEAMS)
        self.rng = np.random.default_rng(3)
        self.started = time.time()
        self.truth: dict[float, np.ndarray] = {}
        self.poses: list[tuple[float, np.ndarray, np.ndarray]] = []  # (stamp, pose, covariance diagonal)
        self.states: list[str] = []
        self.last: tuple[float, np.ndarray, Any, Any] | None = None  # the last normal step
        self.publishers = {
            "scan": self.node.create_publisher(LaserScan, "/scan", SENSOR_QOS),
            "odom": self.node.create_publisher(Odometry, "/odom", RELIABLE_QOS),
            "map": self.node.create_publisher(OccupancyGrid, "/map", MAP_QOS),
            "initialpose": self.node.create_publisher(PoseWithCovarianceStamped, "/initialpose", RELIABLE_QOS),
        }
        self.node.create_subscription(PoseWithCovarianceStamped, f"/{node_name}/pose", self._on_pose, POSE_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: self.states.extend(
            s.message for s in msg.status if s.hardware_id == node_name), RELIABLE_QOS)

    def _on_pose(self, msg: Any) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        pose = np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w])
        covariance = np.array(msg.pose.covariance)
        self.poses.append((conversions.stamp_to_seconds(msg.header.stamp), pose, covariance))

    def spin_for(self, seconds: float) -> None:
        """Spin in short steps (the robot publishes between them)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=max(0.0, min(0.02, deadline - time.monotonic())))

    def step(self) -> Any:
        """One normal step now: odometry (the odom frame is the map frame) then a scan; returns the scan."""
        stamp = time.time()
        truth = truth_at(stamp - self.started)
        self.truth[stamp] = truth
        ranges = self.caster.cast(truth, self.angles).astype(np.float64) + self.rng.normal(0.0, 0.01, BEAMS)
        scan = conversions.scan_to_msg(stamp, "laser", angle_min=-math.pi, angle_increment=2.0 * math.pi / BEAMS,
                                       ranges=ranges, range_min=0.05, range_max=RANGE_MAX)
        odom = conversions.odometry_to_msg(stamp, truth, frame_id="odom")
        self.publishers["odom"].publish(odom)
        self.publishers["scan"].publish(scan)
        self.last = (stamp, truth, odom, scan)
        return scan

    def run(self, seconds: float, done: Callable[[], bool] = lambda: False) -> bool:
        """Normal steps at RATE_HZ for up to ``seconds``, until ``done()``."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.step()
            self.spin_for(1.0 / RATE_HZ)
            if done():
                return True
        return done()

    def send(self, case: dict[str, Any]) -> None:
        assert self.last is not None
        stamp, truth, odom, scan = self.last
        msg = build(case, Step(stamp, truth, odom, scan), self.world, time.time())
        self.publishers[case["kind"]].publish(msg)

    def errors(self, after: float) -> list[float]:
        """Position error [m] of each pose stamped after ``after``."""
        return [math.hypot(*(pose[:2] - self.truth[min(self.truth, key=lambda t: abs(t - stamp))][:2]))
                for stamp, pose, _ in self.poses if stamp > after]


@pytest.mark.parametrize("name", ["ial_localizer", "mcl_baseline"])
def test_the_worst_fuzz_cases_over_dds_leave_the_node_publishing_finite_poses_that_localize(
    name: str, ros_domain_id: int
) -> None:
    pytest.importorskip("rclpy")
    node_name = f"fuzz_{name}"
    args = ["-r", f"__node:={node_name}"]
    if name == "mcl_baseline":  # tracking only: it starts where it is told, as nav2 sets it
        start = truth_at(0.0)
        args += ["-p", "set_initial_pose:=true", "-p", f"initial_pose.x:={start[0]}", "-p",
                 f"initial_pose.y:={start[1]}", "-p", f"initial_pose.yaw:={start[2]}"]
    node = Process(f"robot_localization_suite.nodes.{name}", "--ros-args", *args)
    manager = LifecycleManager([node_name], domain_id=ros_domain_id, log=lambda _line: None)
    robot = Robot(node_name)
    try:
        robot.publishers["map"].publish(robot.world.map_msg)
        assert manager.startup(180.0), node.text()

        def settled(after: float) -> Callable[[], bool]:
            return lambda: len(errors := robot.errors(after)) >= 5 and max(errors[-3:]) < 0.3

        robot.started = time.time()
        assert robot.run(60.0, settled(robot.started)), (robot.errors(0.0)[-5:], robot.states[-5:], node.text())
        before = len(robot.poses)
        for case in WORST_LASER:
            robot.send(case)
            robot.spin_for(0.05)
            robot.step()
            robot.spin_for(1.0 / RATE_HZ)
        attack_end = time.time()
        robot.publishers["map"].publish(robot.world.map_msg)  # a map_server publishing the right map again
        if name == "mcl_baseline":  # once the map is in (a new map restarts the filter), where the robot is
            robot.spin_for(1.0)
            attack_end = time.time()
            robot.publishers["initialpose"].publish(conversions.initial_pose_to_msg(
                attack_end, truth_at(attack_end - robot.started), np.diag([0.1**2, 0.1**2, 0.05**2])))
        localized = robot.run(60.0, settled(attack_end + 1.0))
        bad = [(stamp, pose.tolist(), covariance.tolist()) for stamp, pose, covariance in robot.poses
               if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(covariance)))]
        assert not bad, f"non-finite poses published: {bad[:3]}"
        assert localized, (robot.errors(attack_end)[-5:], robot.states[-5:], node.text()[-3000:])
        assert node.process.poll() is None and "Traceback" not in node.text(), node.text()
        for seen in ("stamped 2147483648.000 s: more than 1 s ahead of the node's clock", "time jumped back to 0.000 s",
                     "occupancy grid of 4294967295 x 4294967295 cells carries 9600 values", "map 1 x 1 cells"):
            assert seen in node.text(), f"the worst cases did not all reach the node: no {seen!r} in\n{node.text()}"
        print(f"\n{name}: {len(WORST_LASER)} worst cases over DDS; {before} poses before, "
              f"{len(robot.poses) - before} after; final errors {np.round(robot.errors(attack_end)[-3:], 3)} m")
    finally:
        robot.close()
        manager.close()
        node.stop()
