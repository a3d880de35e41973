"""Nodes composed into one process (nodes/container.py, runfile key ``container``) over DDS on loopback."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from robot_localization_suite.launch.lifecycle import LifecycleManager
from robot_localization_suite.launch.runner import NodeGroup, NodeSpec, RunError, load_runfile
from robot_localization_suite.ros.bag import read_bag
from robot_localization_suite.ros.context_node import ContextNode
from robot_localization_suite.ros.conversions import grid_map_from_msg, odometry_from_msg, pose_from_pose_msg

ROOT = Path(__file__).resolve().parent.parent
BAG = ROOT / "bags" / "room_outliers_bounded"
LOCALIZERS = ("mcl_baseline", "ial_localizer")
_TOLERANCE_S = 1.0  # transform_tolerance: each map -> odom is stamped this far after its scan


class LockstepReplay:
    """Plays a bag over DDS one scan at a time: the next scan goes out once every localizer has handled this one.

    A localizer answers every scan with one ``map -> odom`` (remapped to ``/<name>/tf``) once it has a
    pose, so no scan is dropped and both runs see the same inputs; the poses on ``~/pose`` are kept.
    """

    def __init__(self, names: tuple[str, ...]) -> None:
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import LaserScan

        from robot_localization_suite.ros.qos import POSE_QOS, RELIABLE_QOS, TF_QOS
        from robot_localization_suite.ros.tf import TFMessage

        self.probe = ContextNode("lockstep_replay")
        node = self.probe.node
        self.names = names
        self.poses: dict[str, list[tuple[float, float, float, float]]] = {name: [] for name in names}
        self.tf_stamp = {name: -np.inf for name in names}
        self.odom_pub = node.create_publisher(Odometry, "/odom", RELIABLE_QOS)
        self.scan_pub = node.create_publisher(LaserScan, "/scan", RELIABLE_QOS)
        for name in names:
            node.create_subscription(PoseWithCovarianceStamped, f"/{name}/pose", self._pose(name), POSE_QOS)
            node.create_subscription(TFMessage, f"/{name}/tf", self._tf(name), TF_QOS)

    def _pose(self, name: str) -> Any:
        def record(msg: Any) -> None:
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            self.poses[name].append((stamp, *pose_from_pose_msg(msg.pose.pose)))

        return record

    def _tf(self, name: str) -> Any:
        def record(msg: Any) -> None:
            stamp = msg.transforms[0].header.stamp
            self.tf_stamp[name] = max(self.tf_stamp[name], stamp.sec + stamp.nanosec * 1e-9)

        return record

    def play(self, messages: list[Any]) -> None:
        # Matched by the writers themselves (the graph can list a reader before its writer has matched it:
        # a first odometry lost that way would shift every later update).
        publishers = (self.odom_pub, self.scan_pub)
        ready = lambda: all(p.get_subscription_count() >= len(self.names) for p in publishers)  # noqa: E731
        assert self.probe.spin_until(ready, 60.0), "the localizers never subscribed"
        self.probe.spin_for(1.0)
        for message in messages:
            if message.topic == "/odom":
                self.odom_pub.publish(message.msg)
            elif message.topic == "/scan":
                if not any(np.isfinite(s) for s in self.tf_stamp.values()):
                    # Before any odometry a scan goes at once (an odometry-free PIL needs none): give the first
                    # odometry time to arrive, or the first update would race it and shift the later ones.
                    self.probe.spin_for(0.5)
                self.scan_pub.publish(message.msg)
                stamp = message.msg.header.stamp.sec + message.msg.header.stamp.nanosec * 1e-9
                due = stamp + _TOLERANCE_S - 1e-6
                handled = lambda due=due: all(s >= due for s in self.tf_stamp.values())  # noqa: E731
                # Before its first pose a localizer sends no map -> odom: wait longer for that first one (its first
                # update may compile kernels; a scan sent meanwhile would make it drop this one, the older).
                started = all(np.isfinite(s) for s in self.tf_stamp.values())
                self.probe.spin_until(handled, 60.0 if started else 10.0)
        self.probe.spin_for(1.0)

    def close(self) -> None:
        self.probe.close()


def _replay(tmp_path: Path, container: str | None) -> dict[str, list[tuple[float, float, float, float]]]:
    messages = list(read_bag(BAG, ["/map", "/odom", "/scan", "/ground_truth"]))
    map_yaml = tmp_path / "room.yaml"
    if not map_yaml.exists():
        grid_map_from_msg(next(m.msg for m in messages if m.topic == "/map")).save(map_yaml)
    start = odometry_from_msg(next(m.msg for m in messages if m.topic == "/ground_truth"))[1]
    specs = [NodeSpec(name, name, params_file=str(ROOT / "config" / f"{name}.yaml"), container=container,
                      parameters={"map_yaml": str(map_yaml), "set_initial_pose": True, "initial_pose.x": float(start[0]),
                                  "initial_pose.y": float(start[1]), "initial_pose.yaw": float(start[2])},
                      remaps={"/tf": f"/{name}/tf"})
             for name in LOCALIZERS]
    lines: list[str] = []
    group = NodeGroup(specs, output=lambda name, line: lines.append(f"[{name}] {line}"), log=lines.append)
    replay = LockstepReplay(LOCALIZERS)
    manager = LifecycleManager(list(LOCALIZERS), log=lines.append)
    try:
        group.start()
        assert len(group.processes) == (1 if container else len(LOCALIZERS))
        assert manager.startup(300.0), "\n".join(lines)
        replay.play([m for m in messages if m.topic in ("/odom", "/scan")])
    finally:
        manager.close()
        replay.close()
        codes, _ = group.stop()
    assert all(code in (0, -2) for code in codes.values()), "\n".join(lines)
    return replay.poses


def test_a_composed_run_gives_the_same_poses_as_separate_processes(tmp_path: Path) -> None:
    separate = _replay(tmp_path, None)
    composed = _replay(tmp_path, "localizers")
    for name in LOCALIZERS:
        assert len(separate[name]) > 20, (name, len(separate[name]))
        assert len(composed[name]) == len(separate[name]), name
        np.testing.assert_allclose(np.array(composed[name]), np.array(separate[name]), rtol=0, atol=1e-9, err_msg=name)


def test_a_node_that_cannot_start_in_a_container_leaves_the_other_running(tmp_path: Path) -> None:
    """A parameter of the wrong type makes mcl_baseline's constructor raise; ial_localizer still configures."""
    specs = [NodeSpec("mcl_baseline", "mcl_baseline", parameters={"max_particles": "many"}, container="shared"),
             NodeSpec("ial_localizer", "ial_localizer", container="shared",
                      parameters={"map_yaml": str(ROOT / "config" / "maps" / "office.yaml")})]
    lines: list[str] = []
    group = NodeGroup(specs, output=lambda name, line: lines.append(f"[{name}] {line}"), log=lines.append)
    manager = LifecycleManager(["ial_localizer"], log=lines.append)
    try:
        group.start()
        assert manager.change_state("ial_localizer", "configure", 120.0), "\n".join(lines)
        assert group.first_exited() is None, "\n".join(lines)
        assert any("mcl_baseline could not start: SettingsError" in line for line in lines), "\n".join(lines)
    finally:
        manager.close()
        group.stop()


def test_a_node_that_raises_in_a_callback_is_stopped_and_the_other_keeps_running() -> None:
    import rclpy
    from rclpy.node import Node

    from robot_localization_suite.nodes.container import Container

    context = rclpy.Context()
    rclpy.init(context=context)
    ticks = {"good": 0, "bad": 0}
    logged: list[str] = []

    def node(name: str, fail_after: int | None) -> Node:
        made = Node(name, context=context)

        def tick() -> None:
            ticks[name] += 1
            if fail_after is not None and ticks[name] > fail_after:
                raise RuntimeError("a bug in the update")

        made.create_timer(0.02, tick)
        return made

    container = Container("test", log=logged.append, context=context)
    try:
        assert container.add("good", lambda: node("good", None))
        assert container.add("bad", lambda: node("bad", 3))
        assert not container.add("broken", lambda: (_ for _ in ()).throw(ValueError("no such map")))
        stop = time.monotonic() + 1.0
        container.spin(lambda: time.monotonic() < stop)
        assert list(container.nodes) == ["good"]
        assert ticks["bad"] >= 4
        assert container.failed == ["broken", "bad"]
        assert any(line.startswith("bad raised: RuntimeError: a bug in the update") for line in logged), logged
        before = ticks["good"]
        stop = time.monotonic() + 0.5
        container.spin(lambda: time.monotonic() < stop)
        assert ticks["good"] > before + 5  # still running after the other failed
    finally:
        container.close()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"executable": "scan_sim", "container": "c"}, "only localizers can share a container"),
        ({"executable": "mcl_baseline", "container": "no way"}, "container must be a name"),
        ({"executable": "mcl_baseline", "container": "c", "arguments": ["--x"]}, "takes no arguments"),
    ],
)
def test_container_errors_name_the_field(tmp_path: Path, entry: dict, message: str) -> None:
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump({"nodes": [entry]}))
    with pytest.raises(RunError, match=message):
        NodeGroup(load_runfile(path).nodes)


def test_a_container_may_not_take_a_node_name() -> None:
    specs = [NodeSpec("mcl_baseline", "mcl_baseline", container="ial_localizer"),
             NodeSpec("ial_localizer", "ial_localizer")]
    with pytest.raises(RunError, match="must not share a node's name"):
        NodeGroup(specs)


def test_the_runner_starts_one_process_per_container(tmp_path: Path) -> None:
    """The command line of a container carries each node's own ros arguments."""
    import json

    from robot_localization_suite.launch.runner import container_command

    specs = [NodeSpec("mcl_baseline", "a", parameters={"max_particles": 900}, remaps={"scan": "front"}, container="c"),
             NodeSpec("ial_localizer", "b", container="c")]
    command = container_command("c", specs, python="python3")
    assert command[:4] == ["python3", "-m", "robot_localization_suite.nodes.container", "c"]
    entries = json.loads(command[4])
    assert [entry["name"] for entry in entries] == ["a", "b"]
    assert NodeSpec(**entries[0]).ros_arguments() == ["--ros-args", "-r", "__node:=a", "-p", "max_particles:=900",
                                                      "-r", "scan:=front"]
